"""Acceptance with uncertainty: the year-round prediction from a fit's covariance."""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.calibration import uncertainty as unc
from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_at_site, to_unix_seconds

IDS = ["H0001", "H0012", "H0033"]


@pytest.fixture(scope="module")
def field(demo_field_path):
    cfg = load_field_config(demo_field_path)
    rng = np.random.default_rng(5)
    model = HeliostatModel.from_config(cfg, IDS)
    model = model.with_params(0.5 * rng.normal(size=model.params.shape) * em.PRIOR_SIGMA)
    model = model.with_params(np.where(np.isin(np.arange(em.P), [em.index(n) for n in em.BACKLASH]), 0.0,
                                       model.params))
    aims = np.array([cfg.target(cfg.heliostat(h).target).center_enu_m for h in IDS])
    t0 = float(to_unix_seconds("2026-01-01T00:00:00Z"))
    times = t0 + (np.arange(0, 365, 14)[:, None] * 86400.0 + np.arange(0, 1440, 60)[None, :] * 60.0).ravel()
    pos = sun_at_site(cfg.site, times)
    sun = np.asarray(pos.vector_enu)[pos.elevation_deg >= 5.0]
    return model, aims, sun


def _cov(scale: float, n: int = len(IDS)) -> np.ndarray:
    sig = scale * em.PRIOR_SIGMA.copy()
    sig[[em.index(n_) for n_ in em.BACKLASH]] = 0.0
    return np.repeat(np.diag(sig**2)[None], n, axis=0)


def test_no_uncertainty_predicts_only_the_unexplained_error(field):
    model, aims, sun = field
    zero = unc.year_prediction(model, _cov(0.0), sun, aims)
    assert np.all(zero.expected_rms_mrad == 0) and np.all(zero.interval_mrad == 0) and np.all(zero.p_exceed == 0)
    assert np.all(zero.reachable > 0.5)
    floor = unc.year_prediction(model, _cov(0.0), sun, aims, unexplained_mrad=np.array([0.5, 1.0, 2.0]))
    np.testing.assert_allclose(floor.expected_rms_mrad, [0.5, 1.0, 2.0])
    np.testing.assert_allclose(floor.interval_mrad, [[0.5, 0.5], [1.0, 1.0], [2.0, 2.0]])
    np.testing.assert_array_equal(floor.p_exceed, [0.0, 0.0, 1.0])  # above 1.2 mrad everywhere or nowhere


def test_the_prediction_scales_with_the_parameter_spread(field):
    model, aims, sun = field
    a = unc.year_prediction(model, _cov(0.05), sun, aims, seed=3)
    b = unc.year_prediction(model, 4.0 * _cov(0.05), sun, aims, seed=3)  # twice the σ
    np.testing.assert_allclose(b.expected_rms_mrad, 2.0 * a.expected_rms_mrad, rtol=1e-9)
    np.testing.assert_allclose(b.interval_mrad, 2.0 * a.interval_mrad, rtol=1e-9)
    assert np.all(b.p_exceed >= a.p_exceed)
    assert np.all(a.interval_mrad[:, 0] < a.expected_rms_mrad) and np.all(a.expected_rms_mrad < a.interval_mrad[:, 1])


def test_the_linearised_prediction_matches_the_model_itself(field):
    """Independent check: draw parameter errors, command the fitted model's strokes, and measure the
    perturbed model's true beam angle against the aim; its mean square over draws and the path is
    the predicted expected RMS²."""
    model, aims, sun = field
    cov = _cov(0.05)
    pred = unc.year_prediction(model, cov, sun, aims)
    rng = np.random.default_rng(9)
    for i in range(len(IDS)):
        one = model.subset([i])
        sol = one.repeat(len(sun)).strokes_for_aim(sun, aims[i])
        ok = sol.in_range
        sq = []
        for _ in range(400):
            dp = rng.normal(size=em.P) * np.sqrt(np.diag(cov[i]))
            pert = one.with_params(one.params + dp).repeat(int(ok.sum()))
            origin, beam = pert.beam(sol.strokes_mm[ok], sun[ok])
            want = optics.unit(aims[i] - origin)
            sq.append(np.mean((1000.0 * np.arccos(np.clip(np.sum(beam * want, axis=1), -1, 1))) ** 2))
        mc = np.sqrt(np.mean(sq))
        assert mc == pytest.approx(pred.expected_rms_mrad[i], rel=0.05), (IDS[i], mc, pred.expected_rms_mrad[i])


def test_figures_do_not_depend_on_the_chunking(field, monkeypatch):
    model, aims, sun = field
    whole = unc.year_prediction(model, _cov(0.1), sun, aims, seed=1)
    monkeypatch.setattr(unc, "_CHUNK_ELEMENTS", 1)  # one heliostat at a time
    parts = unc.year_prediction(model, _cov(0.1), sun, aims, seed=1)
    np.testing.assert_allclose(parts.interval_mrad, whole.interval_mrad, rtol=1e-12)
    np.testing.assert_allclose(parts.p_exceed, whole.p_exceed)
    np.testing.assert_allclose(parts.expected_rms_mrad, whole.expected_rms_mrad, rtol=1e-12)


def test_the_beam_jacobian_is_the_one_the_planner_uses(field):
    from helicalib.calibration.fit import beam_spread_mrad

    model, aims, sun = field
    cov = _cov(0.1)
    jac, ok = unc.beam_jacobians_mrad(model, sun[:3], aims)
    for m in range(3):
        spread = beam_spread_mrad(model, cov, sun[m], aims)
        own = np.sqrt(np.einsum("nip,npq,niq->n", jac[:, m], cov, jac[:, m]))
        np.testing.assert_allclose(np.where(ok[:, m], own, np.nan), spread, rtol=1e-12)


def test_unexplained_error_from_residuals():
    assert unc.unexplained_mrad(0.5, 0.3) == pytest.approx(np.sqrt(0.25 - 0.18))
    assert unc.unexplained_mrad(0.3, 0.3) == 0.0


def _checks(cfg, model, aim, true_params, sun, sigma, rng):
    """Spots of the true heliostat at the strokes the fitted ``model`` commands, with noise σ [mrad]."""
    from helicalib.calibration.fit_solver import beam_basis as _basis

    k = len(sun)
    strokes = model.repeat(k).strokes_for_aim(sun, aim).strokes_mm
    origin, d = model.with_params(true_params[None]).repeat(k).beam(strokes, sun)
    noisy = optics.unit(d + 1e-3 * sigma * np.einsum("ki,kij->kj", rng.normal(size=(k, 2)), _basis(d)))
    _uv, hit, _ = optics.intersect_target(origin, noisy, cfg.target(cfg.heliostat(IDS[0]).target))
    return strokes, hit


def test_checks_of_an_unchanged_heliostat_fall_in_the_band_as_often_as_promised(field, demo_field_path):
    cfg = load_field_config(demo_field_path)
    model, aims, sun = field
    one, cov = model.subset([0]), _cov(0.03)[0]
    rng = np.random.default_rng(4)
    root = np.sqrt(np.diag(cov))
    d2, outside = [], []
    for _ in range(150):  # the truth drawn from the fit's posterior: nothing changed since the fit
        truth = one.params[0] + root * rng.normal(size=em.P)
        strokes, spot = _checks(cfg, one, aims[0], truth, sun[::12], 0.3, rng)
        test = unc.check_against_fit(one, cov, strokes, sun[::12], spot, sigma_mrad=0.3, alpha=0.05)
        d2.extend(test.distance2)
        outside.extend(test.outside)
    d2 = np.asarray(d2)
    n = len(d2)
    assert abs(np.mean(d2) - 2.0) < 0.15 * 2.0  # χ² with 2 degrees of freedom has mean 2
    assert abs(np.mean(outside) - 0.05) < 4 * np.sqrt(0.05 * 0.95 / n) + 0.01


def test_a_settled_pedestal_is_outside_the_band(field, demo_field_path):
    cfg = load_field_config(demo_field_path)
    model, aims, sun = field
    one, cov = model.subset([0]), _cov(0.03)[0]
    rng = np.random.default_rng(6)
    truth = one.params[0].copy()
    truth[em.index("pedestal_tilt_e_mrad")] += 2.0  # a 2 mrad settling step
    strokes, spot = _checks(cfg, one, aims[0], truth, sun[::12], 0.3, rng)
    test = unc.check_against_fit(one, cov, strokes, sun[::12], spot, sigma_mrad=0.3)
    assert np.mean(test.outside) > 0.9
    strokes_same, spot_same = _checks(cfg, one, aims[0], one.params[0], sun[::12], 0.3, rng)
    same = unc.check_against_fit(one, cov, strokes_same, sun[::12], spot_same, sigma_mrad=0.3)
    assert np.mean(same.outside) < 0.1
    # a wider covariance (a fit that knows less) widens the band: the same step stands out less
    wide = unc.check_against_fit(one, 25.0 * cov, strokes, sun[::12], spot, sigma_mrad=0.3)
    assert np.all(wide.distance2 < test.distance2) and np.all(wide.band_mrad > test.band_mrad)
