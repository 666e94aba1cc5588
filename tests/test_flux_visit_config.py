"""Where a campaign's Fe and clean reflectivity come from: ``cameras[].flux_calibration`` (a FLUX.yaml,
its Fe on the HTTP camera) and ``calibration.reflectivity_clean``; the simulated camera's own Fe."""

from __future__ import annotations

import pytest
import yaml

from helicalib.config import load_field_config
from helicalib.devices.camera_http import cameras_from_config
from helicalib.errors import ConfigError


def test_reflectivity_clean_defaults_and_is_checked(demo_data, write_field):
    assert load_field_config(write_field(demo_data)).calibration.reflectivity_clean == 0.93
    demo_data["calibration"]["reflectivity_clean"] = 0.88
    assert load_field_config(write_field(demo_data)).calibration.reflectivity_clean == 0.88
    demo_data["calibration"]["reflectivity_clean"] = 1.2
    with pytest.raises(ConfigError) as err:
        load_field_config(write_field(demo_data))
    assert "calibration.reflectivity_clean" in str(err.value)


def test_http_cameras_get_fe_from_their_flux_yaml(demo_data, write_field, tmp_path):
    (tmp_path / "flux").mkdir()
    (tmp_path / "flux" / "c2.yaml").write_text(yaml.safe_dump(
        {"fe": {"value_wm2_per_grey": 3.1}, "cleanliness": {"reflectivity_clean": 0.9, "atmosphere": "hazy"}}))
    (tmp_path / "flux" / "c1.yaml").write_text(yaml.safe_dump(
        {"fe": {"two_radiometer": {"ea_wm2": 462.4, "eb_wm2": 100.0, "eb_prime_wm2": 95.0, "gav_grey": 190.0}}}))
    demo_data["cameras"][0]["flux_calibration"] = "flux/c1.yaml"   # two radiometers: Fe = Ea·Eb'/(Eb·Gav)
    demo_data["cameras"][1]["flux_calibration"] = "flux/c2.yaml"
    cfg = load_field_config(write_field(demo_data))
    assert cfg.flux_calibration_path(cfg.cameras[0]) == tmp_path / "flux" / "c1.yaml"
    cams = cameras_from_config(cfg)
    assert cams["T1"].fe_wm2_per_grey == pytest.approx(462.4 * 95.0 / (100.0 * 190.0))  # 2.312, the paper's
    assert cams["T1"].atmosphere == "clear"
    assert cams["T2"].fe_wm2_per_grey == pytest.approx(3.1)
    assert cams["T2"].atmosphere == "hazy"


def test_cameras_without_flux_calibration_measure_no_flux(demo_field_path):
    cams = cameras_from_config(load_field_config(demo_field_path))
    assert all(c.fe_wm2_per_grey is None for c in cams.values())


def test_missing_or_bad_flux_yaml_is_refused(demo_data, write_field, tmp_path):
    demo_data["cameras"][0]["flux_calibration"] = "nowhere.yaml"
    with pytest.raises(ConfigError) as err:
        load_field_config(write_field(demo_data))
    assert "cameras[0].flux_calibration: file not found" in str(err.value)
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({"fe": {}}))
    demo_data["cameras"][0]["flux_calibration"] = "bad.yaml"
    cfg = load_field_config(write_field(demo_data))
    with pytest.raises(ConfigError) as err:
        cameras_from_config(cfg)
    assert "bad.yaml" in str(err.value) and "fe" in str(err.value)


def test_simulated_camera_carries_the_scenarios_fe(demo_field_path):
    from helicalib.sim.camera import SimCamera, simulated_fe
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import CameraSpec, Scenario

    sc = Scenario(camera=CameraSpec(gain_counts_per_wm2=0.3, board_albedo=0.85))
    plant = SimulatedPlant(load_field_config(demo_field_path), sc, start_s=1.78e9)
    cam = SimCamera(plant, "C1")
    assert cam.fe_wm2_per_grey == pytest.approx(1.0 / (0.85 * 0.3)) == simulated_fe(sc)
    assert cam.atmosphere is None
