"""The exposure policy (campaign/exposure.py), pure: expected peak irradiance, the chosen exposure,
the gain learned from valid readings, and the retake's corrected exposure."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helicalib.campaign import exposure as ex
from helicalib.campaign.exposure import ExposurePolicy, SpotFigures, expected_peak_wm2

SUN_UP = np.array([0.0, 0.0, 1.0])
BOARD = (np.array([0.0, 0.0, 100.0]), np.array([0.0, 1.0, 0.0]))  # centre, normal (facing north)


def _peak(distance_m, dni=1000.0, clean=1.0, sun=SUN_UP, mirror=(4.0, 4.0), atmosphere="none"):
    centre, normal = BOARD
    pivot = centre + distance_m * np.array([0.0, math.cos(math.radians(30)), -math.sin(math.radians(30))])
    return expected_peak_wm2(dni, mirror, pivot, centre, normal, sun, cleanliness=clean, reflectivity=0.93,
                             atmosphere=atmosphere)


def test_expected_peak_scales_with_dni_and_cleanliness_and_falls_with_distance():
    near = _peak(200.0)
    assert _peak(200.0, dni=500.0) == pytest.approx(near / 2)
    assert _peak(200.0, clean=0.6) == pytest.approx(0.6 * near)
    assert _peak(400.0) < _peak(300.0) < near  # the blur spreads the same power wider
    assert _peak(600.0, atmosphere="clear") < _peak(600.0)  # attenuation over the slant range
    away = np.array([0.0, math.cos(math.radians(30)), -math.sin(math.radians(30))])  # along the beam, from the board
    assert _peak(200.0, sun=away) == 0.0  # the sun exactly opposite the beam: nothing reflected
    # a near mirror at normal incidence (the sun behind the board): its footprint sets the peak, the power over its area
    centre, normal = BOARD
    pivot = centre + np.array([0.0, 5.0, 0.0])
    tiny = expected_peak_wm2(1000.0, (4.0, 4.0), pivot, centre, normal, np.array([0.0, -1.0, 0.0]), atmosphere=None)
    assert tiny == pytest.approx(1000.0 * 0.93, rel=1e-3)


def test_without_any_gain_the_camera_keeps_its_exposure():
    policy = ExposurePolicy()
    assert policy.choose(500.0) is None
    policy.prior_gain = 0.2  # grey per W/m² per ms
    assert policy.choose(None) is None and policy.choose(0.0) is None
    assert policy.choose(500.0) == pytest.approx(ex.TARGET_GREY / 100.0)


def test_the_chosen_exposure_puts_spot_and_board_at_the_target_level_within_the_range():
    policy = ExposurePolicy(range_ms=(0.01, 100.0), prior_gain=0.2)
    policy.saw_board(30.0, 1.0)  # the white board at 30 grey levels at 1 ms
    e = policy.choose(500.0)
    assert (0.2 * 500.0 + 30.0) * e == pytest.approx(ex.TARGET_GREY)
    assert policy.choose(1e-6) == pytest.approx(170.0 / 30.0)  # a faint spot: the board alone sets it
    policy.saw_board(0.0, 1.0)  # an unreadable board level changes nothing
    assert policy.ambient_rate == 30.0
    assert policy.choose(1e9) == 0.01  # clamped to the range


def test_the_gain_is_the_median_of_the_latest_valid_readings_not_touched_by_saturation():
    policy = ExposurePolicy(prior_gain=1.0)
    for peak in (100.0, 120.0, 80.0):
        policy.learn(SpotFigures(2.0, peak=peak, noise=1.0, saturated_fraction=0.0), expected_peak=250.0)
    assert policy.spot_gain() == pytest.approx(100.0 / (250.0 * 2.0))  # the prior gives way to what was seen
    policy.learn(SpotFigures(2.0, peak=250.0, saturated_fraction=0.05), expected_peak=250.0)  # a lower bound only
    policy.learn(SpotFigures(2.0, peak=90.0, saturated_fraction=0.0), expected_peak=None)  # nothing expected
    assert len(policy.gains) == 3
    for _ in range(ex.GAIN_MEMORY):
        policy.learn(SpotFigures(1.0, peak=50.0, saturated_fraction=0.0), expected_peak=100.0)
    assert policy.spot_gain() == pytest.approx(0.5)  # the memory holds the latest only


def test_a_saturated_reading_is_retaken_shorter():
    policy = ExposurePolicy()
    sat = SpotFigures(4.0, peak=230.0, noise=1.5, saturated_fraction=0.3, board_grey=40.0)
    assert policy.retake_exposure_ms("saturated", sat) == pytest.approx(4.0 * ex.SHORTER)
    # a clipped reading with a saturated plateau is too bright, not cut by the rim
    assert policy.retake_exposure_ms("clipped", sat) == pytest.approx(4.0 * ex.SHORTER)
    # shorter never past the range's end: then nothing to retake
    assert policy.retake_exposure_ms("saturated", SpotFigures(0.01, peak=230.0, saturated_fraction=0.5)) is None


def test_a_spot_cut_by_the_rim_is_not_retaken():
    policy = ExposurePolicy()
    cut = SpotFigures(2.0, peak=150.0, noise=1.5, saturated_fraction=0.0, board_grey=30.0)
    assert policy.retake_exposure_ms("clipped", cut) is None
    assert policy.retake_exposure_ms("clipped", SpotFigures(2.0, peak=200.0, saturated_fraction=0.01)) is None
    for other in ("no_spot", "ambient_change", "jitter", "marks_not_found"):
        assert policy.retake_exposure_ms(other, cut) is None


def test_a_faint_reading_is_retaken_longer_by_its_measured_peak_and_the_board_stays_readable():
    policy = ExposurePolicy()
    faint = SpotFigures(1.0, peak=12.0, noise=1.0, saturated_fraction=0.0, board_grey=22.0)
    assert policy.retake_exposure_ms("low_contrast", faint) == pytest.approx(ex.TARGET_GREY / 34.0)
    lost = SpotFigures(1.0, peak=2.0, noise=1.0, saturated_fraction=0.0, board_grey=10.0)  # in the noise
    assert policy.retake_exposure_ms("low_contrast", lost) == pytest.approx(ex.LONGER)
    tiny = SpotFigures(1.0, peak=4.0, noise=1.0, saturated_fraction=0.0, board_grey=1.0)
    assert policy.retake_exposure_ms("low_contrast", tiny) == pytest.approx(ex.LONGER_MAX)
    bright_board = SpotFigures(1.0, peak=2.0, noise=1.0, board_grey=160.0)
    assert policy.retake_exposure_ms("low_contrast", bright_board) == pytest.approx(ex.MAX_BOARD_GREY / 160.0)
    assert policy.retake_exposure_ms("low_contrast", SpotFigures(1.0, peak=None, board_grey=198.0)) is None
    assert ExposurePolicy(range_ms=(0.01, 1.0)).retake_exposure_ms("low_contrast", faint) is None  # at the end
