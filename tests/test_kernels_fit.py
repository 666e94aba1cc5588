"""The compiled refit (:mod:`helicalib.calibration.fit_kernels`) equals its numpy reference
(:class:`~helicalib.calibration.fit_solver.BeamJacobian`, :func:`~helicalib.calibration.fit_solver.gauss_newton`).

Observations are made by a true heliostat with random error parameters (within 3 prior σ) at
random sun positions: strokes for the board centre, some pushed to the ends of the stroke range,
each actuator arriving from a random side, the spot on the true beam with 0.3 mrad of noise.
Tolerances: residuals and Jacobian 1e-9 (mrad, mrad per parameter unit); whole fits' beams over
a sky grid 0.001 mrad (the product's promise between its solvers).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.calibration import fit_kernels, fit_solver
from helicalib.calibration.fit import FitOptions, FitPoints, _Problem, fit_error_model
from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_vector_from_angles
from test_calibration_fit_fast import _beam_difference_mrad as beam_difference_mrad

ROOT = Path(__file__).resolve().parents[1]
CFG = load_field_config(ROOT / "field_config" / "demo_north.yaml")  # the field of beam_difference_mrad
HID = "H0017"
NOMINAL = HeliostatModel.from_config(CFG, [HID])
AIM = np.asarray(CFG.target(CFG.heliostat(HID).target).center_enu_m, dtype=float)
KERNEL_TOL = 1e-9
BEAM_TOL_MRAD = 0.001


def _observations(seed: int, k: int, edge_share: float = 0.25):
    """(true params (P,), strokes (K, 2), sun (K, 3), spot (K, 3), approach (K, 2)) of K observations."""
    rng = np.random.default_rng(seed)
    truth = np.clip(rng.normal(size=em.P), -3.0, 3.0) * em.PRIOR_SIGMA
    true = NOMINAL.with_params(truth[None, :])
    d = NOMINAL.drives
    lo, hi = d.stroke_min_mm[0], d.stroke_max_mm[0]
    strokes, suns = [], []
    while len(strokes) < k:
        sun = sun_vector_from_angles(rng.uniform(60.0, 300.0), rng.uniform(10.0, 80.0))
        sol = true.strokes_for_aim(np.asarray(sun).reshape(1, 3), AIM)
        if not sol.in_range[0]:
            continue
        s = sol.strokes_mm[0].copy()
        if rng.uniform() < edge_share:  # one actuator at an end of its range
            a = int(rng.integers(2))
            s[a] = lo[a] if rng.uniform() < 0.5 else hi[a]
        strokes.append(s)
        suns.append(np.asarray(sun).reshape(3))
    strokes, sun = np.array(strokes), np.array(suns)
    approach = rng.choice([-1.0, 1.0], size=(k, 2))
    origin, direction = true.repeat(k).beam(strokes, sun, approach)
    noise = rng.normal(scale=0.3e-3, size=(k, 3))
    spot = origin + 150.0 * (direction + noise - direction * np.sum(noise * direction, axis=1, keepdims=True))
    return truth, strokes, sun, spot, approach


def _beam_difference_mrad(a, b) -> float:
    """Largest beam angle between fits ``a`` and ``b`` over a sky grid [mrad]."""
    return beam_difference_mrad(a, b, HID)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.0, 3.0), with_approach=st.booleans())
def test_kernel_residuals_and_jacobian_equal_numpy(seed, scale, with_approach):
    """Any parameter row within 3 prior σ, at held strokes across the whole stroke range (its ends
    included) and beyond it by a little (a stroke the linkage cannot reach: the NaN residual)."""
    rng = np.random.default_rng(seed)
    k = 12
    _t, strokes, sun, spot, approach = _observations(seed, k)
    d = NOMINAL.drives
    strokes[:4] = rng.uniform(d.stroke_min_mm[0], d.stroke_max_mm[0], size=(4, 2))
    strokes[4] = d.stroke_min_mm[0]
    strokes[5] = d.stroke_max_mm[0]
    strokes[6, 0] = 1e4  # no triangle has this side: NaN residual with zero derivatives
    app = approach if with_approach else None
    prob = _Problem(NOMINAL, strokes, sun, spot, "beam", app)
    bj = fit_solver.BeamJacobian(NOMINAL.drives, NOMINAL.pivots_enu[0], prob.strokes, prob.approach, prob.sun,
                                 prob.spot, prob.basis, "beam")
    geo = fit_kernels.pack_drive(NOMINAL.drives, NOMINAL.pivots_enu[0])
    params = rng.uniform(-1.0, 1.0, size=em.P) * scale * em.PRIOR_SIGMA
    with np.errstate(divide="ignore", invalid="ignore"):  # the unreachable stroke's derivatives (zeroed)
        res, jac = bj.evaluate(params)
    kres, kjac = fit_kernels.beam_residuals(params, geo, prob.strokes, approach if with_approach else np.zeros((k, 2)),
                                            with_approach, prob.sun, prob.spot, prob.basis, True)
    assert res[6, 0] == fit_kernels.NAN_RESIDUAL_MRAD and not np.any(kjac[6])
    np.testing.assert_allclose(kres, res, rtol=0, atol=KERNEL_TOL)
    np.testing.assert_allclose(kjac, jac, rtol=0, atol=KERNEL_TOL)


def _fit(points: FitPoints, solver: str, start=None, loss: str = "soft_l1"):
    return fit_error_model(NOMINAL, points, FitOptions(loss=loss, n_suggestions=0), start=start, solver=solver)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), k=st.sampled_from([5, 40]), warm=st.booleans())
def test_compiled_fit_equals_numpy_fit(seed, k, warm):
    """Few points (5: the priors hold most parameters) and many (40), from the nominal heliostat or
    warm from a nearby start (a campaign's refit)."""
    truth, strokes, sun, spot, approach = _observations(seed, k)
    points = FitPoints(strokes, sun, spot, approach=approach)
    start = truth + 0.3 * em.PRIOR_SIGMA if warm else None
    ref, comp = _fit(points, "numpy", start), _fit(points, "compiled", start)
    assert comp.message == ref.message == "Gauss-Newton converged"
    assert _beam_difference_mrad(ref, comp) <= BEAM_TOL_MRAD
    np.testing.assert_allclose(comp.residual_vec_mrad, ref.residual_vec_mrad, rtol=0, atol=BEAM_TOL_MRAD)
    np.testing.assert_allclose(comp.sigma, ref.sigma, rtol=1e-5)


@pytest.mark.parametrize("mode", ["tilt_rate", "epochs", "no_approach", "cauchy"])
def test_compiled_fit_equals_numpy_in_every_mode(mode):
    """The fit's other modes: a tilt rate (ages), earlier epochs, no approach recorded, another loss."""
    _truth, strokes, sun, spot, approach = _observations(7, 30)
    kw, opt = {"approach": approach}, {}
    if mode == "tilt_rate":
        kw["age_days"] = np.linspace(60.0, 0.0, 30)
    elif mode == "epochs":
        kw["epoch"] = np.repeat([0, 1, 2], 10)
        spot = spot.copy()
        spot[10:] += 0.05  # the earlier epochs' beams land elsewhere
    elif mode == "no_approach":
        kw = {}
    else:
        opt["loss"] = "cauchy"
    points = FitPoints(strokes, sun, spot, **kw)
    loss = opt.pop("loss", "soft_l1")
    ref = fit_error_model(NOMINAL, points, FitOptions(loss=loss, n_suggestions=0), solver="numpy")
    comp = fit_error_model(NOMINAL, points, FitOptions(loss=loss, n_suggestions=0), solver="compiled")
    assert comp.message == ref.message == "Gauss-Newton converged"
    assert _beam_difference_mrad(ref, comp) <= BEAM_TOL_MRAD
    np.testing.assert_allclose(comp.residual_vec_mrad, ref.residual_vec_mrad, rtol=0, atol=BEAM_TOL_MRAD)
    if mode == "tilt_rate":
        np.testing.assert_allclose(comp.tilt_rate_mrad_per_day, ref.tilt_rate_mrad_per_day, rtol=0, atol=1e-6)
    if mode == "epochs":
        np.testing.assert_allclose(comp.epoch_offsets, ref.epoch_offsets, rtol=0, atol=1e-6)


def test_compiled_is_the_default_and_a_normal_residual_runs_numpy():
    _truth, strokes, sun, spot, approach = _observations(3, 12)
    points = FitPoints(strokes, sun, spot, approach=approach)
    default = fit_error_model(NOMINAL, points, FitOptions(n_suggestions=0))
    comp = _fit(points, "compiled")
    assert np.array_equal(default.params, comp.params)
    normal = [fit_error_model(NOMINAL, points, FitOptions(n_suggestions=0, residual_kind="normal"), solver=s)
              for s in ("compiled", "numpy")]
    assert np.array_equal(normal[0].params, normal[1].params)  # the same (numpy) solver
    with pytest.raises(ValueError, match="solver must be one of compiled, numpy, not 'fortran'"):
        _fit(points, "fortran")
    with pytest.raises(ValueError, match="unknown loss 'l3'"):
        _fit(points, "compiled", loss="l3")


def test_a_wrong_kernel_jacobian_is_caught(monkeypatch):
    """The fit tests can fail: a kernel Jacobian 30 % off in one column converges elsewhere."""
    _truth, strokes, sun, spot, approach = _observations(5, 30)
    points = FitPoints(strokes, sun, spot, approach=approach)
    ref = _fit(points, "numpy")
    right = fit_kernels.fun_jac
    col, other = em.index("canting_1_mrad"), em.index("pedestal_tilt_n_mrad")  # all parameters free, in order

    def wrong(x, *args):
        r, j = right(x, *args)
        data = slice(0, len(r) - len(x))  # the observations' rows (the priors' rows stay right)
        j[data, col] += 0.3 * j[data, other]
        return r, j

    # the solver's own source, run by the interpreter, calls the module's (patched) fun_jac
    monkeypatch.setattr(fit_kernels, "fun_jac", wrong)
    monkeypatch.setattr(fit_kernels, "solve", fit_kernels.solve.py_func)
    bad = _fit(points, "compiled")
    assert bad.message == "Gauss-Newton converged"
    assert _beam_difference_mrad(ref, bad) > BEAM_TOL_MRAD


def test_warm_compiles_every_kernel():
    assert fit_kernels.warm() >= 0.0
    for kernel in (fit_kernels.solve, fit_kernels.beam_residuals, fit_kernels.fun_jac):
        assert kernel.signatures


def test_a_changed_error_model_is_refused_at_import():
    """numba bakes the parameters' columns into the cached kernels: a reordered error model must
    not run against them."""
    fit_kernels.check_names(em.NAMES)
    with pytest.raises(ImportError, match="error model's parameters changed"):
        fit_kernels.check_names((em.NAMES[1], em.NAMES[0], *em.NAMES[2:]))


def test_read_only_and_strided_inputs_use_the_compiled_signature():
    """No input layout makes numba compile another version of the solver mid-run."""
    fit_kernels.warm()
    before = len(fit_kernels.solve.signatures)
    _t, strokes, sun, spot, approach = _observations(1, 14)
    for a in (strokes, sun, spot, approach):
        a.setflags(write=False)
    strided_sun = np.repeat(sun, 2, axis=0)[::2]
    fit = fit_error_model(NOMINAL, FitPoints(strokes, strided_sun, spot, approach=approach),
                          FitOptions(loss="soft_l1", n_suggestions=0))
    assert fit.message == "Gauss-Newton converged"
    assert len(fit_kernels.solve.signatures) == before
