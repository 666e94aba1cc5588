"""vision.spot: annex A centring on the board, checked against rendered ground truth and brute force.

Frames are rendered (perspective board, marks, uneven light, noise), written to real PNG files and
read back. The spot's true centre is the centre of the symmetric irradiance pattern in board
metres, known exactly. Tolerances: the sub-cell methods within 6 mm (about a quarter of a frame
pixel on the board at 45 px/m); ``grlm`` (integer window positions, as the standard) within
0.75 grid cell per axis on round spots.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from helicalib.vision.frames import read_frame, write_png
from helicalib.vision.homography import image_to_board
from helicalib.vision.marks import find_marks
from helicalib.sim.render import DEMO_CAMERA_ENU_M, Lighting, Spot, demo_target, look_at_pose, render_frame
from helicalib.vision.spot import best_window, measure_spot, otsu_threshold, window_centroid

TARGET = demo_target()
POSE = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024))


@pytest.fixture(scope="module")
def before(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    return read_frame(write_png(d / "before.png", render_frame(TARGET, POSE, rng=1)))


@pytest.fixture(scope="module")
def marks(before):
    m = find_marks(before, TARGET)
    assert m.found
    return m


def _after(tmp_path, spots, seed, lighting=Lighting(), name="after.png"):
    return read_frame(write_png(tmp_path / name, render_frame(TARGET, POSE, spots, lighting, rng=seed)))


SPOTS = [
    Spot(center_m=(1.0, -0.5), size_m=(0.8, 0.8), peak=70),
    Spot(center_m=(-2.2, 1.6), size_m=(1.4, 0.9), peak=60, angle_deg=25),
    Spot(center_m=(0.4, 2.5), size_m=(1.6, 1.1), peak=55, shape="flat", angle_deg=-40),
    Spot(center_m=(2.7, -2.1), size_m=(1.0, 1.0), peak=65, shape="flat"),
]


@pytest.mark.parametrize("k", range(len(SPOTS)))
def test_sub_cell_methods_find_the_true_centre(tmp_path, before, marks, k):
    spot = SPOTS[k]
    after = _after(tmp_path, [spot], seed=20 + k)
    for method in ("grlm-centroid", "centroid"):
        r = measure_spot(before, [after], TARGET, method=method, marks=marks)
        assert r.valid, r.message
        assert np.abs(r.offset_m - spot.center_m).max() < 0.006, (method, r.offset_m)


@pytest.mark.parametrize("k", [0, 3])
def test_grlm_window_centre_within_the_grid_quantisation(tmp_path, before, marks, k):
    spot = SPOTS[k]  # round spots: the window-sum maximum is unique
    r = measure_spot(before, [_after(tmp_path, [spot], seed=40 + k)], TARGET, method="grlm", marks=marks)
    assert r.valid, r.message
    assert np.abs(r.offset_m - spot.center_m).max() < 0.75 / r.cells_per_m
    # A.2: the window side is √S grid cells
    assert r.window_side_m == pytest.approx(round(np.sqrt(r.spot_area_px)) / r.cells_per_m)


def test_marks_are_found_on_the_before_frame_when_not_given(tmp_path, before):
    spot = SPOTS[0]
    r = measure_spot(before, [_after(tmp_path, [spot], seed=9)], TARGET)
    assert r.valid and r.method == "grlm-centroid" and r.marks.found
    assert np.abs(r.offset_m - spot.center_m).max() < 0.006
    # the reported pixels are the board points mapped into the frame
    assert np.allclose(image_to_board(r.marks, r.spot_center_px[None])[0], r.offset_m, atol=1e-6)
    assert np.allclose(image_to_board(r.marks, r.target_center_px[None])[0], 0.0, atol=1e-6)
    j = r.to_json()
    for key in ("valid", "reason", "spot_center_px", "offset_m", "target_center_px", "spot_area_px", "threshold",
                "jitter_m"):
        assert key in j
    assert len(j["offset_m"]) == 2 and len(j["window_px"]) == 4


def test_rectifying_removes_the_perspective_bias_of_an_image_space_centroid(tmp_path, before, marks):
    spot = Spot(center_m=(0.0, 0.0), size_m=(1.5, 1.5), peak=60)  # a large spot in the steep demo view
    after = _after(tmp_path, [spot], seed=5)
    D = after.astype(float) - before
    T = otsu_threshold(np.clip(D, 0, 255).astype(np.uint8))
    I = np.where(D >= T, D, 0.0)
    ys, xs = np.mgrid[0: D.shape[0], 0: D.shape[1]]
    naive_px = np.array([(I * xs).sum(), (I * ys).sum()]) / I.sum()
    naive_m = image_to_board(marks, naive_px[None])[0]
    assert np.linalg.norm(naive_m - spot.center_m) > 0.015  # the bias the board grid avoids
    r = measure_spot(before, [after], TARGET, method="centroid", marks=marks)
    assert np.linalg.norm(r.offset_m - spot.center_m) < 0.005


def test_several_after_frames_mean_and_jitter(tmp_path, before, marks):
    centres = np.array([[0.50, 0.30], [0.54, 0.30], [0.52, 0.27], [0.52, 0.33]])
    afters = [_after(tmp_path, [Spot(tuple(c), (0.8, 0.7), peak=70)], seed=60 + i, name=f"a{i}.png")
              for i, c in enumerate(centres)]
    r = measure_spot(before, afters, TARGET, marks=marks)
    assert r.valid, r.message
    mean = centres.mean(axis=0)
    jitter = np.sqrt(np.mean(np.sum((centres - mean) ** 2, axis=1)))  # T/GRLM 3.3, in metres
    assert np.abs(r.offset_m - mean).max() < 0.004
    assert r.jitter_m == pytest.approx(jitter, abs=0.003)
    assert r.frame_offsets_m.shape == (4, 2)


def test_a_small_change_of_daylight_is_compensated(tmp_path, before, marks):
    spot = SPOTS[1]
    brighter = Lighting(ambient=150 * 1.12)
    r = measure_spot(before, [_after(tmp_path, [spot], seed=8, lighting=brighter)], TARGET, marks=marks)
    assert r.valid, r.message
    assert np.abs(r.offset_m - spot.center_m).max() < 0.006
    assert r.frames[0].ambient_ratio == pytest.approx(1.12, abs=0.01)


# ---------------------------------------------------------------------------- annex A core vs brute force
def _brute_window(I, side):
    rows, cols = I.shape
    best, where = -1.0, []
    for r, c in itertools.product(range(rows - side + 1), range(cols - side + 1)):
        f = float(I[r: r + side, c: c + side].sum())
        if f > best + 1e-6:
            best, where = f, [(c, r)]
        elif abs(f - best) <= 1e-6:
            where.append((c, r))
    return np.mean(where, axis=0) + (side - 1) / 2, best


@settings(max_examples=40, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(3, 14), st.integers(3, 14)),
              elements=st.integers(0, 50).map(float)), st.integers(1, 4))
def test_best_window_matches_formula_a3_a4_by_brute_force(I, side):
    side = min(side, *I.shape)
    c, f = best_window(I, side)
    c_ref, f_ref = _brute_window(I, side)
    assert f == pytest.approx(f_ref, abs=1e-3)
    assert np.allclose(c, c_ref)


def test_window_centroid_converges_to_the_centre_of_a_symmetric_spot():
    yy, xx = np.mgrid[0:80, 0:90].astype(float)
    centre = np.array([41.37, 36.81])  # (column, row)
    I = np.exp(-0.5 * (((xx - centre[0]) / 7.0) ** 2 + ((yy - centre[1]) / 5.0) ** 2))
    c = window_centroid(I, np.array([38.0, 39.0]), side=14.3)
    assert np.allclose(c, centre, atol=0.01)  # point samples with fractional edge weights: ~0.005 cell
