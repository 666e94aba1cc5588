"""Error-model fit: injected parameters recovered within the fit's stated 3σ from noisy synthetic data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helicalib.calibration.fit import (FitOptions, FitPoints, beam_spread_mrad, fit_error_model, leave_out_params,
                                      predict_strokes)
from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_at_site

CFG = load_field_config(Path(__file__).resolve().parents[1] / "field_config" / "demo_north.yaml")
_T = pd.date_range("2026-01-03", "2026-12-28", freq="29h", tz="UTC")
_SP = sun_at_site(CFG.site, _T)
SUNS = _SP.vector_enu[_SP.elevation_deg > 8.0]  # a year of real sun positions at the demo site
NOISE_MRAD = 0.2
# injected errors: every parameter at ±1.5 prior σ (signs alternate), a plausible badly built heliostat
PATTERN = 1.5 * np.where(np.arange(em.P) % 2 == 0, 1.0, -1.0) * em.PRIOR_SIGMA


def _observe(hid, true_params, k, seed, outlier_mrad=0.0):
    return _observe_approached(hid, true_params, k, seed, outlier_mrad)[:7]


def _observe_approached(hid, true_params, k, seed, outlier_mrad=0.0, approached=False):
    """Synthetic observations; with ``approached`` each actuator arrives from a random side (±1,
    returned as the 8th item) and the plant's dead bands (its backlash parameters) act."""
    rng = np.random.default_rng(seed)
    model = HeliostatModel.from_config(CFG, [hid])
    target = CFG.target(CFG.heliostat(hid).target)
    aim = np.asarray(target.center_enu_m)
    plant = model.with_params(true_params)
    sun = SUNS[rng.choice(len(SUNS), k, replace=False)]
    held = model.repeat(k).strokes_for_aim(sun, aim)  # what an uncalibrated controller commands
    assert held.in_range.all()
    approach = np.where(np.random.default_rng(seed + 1000).random((k, 2)) < 0.5, -1.0, 1.0) if approached else None
    origin, direction = plant.repeat(k).beam(held.strokes_mm, sun, approach)
    _, hit, valid = optics.intersect_target(origin, direction, target)
    assert valid.all()
    dist = np.linalg.norm(hit - model.pivots_enu[0], axis=1)
    noise_m = rng.normal(size=(k, 2)) * (NOISE_MRAD * 1e-3 * dist)[:, None]
    if outlier_mrad:
        noise_m[0] += outlier_mrad * 1e-3 * dist[0] * np.array([0.6, 0.8])
    spot = hit + noise_m @ target.frame_enu[:2]
    return model, plant, held.strokes_mm, sun, spot, aim, target, approach


@pytest.mark.parametrize("hid", ["H0001", "H0017", "H0033"])
@pytest.mark.parametrize("kind", ["beam", "normal"])
def test_fit_recovers_injected_parameters_within_3_sigma(hid, kind):
    model, plant, strokes, sun, spot, aim, _, approach = _observe_approached(hid, PATTERN, 24, seed=int(hid[1:]),
                                                                             approached=True)
    res = fit_error_model(model, FitPoints(strokes, sun, spot, approach=approach),
                          FitOptions(sigma_mrad=NOISE_MRAD, residual_kind=kind))
    assert res.success
    assert res.free == em.NAMES  # with approaches, the dead bands are fitted too
    z = (res.params - PATTERN) / res.sigma
    assert np.all(np.abs(z) <= 3.0), dict(zip(em.NAMES, np.round(z, 2)))
    # the data pin down the main parameters far better than the prior
    for name in ("stroke_offset_2_mm", "canting_1_mrad", "pedestal_tilt_n_mrad", "backlash_1_mm", "backlash_2_mm"):
        assert name in res.identifiability.determined
        assert res.sigma[em.index(name)] < 0.5 * em.PRIOR_SIGMA[em.index(name)]
    # residuals are at the noise level (beam kind: two components of NOISE_MRAD each)
    scale = 1.0 if kind == "beam" else 0.5
    assert res.rms_mrad < 2.5 * NOISE_MRAD * scale * np.sqrt(2)


def test_calibrated_model_predicts_strokes_for_other_sun_positions():
    model, plant, strokes, sun, spot, aim, target = _observe("H0010", PATTERN, 20, seed=7)
    res = fit_error_model(model, FitPoints(strokes, sun, spot), FitOptions(sigma_mrad=NOISE_MRAD))
    others = SUNS[::5]
    sol = predict_strokes(res, others, aim)
    origin, direction = plant.repeat(len(others)).beam(sol.strokes_mm, others)
    _, hit, _ = optics.intersect_target(origin, direction, target)
    err = optics.tracking_error_exact_mrad(hit, aim, plant.pivots_eff_enu[0])
    nominal = model.repeat(len(others)).strokes_for_aim(others, aim)
    o0, d0 = plant.repeat(len(others)).beam(nominal.strokes_mm, others)
    err0 = optics.tracking_error_exact_mrad(optics.intersect_target(o0, d0, target)[1], aim, plant.pivots_eff_enu[0])
    assert np.sqrt(np.mean(err0**2)) > 5.0  # uncalibrated: far off
    assert np.sqrt(np.mean(err**2)) < 0.3  # calibrated: near the measurement noise


def test_robust_loss_resists_an_outlier():
    model, plant, strokes, sun, spot, aim, _ = _observe("H0005", PATTERN, 16, seed=11, outlier_mrad=25.0)
    res = fit_error_model(model, FitPoints(strokes, sun, spot), FitOptions(sigma_mrad=NOISE_MRAD))
    assert res.free == em.GEOMETRIC  # without approaches the dead bands are not fitted (nor seen)
    free = [em.index(n) for n in res.free]
    z = (res.params[free] - PATTERN[free]) / res.sigma[free]
    assert np.all(np.abs(z) <= 3.0)
    assert res.residual_mrad[0] > 50 * NOISE_MRAD  # the outlier stands out
    assert np.median(res.residual_mrad[1:]) < 3 * NOISE_MRAD
    plain = fit_error_model(model, FitPoints(strokes, sun, spot), FitOptions(sigma_mrad=NOISE_MRAD, loss="linear"))
    assert plain.residual_mrad[0] < res.residual_mrad[0]  # least squares bends toward the outlier


def test_identifiability_one_sun_position_is_not_enough():
    model, plant, strokes, sun, spot, aim, _ = _observe("H0012", PATTERN, 1, seed=3)
    strokes, sun, spot = (np.repeat(a, 6, axis=0) for a in (strokes, sun, spot))
    res = fit_error_model(model, FitPoints(strokes, sun, spot), FitOptions(sigma_mrad=NOISE_MRAD))
    ident = res.identifiability
    assert len(ident.prior_dominated) >= 6
    assert all(ident.data_fraction[n] < 0.75 for n in ("arm_scale_1", "arm_scale_2", "pivot_de_m"))
    best = ident.suggestions[0]
    assert best["gain"] > 0
    assert 1000 * optics.angle_between_rad(np.asarray(best["sun_enu"]), sun[0]) > 100.0  # somewhere else in the sky


def test_free_subset_and_fixed_values():
    model, plant, strokes, sun, spot, aim, _ = _observe("H0020", PATTERN, 8, seed=5)
    free = ("stroke_offset_1_mm", "stroke_offset_2_mm")
    res = fit_error_model(model, FitPoints(strokes, sun, spot), FitOptions(free=free))
    others = [i for i in range(em.P) if em.NAMES[i] not in free]
    assert np.all(res.params[others] == 0.0) and np.all(res.sigma[others] == 0.0)
    assert res.free == free
    with pytest.raises(ValueError):
        fit_error_model(HeliostatModel.from_config(CFG, ["H0001", "H0002"]), FitPoints(strokes, sun, spot))


def test_beam_spread_matches_monte_carlo_of_the_fit_covariance():
    """The linear predicted beam uncertainty agrees with sampling parameters from the fit's
    covariance and measuring, for the same strokes, the true angle between the beam and the aim."""
    ids = ["H0001", "H0017", "H0033"]
    fits, models = [], []
    for hid in ids:
        model, _plant, strokes, sun, spot, aim, _ = _observe(hid, PATTERN, 6, seed=7)
        fits.append(fit_error_model(model, FitPoints(strokes, sun, spot), FitOptions(sigma_mrad=NOISE_MRAD)))
        models.append(model)
    fitted = HeliostatModel.from_config(CFG, ids, np.vstack([f.params for f in fits]))
    cov = np.stack([f.covariance for f in fits])
    aims = np.array([CFG.target(CFG.heliostat(h).target).center_enu_m for h in ids])
    sun = sun_at_site(CFG.site, pd.Timestamp("2026-12-21T03:00:00Z")).vector_enu.reshape(3)
    spread = beam_spread_mrad(fitted, cov, sun, aims)
    rng = np.random.default_rng(3)
    for i in range(len(ids)):
        one = fitted.subset([i])
        strokes = one.strokes_for_aim(sun, aims[i]).strokes_mm
        draws = rng.multivariate_normal(fits[i].params, cov[i], size=400)
        sampled = one.repeat(400).with_params(draws)
        origin, direction = sampled.beam(np.repeat(strokes, 400, axis=0), sun)
        err = 1000.0 * optics.angle_between_rad(direction, optics.unit(aims[i] - origin))
        mc = np.sqrt(np.mean(err**2))
        assert abs(spread[i] - mc) < 0.15 * mc, (ids[i], spread[i], mc)
    assert np.all(spread > 0.1)  # six points leave a noticeable uncertainty
    # more data where it is asked for: the spread at this sun shrinks
    tight = beam_spread_mrad(fitted, cov * 0.01, sun, aims)
    np.testing.assert_allclose(tight, 0.1 * spread, rtol=1e-6)


@pytest.mark.parametrize("outlier", [0.0, 4.0])
def test_leave_out_params_match_full_refits(outlier):
    """One Newton step from the full solution gives the same left-out models as refitting without
    each group (pairs of observations, like a visit's placements), also with a robust-loss outlier."""
    model, _plant, strokes, sun, spot, aim, target = _observe("H0017", PATTERN, 12, seed=11, outlier_mrad=outlier)
    full = fit_error_model(model, FitPoints(strokes, sun, spot), FitOptions(sigma_mrad=NOISE_MRAD))
    groups = [[2 * g, 2 * g + 1] for g in range(6)]
    fast = leave_out_params(full, groups)
    for g, idx in enumerate(groups):
        keep = np.setdiff1d(np.arange(12), idx)
        slow = fit_error_model(model, FitPoints(strokes[keep], sun[keep], spot[keep]),
                               FitOptions(sigma_mrad=NOISE_MRAD))
        # compare what matters: where each model puts the left-out beams on the board [mrad]
        for i in idx:
            a = model.with_params(fast[g]).spot_on_target(strokes[i:i + 1], sun[i], target)[0]
            b = slow.model.spot_on_target(strokes[i:i + 1], sun[i], target)[0]
            dist = np.linalg.norm(target.uvw_to_enu(b) - model.pivots_enu[0])
            assert 1000.0 * np.linalg.norm(a - b) / dist < 0.05, (g, i)
    # and leaving a group out moves the model (the step is not a no-op)
    assert np.max(np.abs(fast - full.params) / em.PRIOR_SIGMA) > 0.01
