"""The compiled geometry kernels against the numpy reference: the same strokes, angles, normals,
beams, spots and flags (≤ 1e-9 rad, mm, m) on the shipped fields' drives and generated ones, with
error parameters up to 3× their prior sigma, including gimbal normals and stroke-limit edges."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from field_variants import AZEL_DRIVE
from helicalib.config import Drive, load_field_config
from helicalib.geometry import drives as dr
from helicalib.geometry import error_model as em
from helicalib.geometry import kernels, optics
from helicalib.geometry.drives import DriveArrays
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_vector_from_angles

ROOT = Path(__file__).resolve().parents[1]
FIELDS = [load_field_config(p) for p in (ROOT / "simulations" / "fields" / "bench500.yaml",
                                          ROOT / "field_config" / "demo_north.yaml")]
PIVOTS = np.concatenate([c.heliostat_positions_enu_m() for c in FIELDS])
AIMS = np.array([t.center_enu_m for c in FIELDS for t in c.targets])
TARGETS = [t for c in FIELDS for t in c.targets]
CUSTOM = {"kind": "custom", "axis1_enu": [0, 0, 1], "axis2_enu": [0.995, 0.0998, 0], "normal0_enu": [0, 0.2, 0.98],
          "mirror_offset_m": 0.2, "mirror_size_m": [3, 3], "actuators": AZEL_DRIVE["actuators"]}
DRIVES = [d for c in FIELDS for d in c.drives.values()] + [Drive.model_validate(AZEL_DRIVE),
                                                           Drive.model_validate(CUSTOM)]
SOUTH = [False] * (len(DRIVES) - 2) + [True, True]
"""Drives whose strokes reach a field south of the tower (pivots and aims mirrored for them)."""
TOL = 1e-9
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def close(a, b, tol=TOL):
    """Equal within ``tol`` with NaN in the same places."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a, b, rtol=0.0, atol=tol, equal_nan=True)


@st.composite
def models(draw, max_rows: int = 4):
    """(model of 1–``max_rows`` heliostats on one drive with random errors, aims (k, 3), south)."""
    k = draw(st.integers(1, max_rows))
    which = draw(st.integers(0, len(DRIVES) - 1))
    rows = draw(st.lists(st.integers(0, len(PIVOTS) - 1), min_size=k, max_size=k))
    pivots = PIVOTS[rows].copy()
    aims = AIMS[draw(st.lists(st.integers(0, len(AIMS) - 1), min_size=k, max_size=k))]
    aims = aims + np.array(draw(st.lists(st.floats(-8.0, 8.0), min_size=3 * k, max_size=3 * k))).reshape(k, 3)
    if SOUTH[which]:
        pivots[:, 1] *= -1.0
        aims[:, 1] *= -1.0
    z = np.array(draw(st.lists(st.floats(-3.0, 3.0), min_size=k * em.P, max_size=k * em.P))).reshape(k, em.P)
    drives = DriveArrays.from_drives([DRIVES[which]] * k)
    return HeliostatModel([f"H{i}" for i in range(k)], pivots, drives, z * em.PRIOR_SIGMA), aims, SOUTH[which]


def suns(draw_el=st.floats(2.0, 88.0), draw_az=st.floats(0.0, 360.0)):
    return st.builds(lambda el, az: sun_vector_from_angles(az, el), draw_el, draw_az)


def approaches(k: int):
    sign = st.sampled_from([-1.0, 0.0, 1.0])
    return st.one_of(st.none(), st.lists(sign, min_size=2, max_size=2).map(np.array),
                     st.lists(sign, min_size=2 * k, max_size=2 * k).map(lambda v: np.array(v).reshape(k, 2)))


def _same_aim(model, sun, aims, approach):
    got = model.strokes_for_aim(sun, aims, approach)
    ref = model.strokes_for_aim(sun, aims, approach, reference=True)
    close(got.strokes_mm, ref.strokes_mm)
    close(got.angles_rad, ref.angles_rad)
    close(got.normal_enu, ref.normal_enu)
    np.testing.assert_array_equal(got.in_range, ref.in_range)
    np.testing.assert_array_equal(got.reachable, ref.reachable)
    return ref


# ---------------------------------------------------------------------------- aim → strokes, forward
@SETTINGS
@given(data=st.data(), drawn=models(), sun=suns())
def test_aim_to_strokes_and_back_match_numpy(data, drawn, sun):
    model, aims, _ = drawn
    approach = data.draw(approaches(len(model)))
    ref = _same_aim(model, sun, aims, approach)
    _same_aim(model, sun, aims[0], approach)  # one aim for all rows
    mid = 0.5 * (model.drives.stroke_min_mm + model.drives.stroke_max_mm)
    strokes = np.where(np.isfinite(ref.strokes_mm), ref.strokes_mm, mid)
    close(model.angles(strokes, approach), model.angles(strokes, approach, reference=True))
    close(model.normal(strokes, approach), model.normal(strokes, approach, reference=True))
    for got, want in zip(model.beam(strokes, sun, approach), model.beam(strokes, sun, approach, reference=True)):
        close(got, want)
    target = data.draw(st.sampled_from(TARGETS))
    per_row = [data.draw(st.sampled_from(TARGETS)) for _ in range(len(model))]
    for t in (target, per_row):
        close(model.spot_on_target(strokes, sun, t, approach), model.spot_on_target(strokes, sun, t, approach,
                                                                                     reference=True))
    for got, want in zip(model.normal_to_strokes(ref.normal_enu, approach),
                         model.normal_to_strokes(ref.normal_enu, approach, reference=True)):
        close(got, want)


@SETTINGS
@given(drawn=models(), strokes=st.lists(st.floats(-3000.0, 6000.0), min_size=2, max_size=2),
       angles=st.lists(st.floats(-4.0, 4.0), min_size=2, max_size=2))
def test_linkage_and_normal_match_numpy_inside_and_outside_the_triangle(drawn, strokes, angles):
    """Strokes far outside the range (no triangle: NaN angles) and angles past γ ∈ (0, π) (NaN strokes)."""
    model, _, _ = drawn
    eff = model.drives_eff
    s = np.array(strokes)
    a = np.array(angles)
    close(dr.strokes_to_angles(eff, s), dr.strokes_to_angles(eff, s, reference=True))
    close(dr.angles_to_strokes(eff, a), dr.angles_to_strokes(eff, a, reference=True))
    close(dr.angles_to_normal(eff, a), dr.angles_to_normal(eff, a, reference=True))
    close(model.normal(s), model.normal(s, reference=True))


@SETTINGS
@given(drawn=models(max_rows=1), which=st.integers(0, 1), side=st.sampled_from([-1.0, 1.0]),
       eps=st.floats(1e-12, 1e-6))
def test_linkage_edges_match_numpy(drawn, which, side, eps):
    """Axis angles a hair inside and outside the linkage range (γ at 0 or π), and the strokes there."""
    model, _, _ = drawn
    eff = model.drives_eff
    low, high = dr.angle_interval_rad(eff)
    edge = (low if side < 0 else high)[0, which]
    for th in (edge - side * eps, edge + side * eps):
        a = np.array([0.5 * (low[0, 0] + high[0, 0]), 0.5 * (low[0, 1] + high[0, 1])])
        a[which] = th
        s = dr.angles_to_strokes(eff, a, reference=True)
        close(dr.angles_to_strokes(eff, a), s, tol=1e-6)  # γ·cos near 0 or π: stroke's slope is 0 there
        close(dr.strokes_to_angles(eff, s), dr.strokes_to_angles(eff, s, reference=True), tol=1e-6)


# ---------------------------------------------------------------------------- gimbal and stroke limits
@SETTINGS
@given(drawn=models(), eps=st.floats(1e-5, 1e-2), phi=st.floats(0.0, 2.0 * np.pi),
       flip=st.sampled_from([-1.0, 1.0]))
def test_gimbal_normals_match_numpy(drawn, eps, phi, flip):
    """Normals within ``eps`` rad of axis 1 (the gimbal, where θ1 turns ill-defined)."""
    model, _, _ = drawn
    a1 = flip * model.drives_eff.axis1_enu
    helper = np.where(np.abs(a1[:, :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    u = optics.unit(np.cross(a1, helper))
    v = np.cross(a1, u)
    n = np.cos(eps) * a1 + np.sin(eps) * (np.cos(phi) * u + np.sin(phi) * v)
    got, ok = dr.normal_to_angles(model.drives_eff, n)
    want, ok_ref = dr.normal_to_angles(model.drives_eff, n, reference=True)
    np.testing.assert_array_equal(ok, ok_ref)
    close(got, want, tol=TOL / eps * 1e-4)  # θ1's conditioning is 1/eps there: 1e-9 rad at eps = 1e-4
    close(dr.angles_to_normal(model.drives_eff, got), dr.angles_to_normal(model.drives_eff, want))
    for x, y in zip(model.normal_to_strokes(n), model.normal_to_strokes(n, reference=True)):
        close(x, y, tol=1e-3 * TOL / eps)


@SETTINGS
@given(drawn=models(max_rows=1), sun=suns(st.floats(10.0, 80.0)), which=st.integers(0, 1),
       end=st.sampled_from(["min", "max"]), delta=st.floats(1e-6, 1e-2), inside=st.booleans())
def test_aims_just_inside_and_outside_the_stroke_range_agree(drawn, sun, which, end, delta, inside):
    """The stroke range moved so that the aim's stroke lies ``delta`` mm inside or outside one end."""
    model, aims, _ = drawn
    ref = model.strokes_for_aim(sun, aims, reference=True)
    _same_aim(model, sun, aims, None)
    assume(bool(ref.reachable[0]))
    s = ref.strokes_mm[0, which]
    lo, hi = model.drives.stroke_min_mm.copy(), model.drives.stroke_max_mm.copy()
    lo[0], hi[0] = ref.strokes_mm[0] - 100.0, ref.strokes_mm[0] + 100.0
    into = delta if inside else -delta
    if end == "min":
        lo[0, which] = s - into
    else:
        hi[0, which] = s + into
    drives = model.drives.replace(stroke_min_mm=lo, stroke_max_mm=hi)
    edged = HeliostatModel(model.ids, model.pivots_enu, drives, model.params)
    got = _same_aim(edged, sun, aims, None)
    assert bool(got.in_range[0]) is inside


# ---------------------------------------------------------------------------- optics and dispatch
@SETTINGS
@given(drawn=models(), sun=suns(), offset=st.floats(0.0, 0.6))
def test_aim_normal_matches_numpy_in_every_shape(drawn, sun, offset):
    model, aims, _ = drawn
    p = model.pivots_eff_enu
    for args in ((p[0], sun, aims[0], offset), (p, sun, aims, offset), (p, np.broadcast_to(sun, p.shape), aims[0],
                                                                         np.full(len(p), offset))):
        close(optics.aim_normal(*args), optics.aim_normal(*args, reference=True))


@SETTINGS
@given(drawn=models(), angles=st.lists(st.floats(-4.0, 4.0), min_size=4, max_size=4))
def test_rotate_matches_numpy_in_every_shape(drawn, angles):
    """Rodrigues rotations as the error model makes them: rows about rows, about one axis, by one angle."""
    model, _, _ = drawn
    a1, n0 = model.drives_eff.axis1_enu, model.drives_eff.normal0_enu
    k = len(model)
    ang = np.resize(np.array(angles), k)
    for args in ((a1, ang, n0), (a1[0], ang, n0), (a1, angles[0], n0), (a1[0], ang[:1], n0[0]),
                 (np.broadcast_to(np.array([0.0, 0.0, 1.0]), (k, 3)), ang, n0)):
        close(dr.rotate(*args), dr.rotate(*args, reference=True))
    for args in ((a1[0], angles[0], n0[0]), (a1[:, None, :], ang[:, None], n0[:, None, :])):  # numpy's shapes
        close(dr.rotate(*args), dr.rotate(*args, reference=True))


def test_the_kernels_run_below_max_rows_and_numpy_from_it(monkeypatch):
    calls = []
    real = kernels.model_strokes_for_aim
    monkeypatch.setattr(kernels, "model_strokes_for_aim", lambda *a: calls.append(len(a[0])) or real(*a))
    cfg = FIELDS[1]
    full = HeliostatModel.from_config(cfg)
    sun = sun_vector_from_angles(150.0, 40.0)
    aim = np.array(cfg.targets[0].center_enu_m)
    _same_aim(full.subset([0]), sun, aim, None)
    _same_aim(full, sun, aim, None)
    assert calls == [1, len(full)]
    monkeypatch.setattr(kernels, "MAX_ROWS", len(full))
    full.strokes_for_aim(sun, aim)
    assert calls == [1, len(full)]  # MAX_ROWS rows or more: numpy's path
    assert not dr.use_kernels(len(full)) and dr.use_kernels(1)


def test_a_shape_the_kernels_do_not_take_goes_the_numpy_way():
    """One heliostat, two stroke rows: numpy broadcasts (2, 2); the kernel path steps aside."""
    model = HeliostatModel.from_config(FIELDS[1]).subset([3])
    s = np.array([[600.0, 500.0], [700.0, 650.0]])
    close(model.normal(s), model.normal(s, reference=True))
    assert model.normal(s).shape == (2, 3)


def test_warm_compiles_every_kernel():
    out = kernels.warm()
    names = ("linkage", "rotate_rows", "angles_to_normal", "normal_to_angles", "aim_normal", "model_normal",
             "model_beam", "model_spot", "model_normal_to_strokes", "model_strokes_for_aim")
    assert out["kernels"] == len(names) and out["seconds"] > 0.0
    for name in names:
        assert getattr(kernels, name).signatures, name


def test_degenerate_inputs_give_nan_as_numpy_does_not_an_exception():
    """A zero normal, a zero sun or an aim at the pivot: NaN (and unreachable), as the numpy
    reference gives, never a ZeroDivisionError out of a kernel."""
    model = HeliostatModel(["H"], PIVOTS[:1], DriveArrays.from_drives([DRIVES[0]]))
    for reference in (False, True):
        strokes, _angles, reachable = model.normal_to_strokes(np.zeros(3), reference=reference)
        assert np.all(np.isnan(strokes)) and not bool(reachable[0])
        assert np.all(np.isnan(model.strokes_for_aim(np.zeros(3), AIMS[0], reference=reference).strokes_mm))
        assert np.all(np.isnan(model.strokes_for_aim(np.array([0.0, 0.6, 0.8]), PIVOTS[0],
                                                     reference=reference).strokes_mm))
    assert np.all(np.isnan(optics.aim_normal(PIVOTS[0], np.zeros(3), AIMS[0], 0.2)))


def test_strided_rows_use_the_compiled_signature():
    """A strided row (a column slice) is made contiguous first: no second compiled version mid-run."""
    kernels.warm()
    model = HeliostatModel(["H"], PIVOTS[:1], DriveArrays.from_drives([DRIVES[0]]))
    before = {k.py_func.__name__: len(k.signatures) for k in (kernels.model_strokes_for_aim, kernels.model_normal)}
    suns = np.tile([0.1, 0.6, 0.79, 0.0], (3, 1))[:, :3]  # rows strided in memory
    model.strokes_for_aim(suns[0], AIMS[0])
    model.normal(np.array([[500.0, 600.0, 0.0]])[0, :2])
    after = {k.py_func.__name__: len(k.signatures) for k in (kernels.model_strokes_for_aim, kernels.model_normal)}
    assert after == before
