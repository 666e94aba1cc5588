"""Where a campaign's Fe and clean reflectivity come from: ``cameras[].flux_calibration`` (a FLUX.yaml,
its Fe on the HTTP camera) and ``calibration.reflectivity_clean``; the simulated camera's own Fe."""

from __future__ import annotations

import pytest
import yaml

from helicalib.campaign.sensor import camera_sensors
from helicalib.config import load_field_config
from helicalib.devices.connect import cameras_from_config
from helicalib.errors import ConfigError


def test_reflectivity_clean_defaults_and_is_checked(demo_data, write_field):
    assert load_field_config(write_field(demo_data)).calibration.reflectivity_clean == 0.93
    demo_data["calibration"]["reflectivity_clean"] = 0.88
    assert load_field_config(write_field(demo_data)).calibration.reflectivity_clean == 0.88
    demo_data["calibration"]["reflectivity_clean"] = 1.2
    with pytest.raises(ConfigError) as err:
        load_field_config(write_field(demo_data))
    assert "calibration.reflectivity_clean" in str(err.value)


def test_camera_sensors_get_fe_from_their_cameras_flux_yaml(demo_data, write_field, tmp_path):
    """The HTTP camera is a device (frames only); each board's sensor takes the Fe and atmosphere
    of its camera's FLUX.yaml from the config."""
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
    assert not any(hasattr(c, "fe_wm2_per_grey") for c in cams.values())
    sensors = camera_sensors(cfg, cams)
    assert sensors["T1"].fe_wm2_per_grey == pytest.approx(462.4 * 95.0 / (100.0 * 190.0))  # 2.312, the paper's
    assert sensors["T1"].atmosphere == "clear"
    assert sensors["T2"].fe_wm2_per_grey == pytest.approx(3.1)
    assert sensors["T2"].atmosphere == "hazy"
    given = camera_sensors(cfg, cams, flux={"T2": (1.5, None)})  # a composition root that knows better
    assert given["T2"].fe_wm2_per_grey == 1.5 and given["T2"].atmosphere is None
    assert given["T1"].fe_wm2_per_grey == pytest.approx(2.312)


def test_cameras_without_flux_calibration_measure_no_flux(demo_field_path):
    cfg = load_field_config(demo_field_path)
    sensors = camera_sensors(cfg, cameras_from_config(cfg))
    assert all(s.fe_wm2_per_grey is None for s in sensors.values())


def test_missing_or_bad_flux_yaml_is_refused(demo_data, write_field, tmp_path):
    demo_data["cameras"][0]["flux_calibration"] = "nowhere.yaml"
    with pytest.raises(ConfigError) as err:
        load_field_config(write_field(demo_data))
    assert "cameras[0].flux_calibration: file not found" in str(err.value)
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({"fe": {}}))
    demo_data["cameras"][0]["flux_calibration"] = "bad.yaml"
    cfg = load_field_config(write_field(demo_data))
    with pytest.raises(ConfigError) as err:
        camera_sensors(cfg, cameras_from_config(cfg))
    assert "bad.yaml" in str(err.value) and "fe" in str(err.value)


def test_the_simulated_plants_flux_is_the_scenarios_fe(demo_field_path):
    from helicalib.sim.camera import SimCamera, simulated_fe, simulated_flux
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import CameraSpec, Scenario

    sc = Scenario(camera=CameraSpec(gain_counts_per_wm2=0.3, board_albedo=0.85))
    plant = SimulatedPlant(load_field_config(demo_field_path), sc, start_s=1.78e9)
    cam = SimCamera(plant, "C1")
    assert cam.fe_wm2_per_grey == pytest.approx(1.0 / (0.85 * 0.3)) == simulated_fe(sc)
    cfg = plant.cfg
    assert simulated_flux(cfg, sc) == {t.id: (simulated_fe(sc), None) for t in cfg.targets}
    sensors = camera_sensors(cfg, {"T1": cam}, flux=simulated_flux(cfg, sc))
    assert sensors["T1"].fe_wm2_per_grey == simulated_fe(sc) and sensors["T1"].atmosphere is None
