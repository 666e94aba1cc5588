"""Inverse model (paper section 2.2): an injected normal error is recovered exactly."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from helicalib.calibration.correction import observed_normal, stroke_correction
from helicalib.config import load_field_config, parse_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.drives import gamma_rad
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_vector_from_angles
from field_variants import AZEL_DRIVE, mirror_south

DEMO = Path(__file__).resolve().parents[1] / "field_config" / "demo_north.yaml"
CFG = load_field_config(DEMO)




def _azel_cfg():
    data = copy.deepcopy(yaml.safe_load(DEMO.read_text()))
    data["drives"]["tr20"] = dict(AZEL_DRIVE)
    return parse_field_config(mirror_south(data))


def _observe(plant, strokes, sun, targets):
    """Where the true plant's beam hits each heliostat's target [m, ENU] (independent forward path)."""
    origin, direction = plant.beam(strokes, sun)
    hits = np.empty_like(origin)
    for i, t in enumerate(targets):
        hits[i] = optics.intersect_target(origin[i], direction[i], t)[1]
    return hits


def test_observed_normal_reflects_sun_to_spot():
    p, s, x = np.array([10.0, 90.0, 4.0]), np.array([0.1, -0.6, 0.79]), np.array([1.0, 8.0, 96.0])
    s = s / np.linalg.norm(s)
    n = observed_normal(p, s, x, 0.3)
    r = optics.reflect(s, n)
    assert 1000 * optics.angle_between_rad(r, x - (p + 0.3 * n)) < 1e-9


@settings(max_examples=25, deadline=None)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(110, 250), st.floats(10, 80), st.floats(110, 250),
       st.floats(10, 80), st.booleans())
def test_injected_stroke_error_recovered_exactly(d1, d2, az_c, el_c, az_n, el_n, azel):
    cfg = _azel_cfg() if azel else CFG
    model = HeliostatModel.from_config(cfg)
    targets = [cfg.target(h.target) for h in cfg.heliostats]
    aims = np.array([t.center_enu_m for t in targets])
    injected = em.zeros(len(model))
    injected[:, em.index("stroke_offset_1_mm")] = d1
    injected[:, em.index("stroke_offset_2_mm")] = d2
    plant = model.with_params(injected)  # the "real" heliostats: push rods off by (d1, d2)
    sun_c, sun_n = sun_vector_from_angles(az_c, el_c), sun_vector_from_angles(az_n, el_n)
    held = model.strokes_for_aim(sun_c, aims)
    # (the test's azimuth push rod covers normal azimuths within ±90° only: skip sun positions beyond it)
    # near γ = 0 or π the linkage is singular (a millimetre is a large angle); judge the rest
    gamma = np.degrees(gamma_rad(model.drives, held.angles_rad))
    ok = held.in_range & np.all((gamma > 15) & (gamma < 165), axis=1)
    assume(ok.sum() >= 5)
    spot = _observe(plant, held.strokes_mm, sun_c, targets)
    corr = stroke_correction(model, held.strokes_mm, sun_c, spot, aims, sun_n)
    # the normal error is the angle between the plant's and the model's normal (computed independently)
    expect = 1000 * optics.angle_between_rad(plant.normal(held.strokes_mm), model.normal(held.strokes_mm))
    np.testing.assert_allclose(corr.normal_error_mrad[ok], expect[ok], atol=1e-6)
    np.testing.assert_allclose(corr.stroke_error_mm[ok], np.tile([d1, d2], (ok.sum(), 1)), atol=1e-6)
    # with the corrected strokes the plant's beam lands on the aim at the next sun position
    gamma_n = np.degrees(gamma_rad(model.drives, model.strokes_for_aim(sun_n, aims).angles_rad))
    nxt = ok & np.all((gamma_n > 15) & (gamma_n < 165), axis=1)
    o, d = plant.beam(corr.strokes_mm, sun_n)
    miss = 1000 * optics.angle_between_rad(d, aims - o)
    assert np.all(miss[nxt] < 1e-5)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from(["stroke", "angle", "rotation"]))
def test_closed_loop_converges_for_general_errors(seed, mode):
    """Any modelled error (tilts, canting, pivot, arms): repeating the correction at one sun converges."""
    model = HeliostatModel.from_config(CFG)
    targets = [CFG.target(h.target) for h in CFG.heliostats]
    aims = np.array([t.center_enu_m for t in targets])
    plant = model.with_params(np.random.default_rng(seed).normal(size=(len(model), em.P)) * em.PRIOR_SIGMA)
    sun = sun_vector_from_angles(160.0, 45.0)
    strokes = model.strokes_for_aim(sun, aims).strokes_mm
    first = None
    for _ in range(6):
        spot = _observe(plant, strokes, sun, targets)
        err = optics.tracking_error_exact_mrad(spot, aims, plant.pivots_eff_enu)
        first = err if first is None else first
        strokes = stroke_correction(model, strokes, sun, spot, aims, sun, mode=mode).strokes_mm
    assert np.median(first) > 1.0
    assert np.all(err < 0.01)
