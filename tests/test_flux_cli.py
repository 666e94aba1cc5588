"""``helicalib flux`` end to end on PNG files, and FLUX.yaml validation."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import yaml

from helicalib.cli import main
from helicalib.config import load_field_config
from helicalib.errors import ConfigError
from helicalib.flux.config import load_correction_data, load_flux_calibration
from helicalib.flux.synth import homography_uv_to_px, render_frame

FE = 30.0
E0, SIGMA, CUV = 4000.0, 0.9, (-1.0, 0.8)


def knee(x):
    x = np.asarray(x, dtype=float)
    return np.where(x <= 120.0, x, 120.0 + 135.0 * (1.0 - np.exp(-(x - 120.0) / 135.0)))


def beam(u, v):
    return E0 * np.exp(-((u - CUV[0]) ** 2 + (v - CUV[1]) ** 2) / (2 * SIGMA**2))


@pytest.fixture(scope="module")
def files(tmp_path_factory, demo_field_path):
    """Frames of demo target T1 seen by camera C1, plus the calibration files and a FLUX.yaml."""
    d = tmp_path_factory.mktemp("flux")
    cfg = load_field_config(demo_field_path)
    target, cam = cfg.target("T1"), cfg.cameras_for("T1")[0]
    w, h = cam.resolution_px
    hom = homography_uv_to_px(target.center_enu_m, target.frame_enu, cam.position_enu_m, cam.camera_matrix)
    yy, xx = np.indices((h, w), dtype=float)
    gain = 1.0 - 0.15 * ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    gain /= gain.mean()
    marks = target.marks.model_dump()
    kw = dict(fe_wm2_per_grey=FE, dark_grey=5.0, gain=gain, response=knee, noise_grey=0.7, marks=marks)
    cv2.imwrite(str(d / "before.png"), render_frame((h, w), hom, target.size_m, None, rng=np.random.default_rng(1), **kw))
    cv2.imwrite(str(d / "after.png"), render_frame((h, w), hom, target.size_m, beam, rng=np.random.default_rng(2), **kw))
    rng = np.random.default_rng(3)
    cv2.imwrite(str(d / "dark.png"), np.clip(np.rint(knee(5.0 + rng.normal(0, 0.7, (h, w)))), 0, 255).astype(np.uint8))
    cv2.imwrite(str(d / "flat.png"), np.clip(np.rint(knee(5.0 + 110.0 * gain)), 0, 255).astype(np.uint8))
    b = np.linspace(0, 300, 61)
    (d / "response.csv").write_text("input,grey\n" + "".join(f"{x},{y}\n" for x, y in zip(b, knee(b))))
    flux_yaml = {
        "camera": "C1",
        "grid_cell_m": 0.02,
        "fe": {"value_wm2_per_grey": FE},
        "corrections": {"dark": {"frame": "dark.png"}, "nonlinearity": {"curve_csv": "response.csv"},
                        "flat_field": {"frame": "flat.png"}},
        "errors": {"dark": 0.01, "nonlinearity": 0.03},
    }
    (d / "FLUX.yaml").write_text(yaml.safe_dump(flux_yaml))
    (d / "TARGET.yaml").write_text(yaml.safe_dump({"targets": [target.model_dump()], "cameras": [cam.model_dump()]}))
    return d


def test_flux_command_json_and_plot(files, demo_field_path, capsys):
    out_png = files / "map.png"
    rc = main(["flux", str(files / "before.png"), str(files / "after.png"), "--field", str(demo_field_path),
               "--target-id", "T1", "--calibration", str(files / "FLUX.yaml"), "--json", "--plot", str(out_png)])
    assert rc == 0
    r = json.loads(capsys.readouterr().out)
    power = 2 * math.pi * SIGMA**2 * E0
    print("cli", r["power_w"] / power - 1, r["peak_wm2"] / E0 - 1, r["centre_uv_m"])
    assert r["power_w"] == pytest.approx(power, rel=0.01)
    assert r["peak_wm2"] == pytest.approx(E0, rel=0.03)
    assert r["centre_uv_m"] == pytest.approx(list(CUV), abs=0.01)
    assert r["system_error"] == pytest.approx(math.hypot(0.01, 0.03), rel=1e-3)
    c = r["corrections"]
    assert c["dark"]["applied"] and c["nonlinearity"]["applied"] and c["flat_field"]["applied"]
    assert c["dark"]["dark_grey"] == pytest.approx(5.0, abs=0.05)
    assert c["nonlinearity"]["k1_grey_per_input"] == pytest.approx(1.0)
    assert not c["distortion"]["applied"] and not c["non_lambertian"]["applied"]
    img = cv2.imread(str(out_png))
    assert img is not None and img.shape[0] > 200


def test_flux_command_with_target_file_text_output(files, capsys):
    rc = main(["flux", str(files / "before.png"), str(files / "after.png"), "--target", str(files / "TARGET.yaml"),
               "--calibration", str(files / "FLUX.yaml")])
    assert rc == 0
    text = capsys.readouterr().out
    assert "power" in text and "kW on the board" in text and "dark, nonlinearity, flat_field, perspective" in text


def test_flux_command_cleanliness(files, demo_field_path, capsys):
    data = yaml.safe_load((files / "FLUX.yaml").read_text())
    data["cleanliness"] = {"reflectivity_clean": 0.93}
    (files / "FLUX_c.yaml").write_text(yaml.safe_dump(data))
    rc = main(["flux", str(files / "before.png"), str(files / "after.png"), "--field", str(demo_field_path),
               "--target-id", "T1", "--calibration", str(files / "FLUX_c.yaml"), "--json",
               "--heliostat", "H0007", "--time", "2026-06-21T13:00:00+08:00", "--dni-wm2", "900"])
    assert rc == 0
    c = json.loads(capsys.readouterr().out)["cleanliness"]
    expected = 900 * 4.5 * 4.5 * 0.93 * c["cos_incidence"] * c["attenuation"]
    assert c["expected_clean_power_w"] == pytest.approx(expected, rel=1e-4)
    assert c["cleanliness"] == pytest.approx(c["power_w"] / expected, rel=1e-3)
    # the beam lands at the map's flux-weighted centre (the beam's centre CUV within the documented 10 mm) and
    # leaves from the mirror centre, within the drive's mirror offset of the heliostat's pivot
    cfg = load_field_config(demo_field_path)
    spot = np.asarray(cfg.target("T1").uvw_to_enu(np.asarray(CUV)))
    assert c["aim_enu_m"] == pytest.approx(list(spot), abs=0.01)
    pivot_range = float(np.linalg.norm(spot - np.asarray(cfg.heliostat("H0007").position_enu_m)))
    assert abs(c["slant_range_m"] - pivot_range) <= cfg.drive_of("H0007").mirror_offset_m + 0.01


def test_missing_frame_and_bad_flux_yaml_are_one_line_errors(files, demo_field_path, tmp_path, capsys):
    rc = main(["flux", str(tmp_path / "nope.png"), str(files / "after.png"), "--field", str(demo_field_path),
               "--target-id", "T1", "--calibration", str(files / "FLUX.yaml")])
    assert rc == 1
    assert "nope.png" in capsys.readouterr().err
    bad = tmp_path / "FLUX.yaml"
    bad.write_text(yaml.safe_dump({"fe": {"value_wm2_per_grey": 2.0, "sun": {"dni_wm2": 900}}, "colour": 1}))
    with pytest.raises(ConfigError) as err:
        load_flux_calibration(bad)
    lines = err.value.problems
    assert f"{bad}: colour: unknown key" in lines
    assert any(line.startswith(f"{bad}: fe.sun.sun_grey_sum: missing required key") for line in lines)


def test_flux_yaml_files_are_resolved_and_checked(tmp_path):
    (tmp_path / "FLUX.yaml").write_text(yaml.safe_dump({
        "fe": {"two_radiometer": {"ea_wm2": 462.4, "eb_wm2": 100, "eb_prime_wm2": 95, "gav_grey": 190}},
        "corrections": {"dark": {"frame": "missing.png"}}}))
    fc = load_flux_calibration(tmp_path / "FLUX.yaml")
    assert fc.fe_wm2_per_grey() == pytest.approx(2.312)
    with pytest.raises(ConfigError, match=r"corrections\.dark\.frame: file not found"):
        load_correction_data(fc)
    (tmp_path / "F2.yaml").write_text(yaml.safe_dump({"fe": {"value_wm2_per_grey": 1.0, "two_radiometer": {
        "ea_wm2": 1, "eb_wm2": 1, "eb_prime_wm2": 1, "gav_grey": 1}}}))
    with pytest.raises(ConfigError, match="fe: give exactly one of"):
        load_flux_calibration(tmp_path / "F2.yaml")


def test_shipped_flux_demo_is_the_simulated_demo_camera(demo_field_path):
    """flux_demo.yaml describes camera C1 as the simulated plant renders it (default scenario)."""
    from helicalib.sim.scenario import Scenario

    fc = load_flux_calibration(demo_field_path.parent / "flux_demo.yaml")
    sc = Scenario()
    assert fc.camera == "C1"
    assert fc.fe_wm2_per_grey() == pytest.approx(1.0 / (sc.camera.board_albedo * sc.camera.gain_counts_per_wm2),
                                                 rel=1e-6)
    assert fc.cleanliness.reflectivity_clean == sc.optics.reflectivity
    assert fc.cleanliness.atmosphere == "none"            # the simulated plant renders no attenuation
    data = load_correction_data(fc)                       # a linear, offset-free, uniform, Lambertian camera
    assert data.dark_grey is None and data.response is None and data.flat_factors is None
    assert fc.corrections.non_lambertian is None
