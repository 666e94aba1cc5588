"""Benchmark splits (PAINT's azimuth / solstice / balanced / high-variance): disjoint, covering, of the
asked size, reproducible from a seed, each selecting what its definition says; and ``fit --split``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.calibration import splits
from helicalib.cli import main

DATA = Path(__file__).parent / "data" / "paint"


def _sun(az_paint_deg, el_deg) -> np.ndarray:
    az, el = np.radians(az_paint_deg), np.radians(el_deg)
    return np.column_stack([np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), np.sin(el)])


sun_sets = st.integers(min_value=2, max_value=40).flatmap(
    lambda n: st.tuples(
        st.lists(st.floats(-150, 150), min_size=n, max_size=n),
        st.lists(st.floats(1, 80), min_size=n, max_size=n)))


@settings(max_examples=40, deadline=None)
@given(sun_sets, st.sampled_from(splits.SPLITS), st.floats(0.05, 0.95), st.integers(0, 2**31 - 1))
def test_splits_are_disjoint_cover_the_set_and_are_reproducible(sun, kind, share, seed):
    s = _sun(*sun)
    n = len(s)
    a = splits.make_split(kind, s, 40.0, share, seed)
    assert np.intersect1d(a.train, a.test).size == 0
    assert np.array_equal(np.union1d(a.train, a.test), np.arange(n))
    assert len(a.test) == min(max(round(share * n), 1), n - 1)
    b = splits.make_split(kind, s, 40.0, share, seed)
    assert np.array_equal(a.train, b.train) and np.array_equal(a.test, b.test)


@settings(max_examples=30, deadline=None)
@given(sun_sets, st.floats(0.1, 0.9))
def test_azimuth_and_solstice_put_one_side_in_test(sun, share):
    s = _sun(*sun)
    az, _ = splits.paint_azimuth_elevation_deg(s)
    a = splits.make_split("azimuth", s, 50.9, share)
    assert az[a.test].min() >= az[a.train].max() - 1e-9  # test = the morning (east, PAINT's largest azimuths)
    dec = splits.declination_deg(s, 50.9)
    b = splits.make_split("solstice", s, 50.9, share)
    assert dec[b.test].min() >= dec[b.train].max() - 1e-9  # test = the summer side


def test_declination_matches_the_almanac():
    """At the 2026 equinoxes and solstices (published instants, UTC) the declination from the sun's position is
    0 and ±23.436° (the obliquity); the site is put where it is near noon then (apparent position: refraction
    at those elevations adds < 0.03°)."""
    from helicalib.geometry.sun import sun_position

    events = [("2026-03-20T14:46Z", 0.0), ("2026-06-21T08:24Z", 23.436), ("2026-09-23T00:05Z", 0.0),
              ("2026-12-21T20:50Z", -23.436)]
    for when, want in events:
        t = pd.Timestamp(when)
        lon = (12.0 - t.hour - t.minute / 60.0) * 15.0
        lon = (lon + 180.0) % 360.0 - 180.0
        s = np.asarray(sun_position(t, 30.0, lon, 0.0).vector_enu, dtype=float)
        assert s[2] > 0.5
        assert splits.declination_deg(s.reshape(1, 3), 30.0)[0] == pytest.approx(want, abs=0.05)


def test_high_variance_takes_the_most_isolated_positions():
    rng = np.random.default_rng(5)
    az, el = rng.uniform(-100, 100, 25), rng.uniform(5, 60, 25)
    x = np.column_stack([az, el])
    d = np.sqrt(((x[:, None, :] - x[None, :, :]) ** 2).sum(-1))  # brute force, not the k-d tree
    score = np.sort(d, axis=1)[:, 1:4].mean(axis=1)
    sp = splits.high_variance_split(az, el, 0.2)
    assert set(sp.test) == set(np.argsort(-score)[:5])


def test_balanced_takes_one_test_position_per_cluster():
    """Four tight, far-apart groups of sun positions and four test records: one from each group."""
    rng = np.random.default_rng(2)
    centres = np.array([[-80, 10], [-20, 50], [30, 30], [90, 15]])
    pts = np.concatenate([c + rng.normal(0, 0.5, (5, 2)) for c in centres])
    group = np.repeat(np.arange(4), 5)
    for seed in range(5):
        sp = splits.balanced_split(pts[:, 0], pts[:, 1], test_share=0.2, seed=seed)
        assert sorted(group[sp.test]) == [0, 1, 2, 3]
    draws = {tuple(splits.balanced_split(pts[:, 0], pts[:, 1], 0.2, seed).test) for seed in range(5)}
    assert len(draws) > 1  # the seed chooses the member


def test_bad_share_and_tiny_sets_are_refused():
    with pytest.raises(Exception, match="test share 1.0"):
        splits.n_test_of(10, 1.0)
    with pytest.raises(Exception, match="at least 2"):
        splits.make_split("azimuth", _sun([10.0], [20.0]), 50.0)
    with pytest.raises(Exception, match="unknown"):
        splits.make_split("hourly", _sun([10.0, 20.0], [20.0, 30.0]), 50.0)


@pytest.fixture(scope="module")
def aa23(tmp_path_factory):
    out = tmp_path_factory.mktemp("aa23")
    assert main(["import-paint", str(DATA), "--out", str(out)]) == 0
    return out


def test_fit_split_reports_out_of_sample_errors_beside_leave_one_out(aa23, capsys):
    capsys.readouterr()
    assert main(["fit", str(aa23 / "observations.csv"), "--field", str(aa23 / "field.yaml"), "--heliostat", "AA23",
                 "--split", "azimuth", "--split", "balanced", "--test-share", "0.3", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert set(rep["splits"]) == {"azimuth", "balanced"} and len(rep["loo_normal_mrad"]) == 10
    az = rep["splits"]["azimuth"]
    assert (az["train"], az["test"]) == (7, 3)
    # the azimuth test set read from the PAINT records themselves: the three largest sun azimuths
    recs = {p.name.split("-")[0]: json.loads(p.read_text())["sun_azimuth"]
            for p in (DATA / "AA23").glob("*-calibration-properties.json")}
    assert set(az["test_record_ids"]) == set(sorted(recs, key=recs.get)[-3:])
    assert az["test_normal_mrad_rms"] == pytest.approx(math.sqrt(np.mean(np.square(az["test_normal_mrad"]))))
    # out of sample is worse than in sample on the train part, and worse than the full fit in sample
    for sp in rep["splits"].values():
        assert sp["test_normal_mrad_rms"] > sp["train_normal_mrad_rms"]
        assert sp["test_normal_mrad_rms"] > rep["in_sample_normal_mrad_mean"]


def test_fit_split_text_and_bad_share(aa23, capsys):
    args = ["fit", str(aa23 / "observations.csv"), "--field", str(aa23 / "field.yaml"), "--heliostat", "AA23"]
    assert main(args + ["--split", "all"]) == 0
    out = capsys.readouterr().out
    assert all(f"split {k}" in out for k in splits.SPLITS) and "leave-one-out" in out
    with pytest.raises(SystemExit):
        main(args + ["--split", "azimuth", "--test-share", "1.5"])


def test_azimuth_split_reproduces_paints_published_split_of_aa23():
    """PAINT's own benchmark file for the AA23 samples (``test_benchmark.csv``) is an azimuth split: its
    3 validation records are the 3 largest sun azimuths, its 3 train records the 3 smallest."""
    import csv

    with open(DATA / "AA23" / "test_benchmark.csv", newline="") as f:
        published = {r["Id"]: r["Split"] for r in csv.DictReader(f)}
    recs = {p.name.split("-")[0]: json.loads(p.read_text()) for p in (DATA / "AA23").glob("*-calibration-properties.json")}
    ids = sorted(recs)
    sun = _sun([recs[i]["sun_azimuth"] for i in ids], [recs[i]["sun_elevation"] for i in ids])
    test = splits.make_split("azimuth", sun, 50.9, test_share=0.3).test
    assert {ids[i] for i in test} == {i for i, s in published.items() if s == "validation"}
    train3 = splits.make_split("azimuth", sun, 50.9, test_share=0.7).train
    assert {ids[i] for i in train3} == {i for i, s in published.items() if s == "train"}
