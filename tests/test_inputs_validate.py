"""``helicalib validate`` refuses what would fail later, each in one line naming the key path (and the
heliostat): a target no camera looks at, a heliostat behind its board, a boolean or a string where a
number belongs, two heliostats at one place, dimensions beyond their physical bounds, an endless
timeout. Every shipped field config still validates."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from helicalib.cli import main
from helicalib.config import load_field_config, parse_field_config
from helicalib.errors import ConfigError

from inputs_helpers import validate_problems

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = [ROOT / "field_config" / "demo_north.yaml", ROOT / "simulations" / "fields" / "bench500.yaml",
           ROOT / "simulations" / "fields" / "dots_cylinder.yaml"]



@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_every_shipped_field_validates(path, capsys):
    assert main(["validate", str(path), "--no-sweep", "--json"]) == 0


def test_a_target_without_a_camera_is_refused(tmp_path, demo_data, capsys):
    demo_data["cameras"] = [c for c in demo_data["cameras"] if c["target"] != "T2"]
    assert validate_problems(capsys, demo_data, tmp_path) == [
        "targets[1]: no camera looks at target 'T2' (give it one in cameras[], with target: T2); every board is "
        "measured by its camera"]


def test_a_spare_board_without_a_camera_is_refused_too(tmp_path, demo_data, capsys):
    """A free board lends itself to other boards' heliostats: no board may lack its camera."""
    spare = dict(demo_data["targets"][1], id="T9")
    spare["center_enu_m"] = [spare["center_enu_m"][0], spare["center_enu_m"][1], spare["center_enu_m"][2] + 40.0]
    demo_data["targets"].append(spare)
    assert any("no camera looks at target 'T9'" in p for p in validate_problems(capsys, demo_data, tmp_path))


def test_a_field_without_any_camera_is_a_description_only(demo_data):
    demo_data["cameras"] = []
    cfg = parse_field_config(demo_data)  # an import (PAINT) has no cameras: it is fitted and reported
    with pytest.raises(ConfigError, match=r"^cameras: none given: this field can be fitted, reported and exported, "
                                          r"not measured"):
        cfg.require_cameras()


def test_a_heliostat_behind_its_board_is_refused(tmp_path, demo_data, capsys):
    h = demo_data["heliostats"][4]
    board = next(t for t in demo_data["targets"] if t["id"] == h["target"])
    # mirror the pivot through the board's plane: same distance, behind the board
    c, n = board["center_enu_m"], board["normal_enu"]
    ahead = sum((p - q) * m for p, q, m in zip(h["position_enu_m"], c, n))
    h["position_enu_m"] = [p - 2 * ahead * m for p, m in zip(h["position_enu_m"], n)]
    problems = validate_problems(capsys, demo_data, tmp_path)
    assert problems == [f"heliostats[4].position_enu_m: '{h['id']}' stands {ahead:.1f} m behind the board of its "
                        f"target '{h['target']}' (the board faces north); its beam cannot reach the board's front"]


def test_two_heliostats_at_one_place_are_refused(tmp_path, demo_data, capsys):
    demo_data["heliostats"][7]["position_enu_m"] = list(demo_data["heliostats"][2]["position_enu_m"])
    a, b = demo_data["heliostats"][2]["id"], demo_data["heliostats"][7]["id"]
    assert validate_problems(capsys, demo_data, tmp_path) == [
        f"heliostats[7].position_enu_m: '{b}' stands 0.00 m from '{a}' (heliostats[2]): closer than half a mirror, "
        "the two would collide"]


def test_heliostats_a_mirror_apart_pass(demo_data):
    x, y, z = demo_data["heliostats"][2]["position_enu_m"]
    demo_data["heliostats"][7]["position_enu_m"] = [x + 2.3, y, z]  # 4.5 m mirrors: more than half a side apart
    parse_field_config(demo_data)


@pytest.mark.parametrize("edit, says", [
    (lambda d: d["site"].update(latitude_deg=True), "site.latitude_deg: expected a number, got True"),
    (lambda d: d["site"].update(altitude_m="1267"), "site.altitude_m: expected a number, got '1267'"),
    (lambda d: d["drives"]["tr20"]["actuators"][0].update(sign=True),
     "drives.tr20.actuators[0].sign: expected a number, got True"),
    (lambda d: d["calibration"].update(max_iterations=False), "calibration.max_iterations: expected a number, got False"),
    (lambda d: d["plant"]["scs"].update(port=True), "plant.scs.port: expected a number, got True"),
    (lambda d: d["plant"]["scs"].update(timeout_s=1e300), "plant.scs.timeout_s: Input should be less than or equal to 300"),
    (lambda d: d["drives"]["tr20"].update(mirror_size_m=[1e308, 4.5]),
     "drives.tr20.mirror_size_m[0]: Input should be less than or equal to 50"),
    (lambda d: d["targets"][0].update(size_m=[12, 1e9]), "targets[0].size_m[1]: Input should be less than or equal to 100"),
    (lambda d: d["drives"]["tr20"]["actuators"][1].update(arm_fixed_m=1e200),
     "drives.tr20.actuators[1].arm_fixed_m: Input should be less than or equal to 20"),
    (lambda d: d["drives"]["tr20"]["actuators"][1].update(stroke_range_mm=[0, 1e12]),
     "drives.tr20.actuators[1].stroke_range_mm: [1] 1e+12 mm is beyond the physical bound of 100000 mm"),
    (lambda d: d["drives"]["tr20"]["actuators"][0].update(gamma0_deg=1e6),
     "drives.tr20.actuators[0].gamma0_deg: Input should be less than or equal to 360"),
    (lambda d: d["calibration"].update(settle_timeout_s=1e300),
     "calibration.settle_timeout_s: Input should be less than or equal to 86400"),
    (lambda d: d["gating"].update(stow_wind_ms=1e9), "gating.stow_wind_ms: Input should be less than or equal to 100"),
    (lambda d: d["acceptance"].update(high_window_h=1e300), "acceptance.high_window_h: Input should be less than or equal to 24"),
    (lambda d: d["acceptance"].update(min_points=10**400), "acceptance.min_points: Input should be less than or equal to 100000"),
    (lambda d: d["tracking_test"].update(threshold_mrad=1e308),
     "tracking_test.threshold_mrad: Input should be less than or equal to 1000"),
    (lambda d: d["targets"][1].update(standby_offset_m=[1e7, 0.0]),
     "targets[1].standby_offset_m: [0] 1e+07 m is beyond the physical bound of 1000 m"),
    (lambda d: d["cameras"][0].update(intrinsics={"fx": 1e300, "fy": 2400, "cx": 640, "cy": 512}),
     "cameras[0].intrinsics.fx: Input should be less than or equal to 1000000"),
    (lambda d: d["cameras"][0].update(distortion=[1e30, 0, 0, 0, 0]),
     "cameras[0].distortion: [0] 1e+30 is beyond the physical bound of 1000"),
    (lambda d: d["plant"]["scs"].update(host=""), "plant.scs.host: String should have at least 1 character"),
])
def test_values_that_fail_later_are_refused_by_key(tmp_path, demo_data, edit, says, capsys):
    edit(demo_data)
    assert validate_problems(capsys, demo_data, tmp_path) == [says]


def test_refusals_reach_run_before_any_plant_contact(tmp_path, demo_data, capsys):
    demo_data["plant"]["scs"]["timeout_s"] = 1e300  # an OverflowError in run, before
    path = tmp_path / "f.yaml"
    path.write_text(yaml.safe_dump(demo_data, sort_keys=False))
    with pytest.raises(ConfigError, match=r"plant.scs.timeout_s: Input should be less than or equal to 300"):
        load_field_config(path)
