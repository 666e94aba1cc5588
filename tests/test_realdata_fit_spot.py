"""Real-data fit (leave-one-out on AA39) and single-frame spot centres on the real AA23 crops."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from helicalib.calibration.observations import Observation, read_observations, write_observations
from helicalib.cli import main
from helicalib.errors import MeasurementError
from helicalib.realdata import paint
from helicalib.vision.single_frame import pixel_to_uv_m, spot_centre_single_frame

DATA = Path(__file__).parent / "data" / "paint"


@pytest.fixture(scope="module")
def imported_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("paint")
    assert main(["import-paint", str(DATA), "--out", str(out)]) == 0
    return out


def test_fit_loo_aa39_reports_finite_figures_better_than_nominal(imported_dir, capsys):
    capsys.readouterr()
    rc = main(["fit", str(imported_dir / "observations.csv"), "--field", str(imported_dir / "field.yaml"),
               "--heliostat", "AA39", "--loo", "--json"])
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    for key in ("in_sample_normal_mrad_mean", "loo_normal_mrad_mean", "loo_beam_m_mean", "nominal_normal_mrad_mean"):
        assert np.isfinite(rep[key]), key
    assert len(rep["loo_normal_mrad"]) == 6
    assert rep["in_sample_normal_mrad_mean"] < rep["loo_normal_mrad_mean"] < rep["nominal_normal_mrad_mean"]
    # the issue's bar: better than the peers' 4-tilt least squares, 2.68 mrad leave-one-out on AA39
    assert rep["loo_normal_mrad_mean"] < 2.68
    assert set(rep["parameters"]) >= {"stroke_offset_1_mm", "pedestal_tilt_n_mrad", "pivot_de_m"}
    assert all(np.isfinite(p["value"]) and p["sigma"] >= 0 for p in rep["parameters"].values())


def test_fit_refuses_unknown_prior_and_too_few_rows(imported_dir):
    assert main(["fit", str(imported_dir / "observations.csv"), "--field", str(imported_dir / "field.yaml"),
                 "--heliostat", "AA39", "--prior", "nonsense=1"]) == 1


def test_observations_roundtrip_and_bad_header(tmp_path):
    row = Observation("H1", "2024-06-01T10:00:00+00:00", 0.0, 0.6, 0.8, 12.5, 300.25, "T1", 1.0, 2.0, 3.0, 0.1, -0.2,
                      "grlm-centroid", "campaign", "42")
    p = write_observations(tmp_path / "o.csv", [row], ["a comment"])
    assert read_observations(p) == [row]
    bad = tmp_path / "bad.csv"
    bad.write_text("heliostat,when\nH1,now\n")
    with pytest.raises(MeasurementError, match="line 1: expected the header"):
        read_observations(bad)


def _crop_centre_uv(t: paint.PaintTarget, fraction_xy) -> np.ndarray:
    """Crop fraction → target (u, v) through the board's measured corners (bilinear)."""
    a, b = fraction_xy
    c = t.corners_enu
    p = (1 - a) * (1 - b) * c["upper_left"] + a * (1 - b) * c["upper_right"] + (1 - a) * b * c["lower_left"] \
        + a * b * c["lower_right"]
    return paint.target_uv(t, p)


def test_single_frame_centres_on_real_aa23_crops_near_helios():
    imp = paint.scan([DATA])
    dist = []
    for rec in [r for r in imp.records if r.heliostat_id == "AA23"]:
        t = imp.tower.targets[rec.target_name]
        img = cv2.imread(str(DATA / "AA23" / f"{rec.record_id}-cropped.png"), cv2.IMREAD_GRAYSCALE)
        res = spot_centre_single_frame(img, t.size_m)
        uv = _crop_centre_uv(t, res.fraction_xy)
        dist.append(np.linalg.norm(uv - paint.target_uv(t, paint.spot_enu(imp, rec, "HeliOS"))))
    assert len(dist) == 10
    assert np.median(dist) <= 0.3
    # the goal: mean <= 0.15 m and max <= 0.5 m from HeliOS
    assert np.mean(dist) <= 0.15 and np.max(dist) <= 0.5


def test_spot_single_frame_cli_subprocess_on_real_crop():
    """The issue's exact command, ``helicalib spot FRAME --single-frame --board-size-m W H --json``, as a
    process, on the AA23 crop with the sky-lit band and shadow edge (240796): no --target needed."""
    import subprocess
    import sys

    imp = paint.scan([DATA])
    rec = next(r for r in imp.records if r.record_id == "240796")
    t = imp.tower.targets[rec.target_name]
    frame = DATA / "AA23" / "240796-cropped.png"
    w, h = t.size_m
    r = subprocess.run([sys.executable, "-m", "helicalib", "spot", str(frame), "--single-frame", "--board-size-m",
                        f"{w}", f"{h}", "--json"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["method"] == "single-frame"
    cx, cy = out["centre_px"]
    assert np.allclose(out["offset_m"], pixel_to_uv_m(cx, cy, (256, 256), (w, h)), atol=1e-9)
    assert np.allclose(out["fraction_xy"], [cx / 256, cy / 256])
    # the centre, through the board's measured corners, against the HeliOS centre of the record
    uv = _crop_centre_uv(t, out["fraction_xy"])
    assert np.linalg.norm(uv - paint.target_uv(t, paint.spot_enu(imp, rec, "HeliOS"))) <= 0.5
    # without --board-size-m (and no target) it is a one-line user error
    r = subprocess.run([sys.executable, "-m", "helicalib", "spot", str(frame), "--single-frame"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "--board-size-m" in r.stderr


def test_fit_uses_calibration_fit_error_model(imported_dir, capsys):
    """One fitter: ``helicalib fit`` gives what calibration.fit.fit_error_model gives with the PAINT priors."""
    from helicalib.calibration.fit import FitOptions, FitPoints, fit_error_model
    from helicalib.calibration.observations import observations_arrays
    from helicalib.config import load_field_config
    from helicalib.geometry import error_model as em
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.realdata.fitting import REALDATA_PRIOR_SIGMA

    capsys.readouterr()
    assert main(["fit", str(imported_dir / "observations.csv"), "--field", str(imported_dir / "field.yaml"),
                 "--heliostat", "AA39", "--json", "--prior", "pivot_du_m=0"]) == 0
    rep = json.loads(capsys.readouterr().out)
    cfg = load_field_config(imported_dir / "field.yaml")
    a = observations_arrays(read_observations(imported_dir / "observations.csv", "AA39"))
    priors = {**REALDATA_PRIOR_SIGMA, "pivot_du_m": 0.0}
    res = fit_error_model(HeliostatModel.from_config(cfg, ["AA39"]), FitPoints(a["strokes_mm"], a["sun_enu"], a["spot_enu"]),
                          FitOptions(prior_sigma=priors, free=[n for n in em.NAMES if priors[n] > 0], loss="linear",
                                     sigma_mrad=2.0, residual_kind="normal"))
    got = np.array([rep["parameters"][n]["value"] for n in em.NAMES])
    assert np.allclose(got, res.params, rtol=1e-6, atol=1e-9)
    assert rep["parameters"]["pivot_du_m"]["value"] == 0.0 and rep["parameters"]["pivot_du_m"]["sigma"] == 0.0


def _synthetic_board(centre_xy, glint=True, seed=0):
    rng = np.random.default_rng(seed)
    h = w = 256
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    img = 120 + 25 * (xx / w) - 15 * (yy / h)  # shading
    img[:, ::32] -= 40  # grid lines
    img[::32, :] -= 40
    # elongated spot rotated 45°
    dx, dy = xx - centre_xy[0], yy - centre_xy[1]
    a, b = (dx + dy) / np.sqrt(2), (dx - dy) / np.sqrt(2)
    img += 60 * np.exp(-0.5 * ((a / 40) ** 2 + (b / 15) ** 2))
    if glint:
        img += 120 * np.exp(-0.5 * (((xx - 250) / 6) ** 2 + ((yy - 6) / 6) ** 2))
    img += rng.normal(0, 1.5, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("centre", [(128.0, 128.0), (100.0, 150.0), (160.0, 90.0)])
def test_single_frame_synthetic_spot_with_grid_shading_and_glint(centre):
    res = spot_centre_single_frame(_synthetic_board(centre), (8.0, 8.0))
    assert abs(res.centre_px[0] - centre[0]) < 3 and abs(res.centre_px[1] - centre[1]) < 3
    u, v = pixel_to_uv_m(centre[0], centre[1], (256, 256), (8.0, 8.0))
    assert abs(res.centre_uv_m[0] - u) < 0.1 and abs(res.centre_uv_m[1] - v) < 0.1


def test_pixel_to_uv_convention():
    assert pixel_to_uv_m(128, 128, (256, 256), (8, 6)) == (0.0, 0.0)
    assert pixel_to_uv_m(256, 0, (256, 256), (8, 6)) == (4.0, 3.0)  # image top-right = +u, +v


def test_spot_single_command_json(tmp_path, capsys):
    f = tmp_path / "frame.png"
    cv2.imwrite(str(f), _synthetic_board((128.0, 128.0)))
    assert main(["spot-single", str(f), "--board-size-m", "8", "8", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert abs(out["centre_uv_m"][0]) < 0.1 and abs(out["centre_uv_m"][1]) < 0.1


def test_single_frame_refuses_empty_board():
    img = np.full((128, 128), 140, np.uint8)
    with pytest.raises(MeasurementError, match="no spot"):
        spot_centre_single_frame(img, (8.0, 8.0))


def test_spot_extension_hook_single_frame(tmp_path, capsys):
    import argparse

    from helicalib.commands import spot_single as single_frame

    p = argparse.ArgumentParser()
    p.add_argument("frames", nargs="+")
    p.add_argument("--json", action="store_true")
    single_frame.add_arguments(p)
    f = tmp_path / "frame.png"
    cv2.imwrite(str(f), _synthetic_board((100.0, 150.0)))
    args = p.parse_args([str(f), "--single-frame", "--board-size-m", "8", "8", "--json"])
    assert single_frame.wants(args)
    assert single_frame.run_spot(args, None, None) == 0
    out = json.loads(capsys.readouterr().out)
    u, v = pixel_to_uv_m(100.0, 150.0, (256, 256), (8.0, 8.0))
    assert abs(out["offset_m"][0] - u) < 0.1 and abs(out["offset_m"][1] - v) < 0.1
    assert not single_frame.wants(p.parse_args([str(f)]))
