"""A spot over the board's rim measured by the symmetry of its visible part (``vision.mirror``).

Unit tests of the symmetric region on synthetic arrays, and real frames of the demo board rendered
by ``sim.render`` with spots of known centre, exposed as the simulated plant's cameras are (the
white board at 25 grey levels), measured with the default limits, with the symmetry rule off
(``max_mirror_slope=None``) and with no rim rule at all (``core_shares=()``).
"""

from __future__ import annotations

import numpy as np
import pytest
from spot_scene import EXPOSED, demo_scene

from helicalib.sim.render import Spot, render_frame
from helicalib.vision.mirror import asymmetry, mirror_centre, mirrored
from helicalib.vision.spot import SpotLimits, measure_spot

CORE_ONLY = SpotLimits(max_mirror_slope=None)


# ---------------------------------------------------------------------------- the symmetric region
def test_mirrored_reflects_about_a_half_cell_point_and_is_empty_off_the_grid():
    a = np.arange(12).reshape(3, 4)
    assert np.array_equal(mirrored(a, np.array([3, 2])), a[::-1, ::-1])  # about (1.5, 1): the whole grid
    out = mirrored(a, np.array([4, 2]))  # about column 2: column j shows column 4 - j
    assert np.array_equal(out[:, 1:], a[::-1, ::-1][:, :3]) and not out[:, 0].any()


def _cut_gaussian(centre, sigma, cols=200, rows=160, rim=178):
    y, x = np.mgrid[0:rows, 0:cols].astype(float)
    I = 100.0 * np.exp(-0.5 * (((x - centre[0]) / sigma[0]) ** 2 + ((y - centre[1]) / sigma[1]) ** 2))
    seen = x < rim
    return np.where(I >= 5.0, I, 0.0), seen


def test_a_gaussian_cut_near_its_peak_is_found_where_its_visible_centroid_is_not():
    I, seen = _cut_gaussian((150.3, 80.6), (25.0, 18.0))
    got = mirror_centre(I, seen, np.array([140.0, 70.0]))
    assert got is not None
    assert np.allclose(got.center_cell, [150.3, 80.6], atol=0.05)
    visible = np.where(seen, I, 0.0)
    assert visible.sum(axis=0) @ np.arange(I.shape[1]) / visible.sum() < 147.0  # what the centroid says
    assert got.slope[0] < 0.75 and got.slope[1] < 0.1  # the cut axis is the one the region limits
    assert got.asymmetry < 0.01  # the half-cell rounding of the region's centre only


def test_a_plateau_reaching_the_rim_is_ill_conditioned():
    y, x = np.mgrid[0:160, 0:200].astype(float)
    I = np.where((np.abs(x - 160) < 40) & (np.abs(y - 80) < 30), 100.0, 0.0)
    got = mirror_centre(I, x < 170, np.array([150.0, 80.0]))
    assert got is None or got.slope[0] > 0.9  # any centre inside the plateau is a fixed point


def test_asymmetry_is_zero_for_a_symmetric_spot_and_large_for_a_lopsided_one():
    I, seen = _cut_gaussian((100.0, 80.0), (20.0, 20.0))
    m2 = np.array([200, 160])
    assert asymmetry(I, seen, m2) < 1e-9
    assert asymmetry(np.where(np.arange(200)[None, :] < 100, I, 0.0), seen, m2) > 0.9


# ---------------------------------------------------------------------------- rendered frames
@pytest.fixture(scope="module")
def scene():
    return demo_scene()


def _measure(scene, spot: Spot):
    target, pose, marks = scene
    before = render_frame(target, pose, (), EXPOSED, rng=11)
    after = render_frame(target, pose, [spot], EXPOSED, rng=12)
    return [measure_spot(before, [after], target, marks=marks, limits=lim)
            for lim in (SpotLimits(), CORE_ONLY, SpotLimits(core_shares=()))]


@pytest.mark.parametrize("spot", [Spot((4.6, 0.5), (1.4, 1.2), peak=150.0),
                                  Spot((0.5, -4.5), (1.2, 1.5), peak=140.0)], ids=["right rim", "lower rim"])
def test_a_spot_whose_every_core_reaches_the_rim_is_measured_by_its_symmetry(scene, spot):
    rim, core, none = _measure(scene, spot)
    assert core.reason == none.reason == "clipped"
    assert rim.valid, rim.message
    f = rim.frames[0]
    assert f.core_share is None and f.mirror_slope is not None and f.mirror_slope <= SpotLimits().max_mirror_slope
    assert f.mirror_asym <= SpotLimits().max_mirror_asymmetry
    assert "symmetry of its visible part" in rim.message and "over the rim" in rim.message
    assert rim.threshold == pytest.approx(f.threshold) and f.clipped_cells > 2
    err_mm = 1000.0 * float(np.linalg.norm(rim.offset_m - np.asarray(spot.center_m)))
    biased_mm = 1000.0 * float(np.linalg.norm(core.offset_m - np.asarray(spot.center_m)))
    assert err_mm < 10.0 and biased_mm > 100.0  # the visible part's centroid is pulled toward the board


def test_a_flat_top_running_over_the_rim_stays_clipped_with_its_partial_centroid(scene):
    rim, core, _ = _measure(scene, Spot((4.6, 0.5), (2.0, 1.6), peak=150.0, shape="flat"))
    assert rim.reason == core.reason == "clipped"
    assert rim.message == core.message and np.array_equal(rim.offset_m, core.offset_m)
    assert rim.frames[-1].mirror_slope is None


def test_a_spot_centred_off_the_board_stays_clipped(scene):
    rim, core, _ = _measure(scene, Spot((6.3, -0.5), (1.2, 1.0), peak=150.0))
    assert rim.reason == core.reason == "clipped"
    assert np.array_equal(rim.offset_m, core.offset_m)


def test_a_spot_on_the_board_is_measured_as_without_the_rule(scene):
    rim, core, none = _measure(scene, Spot((1.0, -0.5), (0.9, 0.8), peak=150.0))
    assert rim.valid and core.valid and none.valid
    assert np.array_equal(rim.offset_m, none.offset_m) and rim.message == none.message
    assert rim.frames[0].mirror_slope is None
