"""The fast fit (analytic Jacobian, damped Gauss-Newton) equals the reference fit (scipy
least_squares with a central-difference Jacobian) on recorded campaign observations.

Data: ``tests/data/fit_observations.csv``, the valid observations of a one-day simulated campaign
of two demo heliostats (``tests/data/make_fit_observations.py``).

Tolerances: beams and residuals within 0.001 mrad (the product's promise); parameters within
1e-4 prior σ (the two solvers agree to ~3e-6 σ: the reference stops at a relative cost change of
1e-8); σ and covariance within 1e-5 relative (the reference covariance uses central differences,
whose truncation error is ~1e-8 relative, at a solution ~1e-6 σ away).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from helicalib.calibration import fit_solver
from helicalib.calibration.fit import FitOptions, FitPoints, _Problem, fit_error_model, sky_grid
from helicalib.campaign import verdict
from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry.heliostat import HeliostatModel

ROOT = Path(__file__).resolve().parents[1]
CFG = load_field_config(ROOT / "field_config" / "demo_north.yaml")
BEAM_TOL_MRAD = 0.001
PARAM_TOL_PRIOR_SIGMA = 1e-4
COV_RTOL = 1e-5


@pytest.fixture(scope="module")
def recorded():
    """{heliostat id: list of observation-like points in capture order}."""
    df = pd.read_csv(ROOT / "tests" / "data" / "fit_observations.csv")
    out = {}
    for hid, rows in df.groupby("heliostat_id", sort=True):
        out[hid] = [SimpleNamespace(
            heliostat_id=hid, target_id=r.target_id, visit_id=int(r.visit_id),
            strokes_read_mm=(r.stroke_read_1_mm, r.stroke_read_2_mm), strokes_cmd_mm=(r.stroke_cmd_1_mm, r.stroke_cmd_2_mm),
            approach=(int(r.approach_1), int(r.approach_2)), sun_enu=(r.sun_e, r.sun_n, r.sun_u),
            spot_enu_m=(r.spot_e_m, r.spot_n_m, r.spot_u_m)) for r in rows.itertuples()]
    assert set(out) == {"H0001", "H0017"} and all(len(p) >= 30 for p in out.values())
    return out


def _inputs(points):
    strokes, sun, spot = verdict.point_arrays(points)
    return strokes, sun, spot, verdict.point_approaches(points)


def _beam_difference_mrad(a, b, hid) -> float:
    """Largest angle [mrad] between the beams of fits ``a`` and ``b`` over a sky grid, for the
    strokes ``a``'s model commands for the board centre (each actuator arriving extending)."""
    aim = np.asarray(CFG.target(CFG.heliostat(hid).target).center_enu_m)
    suns = sky_grid()
    sol = a.model.repeat(len(suns)).strokes_for_aim(suns, aim, np.ones(2))
    ok = sol.in_range
    assert ok.sum() > 20
    beams = [f.model.repeat(int(ok.sum())).beam(sol.strokes_mm[ok], suns[ok], np.ones(2))[1] for f in (a, b)]
    return 1000.0 * float(np.max(np.linalg.norm(beams[0] - beams[1], axis=1)))


def _assert_equivalent(ref, fast, hid, fast_ran=True):
    if fast_ran:
        assert fast.message == "Gauss-Newton converged"  # the fast path ran (no fall-back to the reference)
    assert ref.free == fast.free and ref.residual_kind == fast.residual_kind
    assert _beam_difference_mrad(ref, fast, hid) < BEAM_TOL_MRAD
    assert np.max(np.abs(ref.residual_vec_mrad - fast.residual_vec_mrad)) < BEAM_TOL_MRAD
    assert abs(ref.rms_mrad - fast.rms_mrad) < BEAM_TOL_MRAD
    dp = np.abs(ref.params - fast.params) / em.PRIOR_SIGMA
    assert np.max(dp) < PARAM_TOL_PRIOR_SIGMA, dict(zip(em.NAMES, dp))
    free = [em.index(n) for n in ref.free]
    np.testing.assert_allclose(fast.sigma[free], ref.sigma[free], rtol=COV_RTOL)
    assert np.max(np.abs(fast.covariance - ref.covariance)) < COV_RTOL * np.max(np.abs(ref.covariance))
    assert ref.identifiability.determined == fast.identifiability.determined
    np.testing.assert_allclose(fast.linearisation.jacobian, ref.linearisation.jacobian, rtol=0, atol=1e-5 * np.max(
        np.abs(ref.linearisation.jacobian)))


@pytest.mark.parametrize("hid", ["H0001", "H0017"])
@pytest.mark.parametrize("k", [1, 5, 20, None])
def test_fast_fit_equals_reference_on_recorded_observations(recorded, hid, k):
    points = recorded[hid][:k]
    nominal = HeliostatModel.from_config(CFG, [hid])
    strokes, sun, spot, approach = _inputs(points)
    ref = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach), FitOptions(method="reference"))
    fast = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach))  # the default
    _assert_equivalent(ref, fast, hid)
    # suggestions are ranked alike
    np.testing.assert_allclose([s["sun_enu"] for s in fast.identifiability.suggestions],
                               [s["sun_enu"] for s in ref.identifiability.suggestions], atol=1e-12)


@pytest.mark.parametrize("kind,loss", [("normal", "soft_l1"), ("beam", "linear"), ("normal", "linear"),
                                       ("beam", "cauchy"), ("beam", "arctan"), ("beam", "huber")])
def test_fast_fit_equals_reference_for_each_residual_and_loss(recorded, kind, loss):
    """Huber's cost has a jump in its second derivative, where the Gauss-Newton steps may cycle:
    then the reference solver takes over, so the result is the same either way."""
    points = recorded["H0017"][:24]
    nominal = HeliostatModel.from_config(CFG, ["H0017"])
    strokes, sun, spot, approach = _inputs(points)
    data, kw = FitPoints(strokes, sun, spot, approach=approach), dict(residual_kind=kind, loss=loss, n_suggestions=0)
    _assert_equivalent(fit_error_model(nominal, data, FitOptions(method="reference", **kw)),
                       fit_error_model(nominal, data, FitOptions(**kw)), "H0017", fast_ran=loss != "huber")


@pytest.mark.parametrize("hid", ["H0001", "H0017"])
def test_campaign_refits_warm_started_equal_reference(recorded, hid):
    """The campaign's sequence: a refit after every point, each starting from the last model."""
    points = recorded[hid]
    nominal = HeliostatModel.from_config(CFG, [hid])
    current = nominal
    for k in range(1, len(points) + 1, 3):
        ref_model, ref = verdict.refit(nominal, points[:k], current, method="reference")
        fast_model, fast = verdict.refit(nominal, points[:k], current)
        _assert_equivalent(ref, fast, hid)
        np.testing.assert_array_equal(fast_model.params, fast.params[None, :])
        assert fast_model.ids == (hid,)
        current = fast_model


def test_refit_without_approach_keeps_the_start_dead_bands(recorded):
    """Without recorded approaches the dead bands are not fitted and stay at the start model's values."""
    points = [SimpleNamespace(**{**vars(p), "approach": None}) for p in recorded["H0001"][:10]]
    nominal = HeliostatModel.from_config(CFG, ["H0001"])
    start = nominal.with_params(em.from_dict({"backlash_1_mm": 0.3, "stroke_offset_1_mm": 1.0}))
    ref_model, ref = verdict.refit(nominal, points, start, method="reference")
    fast_model, fast = verdict.refit(nominal, points, start)
    assert fast.free == em.GEOMETRIC
    assert fast_model.params[0, em.index("backlash_1_mm")] == 0.3
    _assert_equivalent(ref, fast, "H0001")


@pytest.mark.parametrize("hid", ["H0001", "H0017"])
def test_leave_one_visit_out_errors_equal_reference(recorded, hid):
    points = recorded[hid]
    nominal = HeliostatModel.from_config(CFG, [hid])
    visit_points = verdict._visit_points(points)
    assert len(visit_points) >= 10
    model, full = verdict.refit(nominal, points, nominal)
    ref = verdict.loo_errors_mrad(CFG, nominal, points, visit_points, model, exact=True, method="reference")
    fast = verdict.loo_errors_mrad(CFG, nominal, points, visit_points, model, exact=True)
    assert np.max(np.abs(ref - fast)) < BEAM_TOL_MRAD
    # the one-step path (the campaign's verdict): vectorised prediction errors equal one model per visit
    step = verdict.loo_errors_mrad(CFG, nominal, points, visit_points, model, full=full)
    groups = [[k for k, p in enumerate(points) if p.visit_id == vp.visit_id] for vp in visit_points]
    from helicalib.calibration.fit import leave_out_params

    params = leave_out_params(full, groups)
    one_by_one = [verdict.prediction_error_mrad(nominal.with_params(params[g][None, :]), vp, CFG.target(vp.target_id))
                  for g, vp in enumerate(visit_points)]
    np.testing.assert_allclose(step, one_by_one, rtol=0, atol=1e-9)
    assert np.max(np.abs(step - fast)) < 0.05  # and the Newton step stays close to the exact refits


@pytest.mark.parametrize("kind", ["beam", "normal"])
def test_analytic_jacobian_matches_central_differences(recorded, kind):
    """At random parameters (every one drawn from its prior, dead bands included)."""
    points = recorded["H0017"]
    nominal = HeliostatModel.from_config(CFG, ["H0017"])
    strokes, sun, spot, approach = _inputs(points)
    prob = _Problem(nominal, strokes, sun, spot, kind, approach)
    bj = fit_solver.BeamJacobian(nominal.drives, nominal.pivots_enu[0], prob.strokes, prob.approach, prob.sun,
                                 prob.spot, prob.basis, kind)
    rng = np.random.default_rng(5)
    for _ in range(3):
        p = rng.normal(size=em.P) * em.PRIOR_SIGMA
        res, jac = bj.evaluate(p)
        np.testing.assert_allclose(res, prob.residuals(p[None, :])[0], rtol=0, atol=1e-9)
        h = 1e-4 * em.PRIOR_SIGMA
        sets = np.repeat(p[None, :], 2 * em.P, axis=0)
        sets[np.arange(em.P), np.arange(em.P)] += h
        sets[em.P + np.arange(em.P), np.arange(em.P)] -= h
        r = prob.residuals(sets)
        fd = np.transpose((r[: em.P] - r[em.P:]) / (2 * h)[:, None, None], (1, 2, 0))
        # per prior σ of each parameter [mrad]: central differences are good to ~1e-8 here
        err = np.max(np.abs(jac - fd), axis=(0, 1)) * em.PRIOR_SIGMA
        assert np.max(err) < 1e-6, dict(zip(em.NAMES, err))
        assert np.all(np.max(np.abs(fd), axis=(0, 1)) * em.PRIOR_SIGMA > 1e-3)  # every parameter moves the beam


def test_a_wrong_jacobian_is_caught(recorded, monkeypatch):
    """A Jacobian a few % off in one column still converges, to another point: the checks above see it."""
    points = recorded["H0001"]
    nominal = HeliostatModel.from_config(CFG, ["H0001"])
    strokes, sun, spot, approach = _inputs(points)
    ref = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach),
                          FitOptions(method="reference", n_suggestions=0))
    right = fit_solver.BeamJacobian.evaluate
    col = em.index("canting_1_mrad")

    def wrong(self, params, jacobian=True):
        res, jac = right(self, params, jacobian)
        if jac is not None:
            jac[:, :, col] += 0.03 * jac[:, :, em.index("pedestal_tilt_n_mrad")]
        return res, jac

    monkeypatch.setattr(fit_solver.BeamJacobian, "evaluate", wrong)
    bad = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach), FitOptions(n_suggestions=0),
                          solver="numpy")  # the numpy solver's BeamJacobian is the one patched
    assert bad.message == "Gauss-Newton converged"
    with pytest.raises(AssertionError):
        _assert_equivalent(ref, bad, "H0001")
    assert _beam_difference_mrad(ref, bad, "H0001") > BEAM_TOL_MRAD


def test_fast_fit_from_far_starts_reaches_the_same_minimum(recorded):
    points = recorded["H0017"][:20]
    nominal = HeliostatModel.from_config(CFG, ["H0017"])
    strokes, sun, spot, approach = _inputs(points)
    ref = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach),
                          FitOptions(method="reference", n_suggestions=0))
    rng = np.random.default_rng(11)
    for _ in range(4):
        start = 2.0 * rng.normal(size=em.P) * em.PRIOR_SIGMA
        _assert_equivalent(ref, fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach),
                                                FitOptions(n_suggestions=0), start=start), "H0017")
    with pytest.raises(ValueError, match="method"):
        fit_error_model(nominal, FitPoints(strokes, sun, spot), FitOptions(method="newton"))


def _cusp_problem(k: float, x0: float):
    """r = (x − 1, k·|x − x0|) with a Jacobian blind to the second term: at x0 every step the
    Jacobian proposes raises the cost, as round-off does at a real minimum."""
    def fun_jac(x):
        return np.array([x[0] - 1.0, k * abs(x[0] - x0)]), np.array([[1.0], [0.0]])
    return fun_jac


def test_gauss_newton_stalled_below_round_off_has_converged():
    x0 = 1.0 + 2e-7  # predicted gain 4e-14 of the cost: above ftol, far below STALL_FTOL
    x, r, _, converged, _ = fit_solver.gauss_newton(_cusp_problem(1e4, x0), np.array([x0]), "linear", 1.0)
    assert converged and x[0] == x0 and r[1] == 0.0


def test_gauss_newton_stalled_far_from_a_minimum_has_failed():
    x0 = 1.0 + 1e-3  # predicted gain 1e-6 of the cost: a real failure, not round-off
    x, _, _, converged, _ = fit_solver.gauss_newton(_cusp_problem(1e6, x0), np.array([x0]), "linear", 1.0)
    assert not converged and x[0] == x0


def test_a_prior_centre_keeps_what_few_points_cannot_see(recorded):
    """After a drift a heliostat is refitted on two checks with its earlier model as the priors'
    centre: the parameters the two points do not determine stay at that model, not at the nominal."""
    hid = "H0001"
    nominal = HeliostatModel.from_config(CFG, [hid])
    full = verdict.refit(nominal, recorded[hid], nominal)[1]
    few = recorded[hid][-2:]
    centred = verdict.refit(nominal, few, nominal.with_params(full.params[None, :]), prior_mean=full.params)[1]
    plain = verdict.refit(nominal, few, nominal.with_params(full.params[None, :]))[1]
    # the two points agree with the full fit, so the centred refit stays at it; the plain one is drawn to 0
    assert _beam_difference_mrad(full, centred, hid) < 0.1 * _beam_difference_mrad(full, plain, hid)
    assert _beam_difference_mrad(full, plain, hid) > 0.3
    # fast and reference solvers agree with a centre too, and so do the leave-one-out parameters
    ref = verdict.refit(nominal, few + recorded[hid][:3], nominal, method="reference", prior_mean=full.params)[1]
    fast = verdict.refit(nominal, few + recorded[hid][:3], nominal, prior_mean=full.params)[1]
    assert _beam_difference_mrad(ref, fast, hid) < 1e-3
    from helicalib.calibration.fit import leave_out_params

    pts = few + recorded[hid][:3]
    loo = leave_out_params(fast, [[0]])[0]
    exact = verdict.refit(nominal, pts[1:], nominal, prior_mean=full.params)[1].params
    np.testing.assert_allclose(loo[fast.linearisation.free_idx], exact[fast.linearisation.free_idx],
                               atol=0.05 * np.max(np.abs(full.params)))


def test_points_weighed_down_by_their_sigma(recorded):
    """A per-point σ scale: 1 changes nothing; a huge one removes the point (the fit equals the fit
    without it); fast and reference solvers agree under it."""
    hid = "H0017"
    pts = recorded[hid]
    strokes, sun, spot, approach = _inputs(pts)
    nominal = HeliostatModel.from_config(CFG, [hid])
    base = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach), FitOptions(n_suggestions=0))
    same = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach, sigma_scale=np.ones(len(pts))),
                           FitOptions(n_suggestions=0))
    np.testing.assert_allclose(same.params, base.params, atol=1e-12)
    scale = np.ones(len(pts))
    scale[:6] = 1e6
    down = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach, sigma_scale=scale),
                           FitOptions(n_suggestions=0))
    s2, u2, p2, a2 = _inputs(pts[6:])
    without = fit_error_model(nominal, FitPoints(s2, u2, p2, approach=a2), FitOptions(n_suggestions=0))
    assert _beam_difference_mrad(down, without, hid) < 1e-3
    assert _beam_difference_mrad(down, base, hid) > 10 * _beam_difference_mrad(down, without, hid)
    ref = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach, sigma_scale=scale),
                          FitOptions(n_suggestions=0, method="reference"))
    assert _beam_difference_mrad(ref, down, hid) < 1e-3


def _tilting(recorded, hid, rate, days=120.0, seed=3):
    """The recorded day's points seen again over ``days`` by a heliostat whose pedestal tilts at
    ``rate`` (east, north) [mrad/day]: each point gets an age and the spot that heliostat's beam
    made then (the recorded fit is the heliostat now). Returns (truth fit, inputs, ages, rows)."""
    from helicalib.calibration.fit_inputs import TILT as _TILT

    pts = recorded[hid]
    nominal = HeliostatModel.from_config(CFG, [hid])
    truth = verdict.refit(nominal, pts, nominal)[1]
    strokes, sun, _spot, approach = _inputs(pts)
    k = len(pts)
    age = np.random.default_rng(seed).permutation(np.linspace(0.0, days, k))
    rows = np.repeat(truth.params[None, :], k, axis=0)
    rows[:, _TILT] -= age[:, None] * np.asarray(rate)
    target = CFG.target(pts[0].target_id)
    uv = nominal.repeat(k).with_params(rows).spot_on_target(strokes, sun, [target] * k, approach)
    spot = np.array([target.uvw_to_enu(u) for u in uv])
    return nominal, truth, (strokes, sun, spot, approach), age, rows


def test_a_tilt_rate_keeps_old_points_consistent(recorded):
    """A pedestal that tilts 0.012 / -0.018 mrad a day over 120 days (up to 2.6 mrad): the fit with
    each point's age finds the rate and the heliostat as it is now; the fit without it misses by
    more than ten times as much. Fast (first order in the tilt change) and reference (each point
    with its own tilts) agree to the linearisation's second order."""
    hid = "H0001"
    rate = np.array([0.012, -0.018])
    nominal, truth, (strokes, sun, spot, approach), age, _rows = _tilting(recorded, hid, rate)
    data = FitPoints(strokes, sun, spot, approach=approach, age_days=age)
    fast = fit_error_model(nominal, data, FitOptions(n_suggestions=0))
    ref = fit_error_model(nominal, data, FitOptions(method="reference", n_suggestions=0))
    plain = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach), FitOptions(n_suggestions=0))
    assert fast.message == "Gauss-Newton converged"
    for f in (fast, ref):
        np.testing.assert_allclose(f.tilt_rate_mrad_per_day, rate, atol=3 * f.tilt_rate_sigma.max())
        assert f.tilt_rate_sigma.max() < 0.1 * np.abs(rate).min()
        assert f.rms_mrad < 0.05  # the points agree with a steadily tilting heliostat
    assert plain.rms_mrad > 0.5
    assert plain.tilt_rate_mrad_per_day is None
    assert _beam_difference_mrad(truth, plain, hid) > 10 * _beam_difference_mrad(truth, fast, hid)
    assert _beam_difference_mrad(fast, ref, hid) < 0.005


def test_leaving_a_visit_out_gives_the_tilts_of_its_time(recorded):
    """Leave-one-out parameters of a fit with a tilt rate are those of the left-out point's time:
    equal to a full refit without the point, moved back by its age."""
    from helicalib.calibration.fit import leave_out_params
    from helicalib.calibration.fit_inputs import TILT as _TILT

    hid = "H0001"
    nominal, _truth, (strokes, sun, spot, approach), age, rows = _tilting(recorded, hid, (0.012, -0.018))
    fast = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach, age_days=age),
                           FitOptions(n_suggestions=0))
    oldest = int(np.argmax(age))
    loo = leave_out_params(fast, [[oldest]])[0]
    keep = np.arange(len(age)) != oldest
    exact = fit_error_model(nominal, FitPoints(strokes[keep], sun[keep], spot[keep], approach=approach[keep],
                                               age_days=age[keep]),
                            FitOptions(n_suggestions=0))
    then = exact.params[_TILT] - age[oldest] * exact.tilt_rate_mrad_per_day
    np.testing.assert_allclose(loo[_TILT], then, atol=0.01)
    # and far from the tilts now (the heliostat moved by age × rate since)
    assert np.max(np.abs(loo[_TILT] - fast.params[_TILT])) > 1.0


def _drifted(recorded, hid, offsets, split=0.5):
    """The recorded day's points, the first ``split`` share of them seen by the heliostat before a
    drift: that epoch's parameters are the recorded fit plus ``offsets`` ({name: value}). Returns
    (nominal, truth fit, inputs, epochs (K,))."""
    pts = recorded[hid]
    nominal = HeliostatModel.from_config(CFG, [hid])
    truth = verdict.refit(nominal, pts, nominal)[1]
    strokes, sun, _spot, approach = _inputs(pts)
    k = len(pts)
    epoch = (np.random.default_rng(7).permutation(k) < int(split * k)).astype(int)
    rows = np.repeat(truth.params[None, :], k, axis=0)
    for name, v in offsets.items():
        rows[epoch == 1, em.index(name)] += v
    target = CFG.target(pts[0].target_id)
    uv = nominal.repeat(k).with_params(rows).spot_on_target(strokes, sun, [target] * k, approach)
    spot = np.array([target.uvw_to_enu(u) for u in uv])
    return nominal, truth, (strokes, sun, spot, approach), epoch


def test_each_epoch_gets_its_own_tilts_and_zero_offsets(recorded):
    """Half of one day's points from before a drift that tilted the pedestal by 3 / -2 mrad and
    moved actuator 1's zero by 2 mm (spots made noise-free by the recorded fit): with each point's
    epoch the points agree with one heliostat again (RMS under 0.05 mrad against 4.4 without), and
    the points from before the drift still inform its build, so its beams over the sky lie nearer
    the truth than a fit to the newest epoch's points alone does (0.35 against 0.66 mrad at most;
    one day's sun positions leave part of the sky to the priors). Fast and reference solvers agree
    to 0.001 mrad; leaving a visit out gives the parameters of its own epoch."""
    from helicalib.calibration.fit import leave_out_params

    hid = "H0001"
    drift = {"pedestal_tilt_e_mrad": 3.0, "pedestal_tilt_n_mrad": -2.0, "stroke_offset_1_mm": 2.0}
    nominal, truth, (strokes, sun, spot, approach), epoch = _drifted(recorded, hid, drift)
    data = FitPoints(strokes, sun, spot, approach=approach, epoch=epoch)
    fast = fit_error_model(nominal, data, FitOptions(n_suggestions=0))
    ref = fit_error_model(nominal, data, FitOptions(method="reference", n_suggestions=0))
    new = epoch == 0
    newest = fit_error_model(nominal, FitPoints(strokes[new], sun[new], spot[new], approach=approach[new]),
                             FitOptions(n_suggestions=0))
    plain = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach), FitOptions(n_suggestions=0))
    assert fast.message == "Gauss-Newton converged"
    for f in (fast, ref):
        assert f.epoch_offsets.shape == (2, em.P) and not np.any(f.epoch_offsets[0])
        assert f.rms_mrad < 0.05
        np.testing.assert_allclose(f.params_of_epoch(1), f.params + f.epoch_offsets[1])
    assert plain.rms_mrad > 1.0 and plain.epoch_offsets is None
    assert _beam_difference_mrad(fast, ref, hid) < BEAM_TOL_MRAD
    near = _beam_difference_mrad(truth, fast, hid)
    assert near < 0.75 * _beam_difference_mrad(truth, newest, hid)
    assert _beam_difference_mrad(truth, plain, hid) > 10 * near
    old = int(np.flatnonzero(epoch == 1)[0])
    loo = leave_out_params(fast, [[old]])[0]
    keep = np.arange(len(epoch)) != old
    exact = fit_error_model(nominal, FitPoints(strokes[keep], sun[keep], spot[keep], approach=approach[keep],
                                               epoch=epoch[keep]),
                            FitOptions(n_suggestions=0))
    np.testing.assert_allclose(loo, exact.params_of_epoch(1), atol=0.01)
    tilt = em.index("pedestal_tilt_e_mrad")
    assert abs(loo[tilt] - fast.params[tilt]) > 2.0  # the tilt of before the drift, not of now


def test_epochs_need_their_parameters_free(recorded):
    hid = "H0001"
    nominal, _truth, (strokes, sun, spot, approach), epoch = _drifted(recorded, hid, {"pedestal_tilt_e_mrad": 3.0})
    with pytest.raises(ValueError, match="pedestal_tilt_e_mrad"):
        fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=approach, epoch=epoch),
                        FitOptions(n_suggestions=0, free=[n for n in em.NAMES if n != "pedestal_tilt_e_mrad"]))


def test_an_epoch_without_observations_rests_on_its_prior(recorded):
    """Epochs 0 and 2 hold the points, epoch 1 none (a drift confirmed twice with no point between):
    the fit still solves, epoch 1's offsets stay at their prior's centre, and the fast and
    reference solvers agree."""
    hid = "H0001"
    nominal, _truth, (strokes, sun, spot, approach), epoch = _drifted(recorded, hid, {"pedestal_tilt_e_mrad": 3.0})
    epoch = 2 * epoch  # the points before the drift are two epochs back
    data = FitPoints(strokes, sun, spot, approach=approach, epoch=epoch)
    fast = fit_error_model(nominal, data, FitOptions(n_suggestions=0))
    ref = fit_error_model(nominal, data, FitOptions(method="reference", n_suggestions=0))
    assert fast.message == "Gauss-Newton converged"
    assert fast.epoch_offsets.shape == (3, em.P)
    np.testing.assert_allclose(fast.epoch_offsets[1], 0.0, atol=1e-9)
    assert fast.epoch_offsets[2, em.index("pedestal_tilt_e_mrad")] > 1.0  # one day shares the 3 mrad with the zero offsets
    assert _beam_difference_mrad(fast, ref, hid) < BEAM_TOL_MRAD
