"""calibration.tracking_test: clause 8.2 verdicts on constructed series at the edges of the limits."""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.calibration.tracking_test import (plot_tracking_test, precision_angles_mrad, tracking_errors_mrad,
                                                 tracking_test)
from helicalib.config import TrackingTest

SPEC = TrackingTest(threshold_mrad=3.5, wind_bins=[{"wind_ms": 4, "min_fraction": 0.99},
                                                   {"wind_ms": 8, "min_fraction": 0.62},
                                                   {"wind_ms": 11, "min_fraction": 0.33}], bin_half_width_ms=1.0)


def _series(wind, n, n_within):
    """n measurements at ``wind`` m/s of which n_within are at 3.5 mrad exactly (within) and the rest at 3.51."""
    return np.r_[np.full(n_within, 3.5), np.full(n - n_within, 3.51)], np.full(n, float(wind))


def _combine(*parts):
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def test_passes_just_above_every_limit():
    eta, wind = _combine(_series(4, 200, 199), _series(8, 100, 63), _series(11, 100, 34))
    r = tracking_test(eta, wind, SPEC)
    assert r.verdict == "pass", r.message
    assert [b.n for b in r.bins] == [200, 100, 100]
    assert [b.within for b in r.bins] == [199, 63, 34]


@pytest.mark.parametrize("which", [0, 1, 2])
def test_exactly_at_a_limit_fails_because_8_2_says_greater_than(which):
    parts = [_series(4, 200, 199), _series(8, 100, 63), _series(11, 100, 34)]
    parts[which] = [_series(4, 100, 99), _series(8, 100, 62), _series(11, 100, 33)][which]
    r = tracking_test(*_combine(*parts), SPEC)
    assert r.verdict == "fail"
    assert [b.passed for b in r.bins] == [k != which for k in range(3)]
    assert f"{SPEC.wind_bins[which].wind_ms:g} m/s" in r.message


def test_bins_are_centre_plus_minus_half_width_inclusive():
    # 3.0 and 5.0 m/s belong to the 4 m/s bin, 5.01 and 2.99 to none
    eta = np.array([1.0, 1.0, 9.0, 9.0])
    wind = np.array([3.0, 5.0, 5.01, 2.99])
    r = tracking_test(eta, wind, SPEC)
    assert r.bins[0].n == 2 and r.bins[0].passed
    assert r.verdict == "incomplete" and "8 m/s" in r.message and "11 m/s" in r.message


def test_a_failing_bin_outranks_an_empty_one_and_nans_are_dropped():
    eta, wind = _series(8, 10, 2)
    r = tracking_test(np.r_[eta, np.nan], np.r_[wind, 8.0], SPEC)
    assert r.verdict == "fail" and r.n == 10


def test_accuracy_and_precision_rms_and_formula_1():
    pivot = np.array([0.0, 100.0, 0.0])
    aim = np.array([0.0, 0.0, 0.0])
    # spots 0.2 m and 0.4 m off the aim point at 100 m: 2 and 4 mrad by formula (1)
    spots = np.array([[0.2, 0.0, 0.0], [0.0, 0.0, 0.4]])
    eta = tracking_errors_mrad(spots, aim, pivot)
    assert np.allclose(eta, [2.0, 4.0])
    prec = precision_angles_mrad(spots, pivot)
    # the mean spot is (0.1, 0, 0.2); each spot is sqrt(0.1² + 0.2²) m from it; distance to P ≈ 100 m
    d = np.hypot(0.1, 0.2)
    assert np.allclose(prec, 1000 * d / np.linalg.norm(np.array([0.1, 0.0, 0.2]) - pivot))
    r = tracking_test(eta, [4.0, 4.0], SPEC, precision_mrad=prec)
    assert r.accuracy_rms_mrad == pytest.approx(np.sqrt((4 + 16) / 2))
    assert r.fraction_within == 0.5
    assert r.precision_rms_mrad == pytest.approx(prec[0])


def test_plot_is_a_png(tmp_path):
    eta, wind = _combine(_series(4, 50, 50), _series(8, 50, 40), _series(11, 50, 20))
    out = tmp_path / "fig3.png"
    plot_tracking_test({"H0001": (eta, wind)}, SPEC, out)
    assert out.read_bytes().startswith(b"\x89PNG")
