"""A spot over the board's rim measured on its core (``vision.spot.core_region``), on rendered frames.

Real frames of the demo board rendered by ``sim.render`` with spots of known centre, exposed as the
simulated plant's cameras are (the white board at 25 grey levels); each measured with the core
threshold (the default limits) and without it (``core_shares=()``: every spot over the rim clipped).
"""

from __future__ import annotations

import numpy as np
import pytest
from spot_scene import EXPOSED, demo_scene

from helicalib.config import Target
from helicalib.sim.render import Spot, demo_target, look_at_pose, render_frame
from helicalib.vision.spot import SpotLimits, core_region, measure_spot

WITHOUT_CORE = SpotLimits(core_shares=())


@pytest.fixture(scope="module")
def scene():
    return demo_scene()


def _measure(scene, spot: Spot, seed: int = 11):
    target, pose, marks = scene
    before = render_frame(target, pose, (), EXPOSED, rng=seed)
    after = render_frame(target, pose, [spot], EXPOSED, rng=seed + 1)
    return (measure_spot(before, [after], target, marks=marks),
            measure_spot(before, [after], target, marks=marks, limits=WITHOUT_CORE))


def test_a_spot_over_the_rim_with_its_core_on_the_board_is_valid_and_accurate(scene):
    spot = Spot((3.36, -2.03), (2.14, 1.56), peak=172.0, angle_deg=30.0)
    core, today = _measure(scene, spot)
    assert today.reason == "clipped"
    assert core.valid, core.message
    f = core.frames[0]
    assert f.core_share is not None and f.clipped_cells > 2
    assert core.threshold == pytest.approx(f.core_share * f.peak)
    assert "core above" in core.message and "over the rim" in core.message
    err_mm = 1000.0 * float(np.linalg.norm(core.offset_m - np.asarray(spot.center_m)))
    assert err_mm < 15.0  # spots wholly on the board measure 8.6 mm RMS (benchmarks/bench_clipped.py)


def test_a_spot_whose_core_reaches_the_rim_stays_clipped_with_its_partial_centroid(scene):
    spot = Spot((5.6, -1.0), (1.0, 0.9), peak=150.0)
    core, today = _measure(scene, spot)
    assert core.reason == today.reason == "clipped"
    assert core.message == today.message
    assert np.array_equal(core.offset_m, today.offset_m)  # the visible part's centroid, as a search needs
    assert core.offset_m[0] < spot.center_m[0] - 0.2  # biased toward the board, as it must be
    assert core.frames[-1].core_share is None


def test_a_core_cut_by_a_dark_mark_stays_clipped(scene):
    """Beside the mark at (5.5, 5.5) the spot's light on the black mark is lost: a core ending there
    looks closed but is cut (measured 227 mm off when the marks are not counted as blind)."""
    spot = Spot((5.1, 4.3), (0.6, 0.54), peak=133.0)
    core, today = _measure(scene, spot)
    assert core.reason == today.reason == "clipped"
    assert np.array_equal(core.offset_m, today.offset_m)


def test_a_spot_cut_by_the_frames_edge_stays_clipped():
    """The core rule is for the board's rim: a board the frame cuts keeps today's verdict."""
    wide = Target(id="W", center_enu_m=(0.0, 8.0, 95.0), normal_enu=(0.0, 1.0, 0.0), size_m=(20.0, 12.0),
                  marks=demo_target().marks)
    pose = look_at_pose((0.0, 75.0, 2.0), wide, 7000, (1280, 1024), aim_uv_m=(1.5, 0.0))
    spot = Spot((-8.0, 0.0), (0.8, 0.8), peak=70)  # its 60 % core lies in the frame, off its edge
    before, after = render_frame(wide, pose, rng=1), render_frame(wide, pose, [spot], rng=2)
    core = measure_spot(before, [after], wide)
    today = measure_spot(before, [after], wide, limits=WITHOUT_CORE)
    assert core.reason == today.reason == "clipped"
    assert np.array_equal(core.offset_m, today.offset_m)


def test_a_spot_wholly_on_the_board_is_measured_bit_for_bit_as_without_the_core_rule(scene):
    spot = Spot((0.7, -1.2), (1.1, 0.8), peak=140.0, shape="flat", angle_deg=20.0)
    core, today = _measure(scene, spot)
    assert core.valid and today.valid
    assert core.to_json() == today.to_json()
    assert core.frames[0].core_share is None and "core" not in core.message


def _blob(shape=(80, 80), centre=(40.0, 40.0), sigma=8.0, peak=100.0) -> np.ndarray:
    r, c = np.mgrid[0:shape[0], 0:shape[1]]
    return (peak * np.exp(-0.5 * ((c - centre[0]) ** 2 + (r - centre[1]) ** 2) / sigma**2)).astype(np.float32)


def _inside(shape=(80, 80)) -> np.ndarray:
    inside = np.zeros(shape, bool)
    inside[1:-1, 1:-1] = True
    return inside


def test_core_region_takes_the_lowest_share_that_keeps_off_the_rim():
    # centre 20 cells from the rim, σ 8: the 30 % core (radius 1.55σ = 12.4) keeps off by more than the margin
    D = _blob(centre=(40.0, 21.0))
    got = core_region(D, _inside(), T=5.0, peak=100.0, limits=SpotLimits())
    assert got is not None and got[0] == 0.3 and got[1] == pytest.approx(30.0)
    assert np.array_equal(got[2], (D >= 30.0) & _inside())


def test_core_region_refuses_a_core_within_the_margin_of_the_rim():
    # centred 10 cells from the off-board ring (row 0): the 60 % core (radius 1.01σ ≈ 8.1 cells) keeps
    # off the ring itself, but not by the margin
    D = _blob(centre=(40.0, 10.0))
    assert not ((D >= 60.0) & ~_inside()).any()
    assert core_region(D, _inside(), T=5.0, peak=100.0, limits=SpotLimits()) is None


def test_core_region_keeps_the_core_off_blind_cells():
    D = _blob()
    blind = np.zeros_like(_inside())
    blind[36:45, 60] = True  # a dark mark 20 cells from the centre: off every core and its margin
    got = core_region(D, _inside(), 5.0, 100.0, SpotLimits(), blind)
    assert got is not None and got[0] == 0.3
    blind[36:45, 52] = True  # 12 cells: within the 30-50 % cores' margins, off the 60 % core's (8 + 3)
    got = core_region(D, _inside(), 5.0, 100.0, SpotLimits(), blind)
    assert got is not None and got[0] == 0.6
    blind[36:45, 47] = True  # within the 60 % core's margin too
    assert core_region(D, _inside(), 5.0, 100.0, SpotLimits(), blind) is None


def test_no_core_shares_means_no_core():
    assert core_region(_blob(), _inside(), 5.0, 100.0, SpotLimits(core_shares=())) is None
