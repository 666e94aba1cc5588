"""HeliostatModel and the error model: aim → strokes → beam lands on the aim, parameter meanings."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.config import load_field_config, parse_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.drives import rotate
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_vector_from_angles
from field_variants import AZEL_DRIVE, mirror_south

DEMO = Path(__file__).resolve().parents[1] / "field_config" / "demo_north.yaml"
CFG = load_field_config(DEMO)
MODEL = HeliostatModel.from_config(CFG)
AIMS = np.array([CFG.target(h.target).center_enu_m for h in CFG.heliostats])
TARGETS = [CFG.target(h.target) for h in CFG.heliostats]




def _azel_config():
    data = yaml.safe_load(DEMO.read_text())
    data = copy.deepcopy(data)
    data["drives"] = {"ae": dict(AZEL_DRIVE),
        "cu": {"kind": "custom", "axis1_enu": [0, 0, 1], "axis2_enu": [0.995, 0.0998, 0], "normal0_enu": [0, 0.2, 0.98],
               "mirror_offset_m": 0.2, "mirror_size_m": [3, 3], "actuators": data["drives"]["tr20"]["actuators"]}}
    for i, h in enumerate(data["heliostats"]):
        h["drive"] = "ae" if i % 2 else "cu"
    return parse_field_config(mirror_south(data))


def _miss_mrad(model, strokes, sun, aims):
    origin, direction = model.beam(strokes, sun)
    return 1000 * optics.angle_between_rad(direction, aims - origin)


def _sun_in_south(az, el):
    return sun_vector_from_angles(az, el)


@settings(max_examples=60, deadline=None)
@given(st.floats(100, 260), st.floats(5, 85))
def test_aim_strokes_beam_lands_on_aim_zero_errors(az, el):
    sun = _sun_in_south(az, el)
    sol = MODEL.strokes_for_aim(sun, AIMS)
    ok = sol.reachable
    assert ok.any()
    assert np.all(_miss_mrad(MODEL, sol.strokes_mm, sun, AIMS)[ok] < 1e-6)


@settings(max_examples=40, deadline=None)
@given(st.floats(100, 260), st.floats(5, 85), st.integers(0, 2**31 - 1))
def test_aim_strokes_beam_lands_on_aim_with_errors(az, el, seed):
    params = np.random.default_rng(seed).normal(size=(len(MODEL), em.P)) * em.PRIOR_SIGMA
    model = MODEL.with_params(params)
    sun = _sun_in_south(az, el)
    sol = model.strokes_for_aim(sun, AIMS)
    ok = sol.reachable
    assert np.all(_miss_mrad(model, sol.strokes_mm, sun, AIMS)[ok] < 1e-6)
    # and the spot lies on the aim point in the target frame
    uv = model.spot_on_target(sol.strokes_mm, sun, TARGETS)
    assert np.all(np.abs(uv[ok]) < 1e-6)


@settings(max_examples=30, deadline=None)
@given(st.floats(60, 300), st.floats(5, 85))
def test_aim_round_trip_azimuth_elevation_and_custom_drives(az, el):
    cfg = _azel_config()
    model = HeliostatModel.from_config(cfg)
    sun = _sun_in_south(az, el)
    sol = model.strokes_for_aim(sun, AIMS)
    assert sol.reachable.any()
    assert np.all(_miss_mrad(model, sol.strokes_mm, sun, AIMS)[sol.reachable] < 1e-6)


def test_demo_field_in_range_at_noon_midsummer():
    sun = sun_vector_from_angles(180.0, 73.0)
    sol = MODEL.strokes_for_aim(sun, AIMS)
    assert sol.in_range.all() and sol.reachable.all()


def test_stroke_offset_means_commanded_stroke_falls_short():
    params = em.zeros(len(MODEL))
    params[:, em.index("stroke_offset_1_mm")] = 1.5
    params[:, em.index("stroke_offset_2_mm")] = -0.7
    strokes = np.tile([900.0, 1200.0], (len(MODEL), 1))
    np.testing.assert_allclose(MODEL.with_params(params).normal(strokes), MODEL.normal(strokes + [1.5, -0.7]), atol=1e-14)


def test_pedestal_tilt_rotates_the_whole_drive_and_pivot_shift_moves_the_beam():
    strokes = np.tile([900.0, 1200.0], (len(MODEL), 1))
    params = em.zeros(len(MODEL))
    params[:, em.index("pedestal_tilt_n_mrad")] = 3.0
    n = MODEL.with_params(params).normal(strokes)
    north = np.broadcast_to([0.0, 1.0, 0.0], n.shape)
    np.testing.assert_allclose(n, rotate(north, np.full(len(MODEL), 3e-3), MODEL.normal(strokes)), atol=1e-14)
    params = em.zeros(len(MODEL))
    params[:, em.index("pivot_du_m")] = 0.04
    o1, d1 = MODEL.with_params(params).beam(strokes, [0.0, -0.5, 0.866])
    o0, d0 = MODEL.beam(strokes, [0.0, -0.5, 0.866])
    np.testing.assert_allclose(o1 - o0, np.tile([0, 0, 0.04], (len(MODEL), 1)), atol=1e-12)
    np.testing.assert_allclose(d1, d0, atol=1e-14)


def test_every_parameter_moves_the_beam():
    strokes = np.tile([900.0, 1200.0], (len(MODEL), 1))
    sun = np.array([0.0, -0.5, 0.866])
    o0, d0 = MODEL.beam(strokes, sun)
    approach = np.tile([1.0, -1.0], (len(MODEL), 1))
    for i, p in enumerate(em.PARAMETERS):
        params = em.zeros(len(MODEL))
        params[:, i] = p.prior_sigma
        o, d = MODEL.with_params(params).beam(strokes, sun, approach)
        assert np.max(np.linalg.norm(o - o0, axis=1) + np.linalg.norm(d - d0, axis=1)) > 1e-5, p.name
        if p.name in em.BACKLASH:  # a dead band acts only through the approach direction
            o, d = MODEL.with_params(params).beam(strokes, sun)
            assert np.max(np.linalg.norm(o - o0, axis=1) + np.linalg.norm(d - d0, axis=1)) == 0.0, p.name


def test_backlash_parameters_match_the_simulated_plant_and_invert_exactly():
    """The model's dead bands put the mirror where the simulator's backlash does (half the band
    against the approach), and strokes_for_aim with an approach lands the beam on the aim."""
    from helicalib.sim.scenario import Scenario
    from helicalib.sim.truth import TrueField

    truth = TrueField(CFG, Scenario(), 0.0, zero=True)
    band = np.tile([0.6, 0.35], (len(MODEL), 1))
    truth.backlash_mm = band
    params = em.zeros(len(MODEL))
    params[:, em.index("backlash_1_mm")], params[:, em.index("backlash_2_mm")] = band[:, 0], band[:, 1]
    model = MODEL.with_params(params)
    strokes = np.tile([900.0, 1200.0], (len(MODEL), 1))
    sun = np.array([0.3, -0.5, 0.81])
    for approach in ([1.0, 1.0], [-1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]):
        a = np.tile(approach, (len(MODEL), 1))
        true = truth.beam(strokes, sun, 0.0, approach=a, jitter=False)
        np.testing.assert_allclose(model.normal(strokes, a), true.normal_enu, atol=1e-12)
        aim = np.asarray(CFG.targets[0].center_enu_m, dtype=float)
        sol = model.strokes_for_aim(sun, aim, a)
        np.testing.assert_allclose(sol.strokes_mm - MODEL.strokes_for_aim(sun, aim).strokes_mm, 0.5 * band * a,
                                   atol=1e-9)
        origin, direction = model.beam(sol.strokes_mm, sun, a)
        assert np.max(optics.angle_between_rad(direction, optics.unit(aim - origin))) < 1e-9


def test_error_model_names_and_dicts():
    names = [p.name for p in em.PARAMETERS]
    for required in ("stroke_offset_1_mm", "stroke_offset_2_mm", "pedestal_tilt_e_mrad", "pedestal_tilt_n_mrad",
                     "axis_nonorthogonality_mrad", "canting_1_mrad", "canting_2_mrad", "pivot_de_m", "pivot_dn_m",
                     "pivot_du_m", "arm_scale_1", "arm_scale_2"):
        assert required in names
    row = np.arange(em.P, dtype=float)
    assert np.array_equal(em.from_dict(em.as_dict(row)), row)
    assert em.zeros(3).shape == (3, em.P)
    with pytest.raises(KeyError, match="unknown error-model parameter"):
        em.index("nope")


def test_model_is_immutable_and_subset_keeps_rows():
    with pytest.raises(AttributeError):
        MODEL.params = None
    sub = MODEL.subset([3, 1])
    assert sub.ids == (MODEL.ids[3], MODEL.ids[1])
    np.testing.assert_array_equal(sub.pivots_enu, MODEL.pivots_enu[[3, 1]])
    one = HeliostatModel.from_config(CFG, ["H0002"])
    assert len(one) == 1 and one.ids == ("H0002",)


def test_subset_has_the_effective_drives_a_new_model_of_those_rows_computes():
    """subset() slices the effective drives instead of applying the errors again: the same values."""
    rng = np.random.default_rng(8)
    params = rng.normal(0.0, 1.0, (len(MODEL), em.P)) * np.where(em.prior_sigma() > 0, em.prior_sigma(), 1.0)
    model = MODEL.with_params(params)
    rows = [7, 0, 7, len(MODEL) - 1]
    sub = model.subset(rows)
    fresh = HeliostatModel([model.ids[i] for i in rows], model.pivots_enu[rows], model.drives.take(rows),
                           params[rows])
    assert sub.ids == fresh.ids
    for name in ("pivots_enu", "params", "pivots_eff_enu"):
        np.testing.assert_array_equal(getattr(sub, name), getattr(fresh, name))
        assert not getattr(sub, name).flags.writeable
    for f in ("axis1_enu", "axis2_enu", "normal0_enu", "arm_moving_m", "length_at_zero_m", "stroke_min_mm"):
        np.testing.assert_array_equal(getattr(sub.drives_eff, f), getattr(fresh.drives_eff, f))
        np.testing.assert_array_equal(getattr(sub.drives, f), getattr(fresh.drives, f))
    sun = np.array([0.3, -0.5, 0.8])
    aim = np.array([0.0, 0.0, 60.0])
    np.testing.assert_array_equal(sub.strokes_for_aim(sun, aim).strokes_mm,
                                  model.strokes_for_aim(sun, aim).strokes_mm[rows])
    np.testing.assert_array_equal(model.subset(slice(2, 5)).params, params[2:5])
