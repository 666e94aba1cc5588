"""Drift evidence of a re-check, on recorded campaign observations (tests/data/fit_observations.csv,
a one-day simulated campaign of the demo field)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from helicalib.campaign.book import book_points
from helicalib.campaign.verdict import refit
from helicalib.campaign.operation.drift import drift_evidence
from helicalib.geometry.heliostat import HeliostatModel
from test_calibration_fit_fast import CFG, recorded  # noqa: F401  (the fixture)


def _moved(point, mrad: float):
    """The same observation with its spot moved across the beam by ``mrad`` seen from the mirror."""
    spot = np.asarray(point.spot_enu_m, float)
    origin = np.asarray(CFG.heliostat(point.heliostat_id).position_enu_m, float)
    d = spot - origin
    across = np.cross(d, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    return SimpleNamespace(**{**vars(point), "spot_enu_m": tuple(spot + 1e-3 * mrad * np.linalg.norm(d) * across)})


@pytest.fixture(scope="module")
def fitted(recorded):  # noqa: F811
    points = recorded["H0001"]
    nominal = HeliostatModel.from_config(CFG, ["H0001"])
    model, fit = refit(nominal, points[:30], nominal)
    assert fit is not None
    return nominal, model, points


def test_an_unchanged_heliostat_shows_no_drift(fitted):
    nominal, model, points = fitted
    later = [drift_evidence(nominal, model, points[:30], p) for p in points[30:]]
    assert later and all(d is not None for d in later)
    assert sum(d["drift"] for d in later) == 0
    assert all(d["band_mrad"] > 0 and d["fit_points"] == 30 for d in later)


@pytest.mark.parametrize("mrad", [3.0, 5.0])
def test_a_moved_beam_is_drift(fitted, mrad):
    nominal, model, points = fitted
    d = drift_evidence(nominal, model, points[:30], _moved(points[31], mrad))
    assert d["drift"] and d["p_value"] < 1e-3
    assert d["residual_mrad"] == pytest.approx(mrad, abs=0.8)
    assert d["residual_mrad"] > 3 * d["band_mrad"]


def test_without_a_fit_there_is_no_evidence(fitted):
    nominal, model, points = fitted
    assert drift_evidence(nominal, model, [], points[31]) is None


def test_book_points_are_the_located_ones_since_the_epoch():
    base = SimpleNamespace(heliostat_id="H0001", visit_id=1, valid=True, capture_time_s=10.0, spot_enu_m=(1.0, 2.0, 3.0),
                           sun_enu=(0.0, 0.6, 0.8))
    later = SimpleNamespace(**{**vars(base), "capture_time_s": 11.0})
    rows = [base, later,
            SimpleNamespace(**{**vars(base), "valid": False}),
            SimpleNamespace(**{**vars(base), "spot_enu_m": None}),
            SimpleNamespace(**{**vars(base), "spot_enu_m": (np.nan, 0.0, 0.0)})]
    assert book_points(rows) == [base, later]
    assert book_points(rows, since_s=10.5) == [later]
