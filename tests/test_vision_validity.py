"""vision.spot validity: each invalid class is detected with its reason code and a sentence."""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.config import Target
from helicalib.vision.frames import read_frame, write_png
from helicalib.vision.marks import find_marks
from helicalib.sim.render import DEMO_CAMERA_ENU_M, Lighting, Spot, demo_target, look_at_pose, render_frame
from helicalib.vision.spot import REASONS, SpotLimits, measure_spot

TARGET = demo_target()
POSE = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024))
GOOD = Spot(center_m=(0.5, -0.4), size_m=(0.8, 0.8), peak=70)


@pytest.fixture(scope="module")
def before():
    return render_frame(TARGET, POSE, rng=1)


@pytest.fixture(scope="module")
def marks(before):
    return find_marks(before, TARGET)


def _png(tmp_path, img, name="a.png"):
    return read_frame(write_png(tmp_path / name, img))


def _check(r, reason):
    assert not r.valid
    assert r.reason == reason, (r.reason, r.message)
    assert reason in REASONS
    assert r.message.endswith(".") and len(r.message) > 20
    assert r.to_json()["reason"] == reason


def test_the_good_spot_is_valid(tmp_path, before, marks):
    r = measure_spot(before, [_png(tmp_path, render_frame(TARGET, POSE, [GOOD], rng=2))], TARGET, marks=marks)
    assert r.valid and r.reason == "ok"


def test_no_spot(tmp_path, before, marks):
    after = _png(tmp_path, render_frame(TARGET, POSE, rng=3))  # same scene, fresh noise
    _check(measure_spot(before, [after], TARGET, marks=marks), "no_spot")


def test_low_contrast(tmp_path, before, marks):
    faint = Spot(center_m=(0.5, -0.4), size_m=(1.0, 1.0), peak=14)  # a cloud over the sun, a dirty mirror
    _check(measure_spot(before, [_png(tmp_path, render_frame(TARGET, POSE, [faint], rng=4))], TARGET, marks=marks),
           "low_contrast")


def test_clipped_by_the_board_edge(tmp_path, before, marks):
    edge = Spot(center_m=(5.6, 0.0), size_m=(0.8, 0.8), peak=70)
    _check(measure_spot(before, [_png(tmp_path, render_frame(TARGET, POSE, [edge], rng=5))], TARGET, marks=marks),
           "clipped")


def test_clipped_by_the_frame_edge(tmp_path):
    wide = Target(id="W", center_enu_m=(0.0, 8.0, 95.0), normal_enu=(0.0, 1.0, 0.0), size_m=(20.0, 12.0),
                  marks={"vertices_m": [[-5.5, 5.5], [5.5, 5.5], [5.5, -5.5], [-5.5, -5.5]], "arm_m": 1.4,
                         "thickness_m": 0.35})
    pose = look_at_pose((0.0, 75.0, 2.0), wide, 7000, (1280, 1024), aim_uv_m=(1.5, 0.0))
    before = render_frame(wide, pose, rng=1)
    spot = Spot(center_m=(-8.0, 0.0), size_m=(0.8, 0.8), peak=70)  # on the board, cut by the frame's left edge
    r = measure_spot(before, [_png(tmp_path, render_frame(wide, pose, [spot], rng=2))], wide)
    _check(r, "clipped")
    assert r.marks.found


def test_saturated(tmp_path, before, marks):
    hot = Spot(center_m=(0.5, -0.4), size_m=(0.9, 0.9), peak=300)
    r = measure_spot(before, [_png(tmp_path, render_frame(TARGET, POSE, [hot], rng=6))], TARGET, marks=marks)
    _check(r, "saturated")
    # a looser limit accepts the same frame
    r2 = measure_spot(before, [_png(tmp_path, render_frame(TARGET, POSE, [hot], rng=6))], TARGET, marks=marks,
                      limits=SpotLimits(max_saturated_fraction=0.9))
    assert r2.valid


def test_marks_not_found(tmp_path):
    blank = np.full((1024, 1280), 150, np.uint8)
    after = blank.copy()
    after[400:500, 600:700] = 220
    _check(measure_spot(blank, [after], TARGET), "marks_not_found")


def test_reprojection_too_large(tmp_path, before):
    after = render_frame(TARGET, POSE, [GOOD], rng=2)
    _check(measure_spot(before, [after], TARGET, limits=SpotLimits(max_reprojection_px=0.01)), "reprojection")


def test_ambient_change(tmp_path, before, marks):
    cloud = Lighting(ambient=150 * 0.6)
    after = _png(tmp_path, render_frame(TARGET, POSE, [GOOD], cloud, rng=7))
    r = measure_spot(before, [after], TARGET, marks=marks)
    _check(r, "ambient_change")
    assert "-40 %" in r.message


def test_a_beam_crossing_the_board_in_the_before_frame_is_refused(tmp_path, marks):
    """Another heliostat's beam on the board while the before frame was taken (moving between its
    board and its standby point) leaves a patch darker in the after frame than in the before; the
    difference's centre would lie between the two spots, so the reading is refused as "ambient_change".
    The same spot with a clean before frame is valid, and so is a faint patch of lost light (under the
    share of the spot's area)."""
    crossing = Spot(center_m=(-2.0, 1.5), size_m=(0.9, 0.9), peak=60)
    lit_before = _png(tmp_path, render_frame(TARGET, POSE, [crossing], rng=1), "b.png")
    after = _png(tmp_path, render_frame(TARGET, POSE, [GOOD], rng=2))
    r = measure_spot(lit_before, [after], TARGET, marks=marks)
    _check(r, "ambient_change")
    assert "before frame" in r.message and "another beam" in r.message
    clean = render_frame(TARGET, POSE, rng=1)
    assert measure_spot(clean, [after], TARGET, marks=marks).valid
    small = Spot(center_m=(-2.0, 1.5), size_m=(0.2, 0.2), peak=60)  # a few cells of lost light
    r = measure_spot(_png(tmp_path, render_frame(TARGET, POSE, [small], rng=1), "c.png"), [after], TARGET, marks=marks)
    assert r.valid, r.message


def test_jitter(tmp_path, before, marks):
    afters = [_png(tmp_path, render_frame(TARGET, POSE, [Spot((0.5 + du, -0.4), (0.8, 0.8), peak=70)], rng=10 + i),
                   f"a{i}.png") for i, du in enumerate((-0.3, 0.0, 0.3))]
    r = measure_spot(before, afters, TARGET, marks=marks)
    _check(r, "jitter")
    assert r.jitter_m == pytest.approx(np.sqrt(2 * 0.3**2 / 3), abs=0.01)


@pytest.mark.parametrize("bad", ["empty", "wrong_size", "three_d", "nan", "none"])
def test_bad_frames_give_an_invalid_result_not_a_traceback(before, marks, bad):
    after = {"empty": np.zeros((0, 0), np.uint8), "wrong_size": np.zeros((512, 640), np.uint8),
             "three_d": np.zeros((4, 4, 4, 4)), "nan": np.full((1024, 1280), np.nan), "none": None}[bad]
    afters = [] if bad == "none" else [after]
    _check(measure_spot(before, afters, TARGET, marks=marks), "bad_frame")


def test_one_bad_frame_among_several_names_it(tmp_path, before, marks):
    good = render_frame(TARGET, POSE, [GOOD], rng=2)
    hot = render_frame(TARGET, POSE, [Spot((0.5, -0.4), (0.9, 0.9), peak=300)], rng=3)
    r = measure_spot(before, [good, hot], TARGET, marks=marks)
    _check(r, "saturated")
    assert r.failed_frame == 1 and "after frame 2" in r.message
