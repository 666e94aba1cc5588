"""The band-capacity bound and the band figures of ``benchmarks/bench_band.py``.

The bound from synthetic crossings (exact arithmetic), the bench500 field's own crossings at the
equinox (the first setting band opens at 0.691 days), and a database written through the store's
own API: gated hours, visits and band points per crossing, days to 95 % against the bound.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_band as bb

from helicalib.config import load_field_config
from helicalib.geometry.sun import parse_time, to_unix_seconds
from helicalib.store.records import Observation
from helicalib.store.sqlite import Store

H = 3600.0


def test_the_bound_is_where_both_bands_have_offered_enough_points():
    cross = [bb.Crossing("rising", 0, 0.0, H), bb.Crossing("setting", 0, 10 * H, 11 * H),
             bb.Crossing("rising", 1, 24 * H, 25 * H), bb.Crossing("setting", 1, 34 * H, 35 * H)]
    # 2 boards × 10 an hour: 20 band points a crossing
    assert bb.capacity_bound(cross, 20, 2, 10.0, 0.95) == pytest.approx(10 * H + 19 / 20 * H)
    # 40 heliostats: 38 needed, the second crossings of each kind, 18 of their 20
    assert bb.capacity_bound(cross, 40, 2, 10.0, 0.95) == pytest.approx(34 * H + 18 / 20 * H)
    assert bb.capacity_bound(cross, 100, 2, 10.0, 0.95) is None
    # the weather left half of the first setting crossing: its capacity is 10, the rest the next evening
    assert bb.capacity_bound(cross, 20, 2, 10.0, 0.95, hours=[1.0, 0.5, 1.0, 1.0]) == pytest.approx(34 * H + 0.45 * H)


def _start() -> float:
    return float(to_unix_seconds([parse_time(bb.EQUINOX)])[0])


@pytest.fixture(scope="module")
def bench500():
    return load_field_config(bb.FIELD)


def test_bench500_at_the_equinox_cannot_be_accepted_before_its_first_setting_band(bench500):
    start = _start()
    cross = bb.crossings(bench500, start, start + 86400.0)
    assert [c.kind for c in cross] == ["rising", "setting"]
    assert (cross[1].start_s - start) / 86400 == pytest.approx(0.691, abs=0.002)
    assert (cross[1].end_s - start) / 86400 == pytest.approx(0.728, abs=0.002)
    far = bb.crossings(bench500, start, start + 30 * 86400.0)
    fast = bb.capacity_bound(far, 500, 4, 135.0, 0.95)
    assert (fast - start) / 86400 == pytest.approx(0.728, abs=0.002)  # 4 × 0.89 h × 135 ≥ 475: the first evening
    slow = bb.capacity_bound(far, 500, 4, 90.0, 0.95)
    assert 1.69 < (slow - start) / 86400 < 1.73  # 320 a crossing: the second evening


def _obs(cid, vid, hid, t, elevation, valid=True) -> Observation:
    return Observation(campaign_id=cid, heliostat_id=hid, target_id="T1", visit_id=vid, iteration=0,
                       capture_time_s=t, strokes_cmd_mm=(1.0, 2.0), strokes_read_mm=(1.0, 2.0), approach=(1, 1),
                       sun_enu=(0.0, 0.5, 0.8), sun_azimuth_deg=90.0, sun_elevation_deg=elevation, sun_rising=True,
                       valid=valid, reason="ok" if valid else "no_spot", message="", error_mrad=1.0 if valid else None)


def test_a_database_gives_open_hours_band_points_and_days_against_the_bound(bench500, tmp_path):
    start = _start()
    cross = bb.crossings(bench500, start, start + 86400.0)
    rise, sets = cross
    ids = [h.id for h in bench500.heliostats]
    with Store.open(tmp_path / "helicalib.db", tmp_path / "img", durable=False, batched=True) as store:
        cid = store.start_campaign(name="t", mode="simulate", started_s=start,
                                   heliostats=[(h, bench500.heliostat_index(h), bench500.heliostat(h).target)
                                               for h in ids], settings={"days": 1.0, "seed": 7, "spots_per_board": 1})
        # the gate shut for the rising band's first 0.2 h (DNI) and its last 0.1 h
        store.record_event(campaign_id=cid, time_s=rise.start_s - 60, kind="gated", reason="DNI")
        store.record_event(campaign_id=cid, time_s=rise.start_s + 0.2 * H, kind="ungated", reason="ok")
        store.record_event(campaign_id=cid, time_s=rise.end_s - 0.1 * H, kind="gated", reason="DNI")
        store.record_event(campaign_id=cid, time_s=rise.end_s + 60, kind="ungated", reason="ok")
        for k, hid in enumerate(ids[:480]):  # 480 heliostats with a rising point, 470 with a setting one
            for c, limit in ((rise, 480), (sets, 470)):
                if k >= limit:
                    continue
                t = c.start_s + (k + 0.5) / limit * (c.end_s - c.start_s)
                vid = store.begin_visit(cid, hid, "T1", t - 1)
                store.record_observation(_obs(cid, vid, hid, t, 10.0))
                store.end_visit(vid, ended_s=t + 5, outcome="converged")
                if c is sets:
                    store.record_verdict(campaign_id=cid, heliostat_id=hid, time_s=t + 5, accepted=True, n_points=5,
                                         rms_mrad=1.0, reasons=[])
        vid = store.begin_visit(cid, ids[0], "T1", rise.start_s + 100)  # an invalid reading gives no point
        store.record_observation(_obs(cid, vid, ids[499], rise.start_s + 120, 6.0, valid=False))
        store.finish_campaign(cid, start + 86400.0)
    db = tmp_path / "helicalib.db"
    assert bb.open_hours(db, cross) == pytest.approx([rise.hours - 0.3, sets.hours], abs=1e-6)
    assert bb.campaign_of(db)[1] and bb.accepted_now(db) == 470
    doc = bb.report(bench500, db, start, 1.0, {"one at a time": 90.0, "with turns": 135.0}, "one at a time")
    r, s = doc["crossings"]
    assert (r["heliostats_with_point"], r["new_heliostats"], r["visits"]) == (480, 480, 481)
    assert (s["heliostats_with_point"], s["heliostats_with_kind"]) == (470, 470)
    assert r["points_per_board_hour"] == pytest.approx(480 / (4 * rise.hours), abs=0.1)
    assert r["points_per_open_board_hour"] == pytest.approx(480 / (4 * (rise.hours - 0.3)), abs=0.1)
    assert doc["days_to_90"] is not None and doc["days_to_95"] is None  # 470 of the 475 needed
    assert doc["bounds"]["one at a time (90 per board-hour)"]["days_to_95"] > 1.69
    assert doc["bounds"]["with turns (135 per board-hour)"]["days_to_95"] == pytest.approx(0.728, abs=0.002)


def test_the_cli_reads_a_database_and_refuses_a_missing_one(tmp_path, capsys):
    with pytest.raises(SystemExit, match="no such database"):
        bb.main(["--db", str(tmp_path / "none.db"), "--out", str(tmp_path / "o.json")])


def test_the_run_s_rate_comes_from_the_crossings_the_boards_limited(bench500, tmp_path):
    """Day 0's rising crossing leaves 200 heliostats to the next morning's (the boards were the limit);
    that crossing serves just those 200 (nobody else left): the run's rate is day 0's alone."""
    start = _start()
    cross = bb.crossings(bench500, start, start + 2 * 86400.0)
    rise0, set0, rise1, _set1 = cross
    ids = [h.id for h in bench500.heliostats]
    with Store.open(tmp_path / "helicalib.db", tmp_path / "img", durable=False, batched=True) as store:
        cid = store.start_campaign(name="t", mode="simulate", started_s=start,
                                   heliostats=[(h, bench500.heliostat_index(h), bench500.heliostat(h).target)
                                               for h in ids], settings={"days": 2.0, "seed": 7, "spots_per_board": 1})
        for c, served in ((rise0, ids[:300]), (set0, ids), (rise1, ids[300:])):
            for k, hid in enumerate(served):
                t = c.start_s + (k + 0.5) / len(served) * (c.end_s - c.start_s)
                vid = store.begin_visit(cid, hid, "T1", t - 1)
                store.record_observation(_obs(cid, vid, hid, t, 10.0))
                store.end_visit(vid, ended_s=t + 5, outcome="converged")
        store.finish_campaign(cid, start + 2 * 86400.0)
    doc = bb.report(bench500, tmp_path / "helicalib.db", start, 2.0, {"with turns": 140.0}, "with turns")
    rate = next(b["rate"] for k, b in doc["bounds"].items() if k.startswith("this run's band rate ("))
    assert rate == pytest.approx(300 / (4 * rise0.hours), abs=0.1)  # not the mean over the three crossings
    assert doc["band_points_per_open_board_hour"] == pytest.approx(rate, abs=0.1)
