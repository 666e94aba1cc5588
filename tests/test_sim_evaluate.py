"""The end-of-run sky evaluation (sim/evaluate.py): one pass for both backlash settings, a subset
of rows, and the errors against a direct computation of the true beam."""

from pathlib import Path

import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.sun import year_sun_times
from helicalib.sim.evaluate import evaluate_model, evaluate_models
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import Scenario

FIELD = Path(__file__).resolve().parents[1] / "field_config" / "demo_north.yaml"
T0 = 1_780_500_000.0


@pytest.fixture(scope="module")
def case():
    cfg = load_field_config(FIELD)
    truth = SimulatedPlant(cfg, Scenario(), start_s=T0).truth
    rng = np.random.default_rng(7)
    params = truth.params0 + rng.normal(0.0, 0.3, truth.params0.shape) * em.PRIOR_SIGMA
    times, sun = year_sun_times(cfg.site, 2026, step_days=61.0, step_min=120.0)
    return cfg, truth, params, times, sun


def test_one_pass_gives_each_backlash_setting_as_alone(case):
    _cfg, truth, params, times, sun = case
    both = evaluate_models(truth, params, times, sun, t_eval_s=T0 + 86400.0, backlash=("tracking", "none"))
    for b in ("tracking", "none"):
        alone = evaluate_models(truth, params, times, sun, t_eval_s=T0 + 86400.0, backlash=(b,))[b]
        assert np.array_equal(both[b].errors_mrad, alone.errors_mrad, equal_nan=True)
        assert np.array_equal(both[b].errors_formula1_mrad, alone.errors_formula1_mrad, equal_nan=True)
    # backlash changes the answer: the two settings are not the same figures under another name
    assert not np.array_equal(both["tracking"].errors_mrad, both["none"].errors_mrad, equal_nan=True)


def test_rows_evaluate_only_those_heliostats_with_the_same_errors(case):
    _cfg, truth, params, times, sun = case
    full = evaluate_model(truth, params, times, sun, backlash="tracking")
    rows = [9, 2, 30]
    part = evaluate_model(truth, params, times, sun, backlash="tracking", rows=rows)
    assert np.array_equal(part.errors_mrad[rows], full.errors_mrad[rows], equal_nan=True)
    others = np.setdiff1d(np.arange(truth.n), rows)
    assert np.all(np.isnan(part.errors_mrad[others]))
    flat = full.errors_mrad[sorted(rows)]
    flat = flat[np.isfinite(flat)]
    assert part.field_rms_mrad == pytest.approx(float(np.sqrt(np.mean(flat**2))), rel=1e-12)


def test_errors_match_the_true_beam_computed_directly(case):
    cfg, truth, params, times, sun = case
    ev = evaluate_model(truth, params, times, sun, backlash="none")
    model = truth.nominal.with_params(params)
    aims = np.array([cfg.target(h.target).center_enu_m for h in cfg.heliostats], dtype=float)
    for k in (0, len(sun) // 2):
        sol = model.strokes_for_aim(sun[k], aims)
        beam = truth.beam(np.where(sol.in_range[:, None], sol.strokes_mm, 0.0), sun[k], truth.start_s, jitter=False)
        want = 1000.0 * optics.angle_between_rad(beam.direction_enu, aims - beam.origin_enu)
        ok = sol.in_range & np.isfinite(ev.errors_mrad[:, k])
        assert ok.sum() >= truth.n // 2
        np.testing.assert_allclose(ev.errors_mrad[ok, k], want[ok], rtol=0, atol=1e-9)
