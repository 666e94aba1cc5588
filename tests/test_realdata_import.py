"""PAINT import: conversions checked against the README's figures and formulas, and the imported
custom drive against the independent PAINT kinematics (nominal agreement ≤ 0.01 mrad)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from helicalib.calibration.observations import read_observations
from helicalib.cli import main
from helicalib.config import load_field_config, parse_field_config
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.optics import angle_between_rad
from helicalib.realdata import geodesy, paint
from helicalib.realdata.paint_kinematics import normal_error_mrad, sun_vector_paint

DATA = Path(__file__).parent / "data" / "paint"
PLANT = (50.913421122592574, 6.387824755874856, 87.0)


@pytest.fixture(scope="module")
def imported():
    imp = paint.scan([DATA])
    cfg = parse_field_config(paint.field_config_dict(imp))
    return imp, cfg


def test_wgs84_to_plant_enu_matches_readme_positions():
    aa39 = json.loads((DATA / "AA39" / "AA39-heliostat-properties.json").read_text())["heliostat_position"]
    enu = geodesy.wgs84_to_enu(aa39, PLANT)
    np.testing.assert_allclose(enu, [13.258, 24.716, 1.689], atol=0.002)


def test_wgs84_to_enu_basic_geometry():
    # straight above the reference: pure up
    np.testing.assert_allclose(geodesy.wgs84_to_enu([PLANT[0], PLANT[1], 187.0], PLANT), [0, 0, 100.0], atol=1e-6)
    # 1 arc-second of latitude north: the meridian arc (M + h)·dφ with M = a(1-e²)/(1-e² sin²φ)^1.5
    e2 = geodesy.WGS84_F * (2 - geodesy.WGS84_F)
    phi = math.radians(PLANT[0])
    m = geodesy.WGS84_A * (1 - e2) / (1 - e2 * math.sin(phi) ** 2) ** 1.5
    enu = geodesy.wgs84_to_enu([PLANT[0] + 1 / 3600, PLANT[1], PLANT[2]], PLANT)
    assert enu[1] == pytest.approx((m + PLANT[2]) * math.radians(1 / 3600), rel=1e-6)  # arc at height h
    assert abs(enu[0]) < 1e-6
    # equator / prime meridian is at (a + h, 0, 0) in ECEF
    np.testing.assert_allclose(geodesy.geodetic_to_ecef(0.0, 0.0, 10.0), [geodesy.WGS84_A + 10, 0, 0], atol=1e-6)


def test_gauss_krueger_offsets_to_enu_matches_paint_conversion():
    # HeliOS position of AA23 (x=-57.2, y=25, z=88.711); README: ENU (-57.067, 25.300, 1.711) via PAINT/pyproj
    enu = geodesy.gauss_krueger_offset_to_enu(-57.2, 25.0, 88.711, 87.0)
    np.testing.assert_allclose(enu, [-57.067, 25.300, 1.711], atol=0.005)


def test_sun_azimuth_origin_is_south_positive_east():
    np.testing.assert_allclose(sun_vector_paint(0.0, 0.0), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(sun_vector_paint(90.0, 0.0), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(sun_vector_paint(-90.0, 30.0), [-math.cos(math.radians(30)), 0, 0.5], atol=1e-12)


def test_import_finds_heliostats_records_and_targets(imported):
    imp, cfg = imported
    assert set(imp.heliostats) == {"AA23", "AA39"}
    counts = {h: sum(r.heliostat_id == h for r in imp.records) for h in ("AA23", "AA39")}
    assert counts == {"AA23": 10, "AA39": 6}
    assert {t.id for t in cfg.targets} == {"solar_tower_juelich_upper", "solar_tower_juelich_lower", "multi_focus_tower"}
    assert all(t.marks is None for t in cfg.targets)
    np.testing.assert_allclose(cfg.heliostat("AA23").position_enu_m, [-57.067, 25.300, 1.711], atol=0.005)
    # the lower STJ board is ≈ 8.6 m wide and 7.2 m tall (PAINT's STJ ENU corners: ±4.3 m, 39.48..46.70 m)
    w, h = cfg.target("solar_tower_juelich_upper").size_m
    assert w == pytest.approx(8.62, abs=0.03) and h == pytest.approx(7.22, abs=0.03)


def test_motor_steps_to_stroke_and_actuator_length(imported):
    imp, cfg = imported
    props = json.loads((DATA / "AA39" / "AA39-heliostat-properties.json").read_text())
    acts = props["kinematics_properties"]["actuators"]
    drive = cfg.drive_of("AA39")
    for act, cfg_act in zip(acts, drive.actuators):
        steps = 30000
        stroke = float(paint.steps_to_stroke_mm(steps, imp.heliostats["AA39"].kinematics.actuators[acts.index(act)]))
        assert stroke == pytest.approx(1000 * steps / act["increment"], rel=1e-12)
        # our actuator length at that stroke = PAINT's L(m) = m / increment + initial_stroke_length
        assert cfg_act.length_at_zero_stroke_m + stroke / 1000 == pytest.approx(
            steps / act["increment"] + act["initial_stroke_length"], abs=1e-12)
        assert {cfg_act.arm_fixed_m, cfg_act.arm_moving_m} == {act["offset"], act["pivot_radius"]}


def _readme_normal(props: dict, steps) -> np.ndarray:
    """The README's formula, written out here a third time: Re(θ1) Ru(θ2) (0, -1, 0)."""
    th = []
    for i, (a, m) in enumerate(zip(props["kinematics_properties"]["actuators"], steps)):
        o, r, l0 = a["offset"], a["pivot_radius"], a["initial_stroke_length"]
        lm = m / a["increment"] + l0
        d = math.acos((o * o + r * r - l0 * l0) / (2 * o * r)) - math.acos((o * o + r * r - lm * lm) / (2 * o * r))
        base = a["initial_angle"] - (math.pi / 2 if i == 0 else 0.0)
        th.append(base - d if a["clockwise_axis_movement"] == 0 else base + d)
    c1, s1, c2, s2 = math.cos(th[0]), math.sin(th[0]), math.cos(th[1]), math.sin(th[1])
    re = np.array([[1, 0, 0], [0, c1, -s1], [0, s1, c1]])
    ru = np.array([[c2, -s2, 0], [s2, c2, 0], [0, 0, 1]])
    return re @ ru @ np.array([0.0, -1.0, 0.0])


def test_axis1_angle_from_zenith_and_mirror_offset(imported):
    imp, cfg = imported
    props = json.loads((DATA / "AA39" / "AA39-heliostat-properties.json").read_text())
    model = HeliostatModel.from_config(cfg, ["AA39"])
    for rec in [r for r in imp.records if r.heliostat_id == "AA39"]:
        acts = imp.heliostats["AA39"].kinematics.actuators
        strokes = np.array([[float(paint.steps_to_stroke_mm(m, a)) for m, a in zip(rec.motor_steps, acts)]])
        n = model.normal(strokes)[0]
        np.testing.assert_allclose(n, _readme_normal(props, rec.motor_steps), atol=1e-12)
        assert n[2] > 0.5  # facing the sky, not 90° off
        origin, _ = model.beam(strokes, rec.sun_enu)
        np.testing.assert_allclose(origin[0], np.asarray(cfg.heliostat("AA39").position_enu_m) - 0.175 * n, atol=1e-12)


@pytest.mark.parametrize("hid", ["AA39", "AA23"])
def test_nominal_beam_agrees_with_paint_kinematics(imported, hid):
    imp, cfg = imported
    model = HeliostatModel.from_config(cfg, [hid])
    kin = imp.heliostats[hid].kinematics
    for rec in [r for r in imp.records if r.heliostat_id == hid]:
        strokes = np.array([[float(paint.steps_to_stroke_mm(m, a)) for m, a in zip(rec.motor_steps, kin.actuators)]])
        o, d = model.beam(strokes, rec.sun_enu)
        o_ref, d_ref = kin.beam(rec.motor_steps, rec.sun_enu)
        assert 1000 * angle_between_rad(d[0], d_ref) <= 0.01
        np.testing.assert_allclose(o[0], o_ref, atol=1e-6)


def test_nominal_normal_error_matches_peer_figures(imported):
    imp, _ = imported
    # peers (MANIFEST): nominal PAINT parameters 13.45 mrad mean on AA39 (UTIS), 86 mrad on AA23
    for hid, peer, tol in (("AA39", 13.45, 0.05), ("AA23", 86.0, 1.0)):
        kin = imp.heliostats[hid].kinematics
        errs = [normal_error_mrad(kin, r.motor_steps, r.sun_enu, paint.spot_enu(imp, r, "UTIS"))
                for r in imp.records if r.heliostat_id == hid]
        assert np.mean(errs) == pytest.approx(peer, abs=tol)


def test_import_paint_command_writes_loadable_files(tmp_path, capsys):
    assert main(["import-paint", str(DATA), "--out", str(tmp_path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["records"] == 16
    cfg = load_field_config(tmp_path / "field.yaml")
    assert cfg.drive_of("AA39").kind == "custom"
    assert cfg.drive_of("AA39").mirror_offset_m == pytest.approx(-0.175)
    rows = read_observations(tmp_path / "observations.csv", "AA39")
    assert len(rows) == 6 and all(r.source == "PAINT" and r.spot_method == "UTIS" for r in rows)
    for r in rows:  # observed spot in target u, v is consistent with its ENU position
        uvw = cfg.target(r.target_id).enu_to_uvw(r.spot_enu_m)
        assert uvw[0] == pytest.approx(r.target_u_m, abs=1e-9) and uvw[1] == pytest.approx(r.target_v_m, abs=1e-9)
        assert abs(uvw[2]) < 0.05  # on the board plane
