"""``helicalib aim`` and the stroke-feasibility sweep of ``helicalib validate`` (in-process CLI)."""

from __future__ import annotations

import json
import math

import numpy as np

from helicalib.cli import main
from helicalib.geometry import optics


def _run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_aim_json_matches_hand_computed_tilt_roll_kinematics(capsys, demo_field_path):
    code, out, _ = _run(capsys, "aim", str(demo_field_path), "--heliostat", "H0001", "--target", "T1",
                        "--time", "2026-06-21T12:00:00+08:00", "--json")
    assert code == 0
    d = json.loads(out)
    assert d["in_range"] and d["target"] == "T1"
    # demo drive tr20 by hand: ℓ = ℓ0 + s/1000, γ = acos((ra² + rb² − ℓ²)/(2 ra rb)), θ = γ − γ0 (sign +1)
    acts = [(1.6, 1.1, 60.0, 0.80), (1.2, 0.9, 90.0, 0.50)]
    theta = []
    for s, (ra, rb, g0, l0) in zip(d["strokes_mm"], acts):
        length = l0 + s / 1000.0
        theta.append(math.acos((ra * ra + rb * rb - length * length) / (2 * ra * rb)) - math.radians(g0))
    np.testing.assert_allclose(np.degrees(theta), d["angles_deg"], atol=1e-9)
    t1, t2 = theta  # tilt-roll: n = R(x, θ1)·R(y, θ2)·z
    n = np.array([math.sin(t2), -math.sin(t1) * math.cos(t2), math.cos(t1) * math.cos(t2)])
    np.testing.assert_allclose(n, d["normal_enu"], atol=1e-12)
    # the beam from the mirror centre (pivot + 0.25 m · n) reaches T1's centre
    pivot = np.array([-51.18, 47.76, 4.3])
    sun = np.array(d["sun"]["vector_enu"])
    r = 2 * (sun @ n) * n - sun
    assert 1000 * optics.angle_between_rad(r, np.array([9.0, 8.0, 95.0]) - (pivot + 0.25 * n)) < 1e-6
    # sun position at the site (azimuth from north, clockwise), consistent with the vector
    az, el = math.radians(d["sun"]["azimuth_deg"]), math.radians(d["sun"]["elevation_deg"])
    np.testing.assert_allclose(sun, [math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)], atol=1e-9)


def test_aim_text_and_unknown_heliostat(capsys, demo_field_path):
    code, out, _ = _run(capsys, "aim", str(demo_field_path), "--heliostat", "H0002", "--time", "2026-03-20T13:00:00+08:00")
    assert code == 0 and "in range" in out and "T2" in out
    code, _, err = _run(capsys, "aim", str(demo_field_path), "--heliostat", "H9999", "--time", "2026-03-20T13:00:00+08:00")
    assert code == 1 and "H9999" in err


def test_aim_with_params_file_moves_strokes(capsys, demo_field_path, tmp_path):
    base = json.loads(_run(capsys, "aim", str(demo_field_path), "--heliostat", "H0003", "--time",
                           "2026-03-20T13:00:00+08:00", "--json")[1])
    p = tmp_path / "params.json"
    p.write_text(json.dumps({"stroke_offset_1_mm": 2.5}))
    moved = json.loads(_run(capsys, "aim", str(demo_field_path), "--heliostat", "H0003", "--time",
                            "2026-03-20T13:00:00+08:00", "--params", str(p), "--json")[1])
    np.testing.assert_allclose(np.subtract(moved["strokes_mm"], base["strokes_mm"]), [-2.5, 0.0], atol=1e-9)
    # dead bands: half of each band toward the arrival direction; without --approach, none
    p.write_text(json.dumps({"backlash_1_mm": 0.6, "backlash_2_mm": 0.4}))
    args = ("aim", str(demo_field_path), "--heliostat", "H0003", "--time", "2026-03-20T13:00:00+08:00",
            "--params", str(p), "--json")
    middle = json.loads(_run(capsys, *args)[1])
    arrived = json.loads(_run(capsys, *args, "--approach", "1", "-1")[1])
    np.testing.assert_allclose(middle["strokes_mm"], base["strokes_mm"], atol=1e-9)
    np.testing.assert_allclose(np.subtract(arrived["strokes_mm"], base["strokes_mm"]), [0.3, -0.2], atol=1e-9)
    assert arrived["approach"] == [1, -1]
    p.write_text(json.dumps({"bogus": 1}))
    code, _, err = _run(capsys, "aim", str(demo_field_path), "--heliostat", "H0003", "--time",
                        "2026-03-20T13:00:00+08:00", "--params", str(p))
    assert code == 1 and "bogus" in err


def test_validate_sweep_demo_feasible(capsys, demo_field_path):
    code, out, _ = _run(capsys, "validate", str(demo_field_path), "--json")
    assert code == 0
    sweep = json.loads(out)["stroke_feasibility"]
    assert sweep["feasible"] and sweep["worst_margin_mm"] > 0
    assert len(sweep["heliostats"]) == 40 and sweep["sun_positions"] > 500
    used = sweep["drives"]["tr20"]["stroke_used_mm"]
    assert 0 <= used[0][0] < used[0][1] <= 1850 and 0 <= used[1][0] < used[1][1] <= 1590


def test_validate_sweep_reports_a_short_actuator(capsys, demo_data, write_field):
    demo_data["drives"]["tr20"]["actuators"][1]["stroke_range_mm"] = [0, 1000]
    path = write_field(demo_data)
    code, out, _ = _run(capsys, "validate", str(path))
    assert code == 0
    assert "OUT OF RANGE" in out
    code, out, _ = _run(capsys, "validate", str(path), "--json")
    sweep = json.loads(out)["stroke_feasibility"]
    assert not sweep["feasible"] and sweep["worst_margin_mm"] < 0
    bad = sweep["heliostats"][sweep["out_of_range"][0]]
    assert bad["worst_actuator"] == 2 and bad["out_of_range_fraction"] > 0
    # and the existing summary is still there
    assert json.loads(out)["heliostats"] == 40
