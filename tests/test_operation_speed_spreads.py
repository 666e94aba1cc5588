"""Operation's day grid of predicted beam errors: all the day's suns in one pass give exactly the
numbers of one :func:`~helicalib.calibration.fit.beam_spread_mrad` per sun (the preferred check
times, and so the campaign, do not change)."""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.calibration.fit import beam_spread_mrad
from helicalib.campaign.operation import checks
from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_at_site, to_unix_seconds


@pytest.fixture(scope="module")
def day(demo_field_path):
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats][:12]
    rng = np.random.default_rng(11)
    model = HeliostatModel.from_config(cfg, ids)
    model = model.with_params(0.5 * rng.normal(size=model.params.shape) * em.PRIOR_SIGMA)
    aims = np.array([cfg.target(cfg.heliostat(h).target).center_enu_m for h in ids], dtype=float)
    root = rng.normal(size=(len(ids), em.P, em.P)) * (0.05 * em.PRIOR_SIGMA)[None, :, None]
    cov = np.einsum("nij,nkj->nik", root, root)  # symmetric, positive semi-definite, heliostat by heliostat
    t0 = float(to_unix_seconds("2026-06-21T00:00:00Z"))
    pos = sun_at_site(cfg.site, t0 + np.arange(0.0, 86400.0, 1800.0))
    suns = np.asarray(pos.vector_enu)[pos.elevation_deg >= -5.0]  # low suns too: some aims out of reach
    return model, cov, suns, aims


def _one_sun_at_a_time(model, cov, suns, aims):
    return np.array([beam_spread_mrad(model, cov, s, aims) for s in suns])


def test_one_pass_over_the_suns_equals_one_call_per_sun(day):
    model, cov, suns, aims = day
    got = checks.spreads_over_suns(model, cov, suns, aims)
    want = _one_sun_at_a_time(model, cov, suns, aims)
    assert got.shape == (len(suns), len(model))
    assert np.isfinite(want).sum() > len(model)  # the comparison is of numbers, not of NaNs only
    np.testing.assert_array_equal(got, want)  # bit for bit: the same preferred times


def test_passes_split_by_the_row_cap_give_the_same_numbers(day, monkeypatch):
    model, cov, suns, aims = day
    whole = checks.spreads_over_suns(model, cov, suns, aims)
    monkeypatch.setattr(checks, "SPREAD_ROWS_PER_PASS", 3 * len(model) * (em.P + 1))  # three suns a pass
    parts = checks.spreads_over_suns(model, cov, suns, aims)
    np.testing.assert_array_equal(parts, whole)
    monkeypatch.setattr(checks, "SPREAD_ROWS_PER_PASS", 1)  # one sun a pass
    np.testing.assert_array_equal(checks.spreads_over_suns(model, cov, suns, aims), whole)
