"""vision.marks: the four L marks under perspective, uneven light, noise, a bright spot, lens distortion.

Ground truth: the renderer's camera pose projects the configured mark vertices (board metres)
into the frame independently of the detector (``cv2.projectPoints`` of the 3-D board points).
"""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.config import Camera
from helicalib.vision.frames import read_frame, write_png
from helicalib.vision.homography import board_to_image, image_to_board
from helicalib.vision.marks import find_marks
from helicalib.sim.render import (DEMO_CAMERA_ENU_M, Lighting, Spot, demo_target, look_at_pose,
                                     project_board_points, render_frame)

TARGET = demo_target()
VERTICES_M = np.array(TARGET.marks.vertices_m)


def _roundtrip(tmp_path, img, name="f.png"):
    return read_frame(write_png(tmp_path / name, img))


SCENES = {
    # the demo camera: on the ground ~70 m in front of the 12 m board at 95 m, a steep upward view
    "demo": dict(cam=DEMO_CAMERA_ENU_M, fx=5200, roll=0.0, light=Lighting()),
    # oblique from the side, rolled, strong light gradient, more noise
    "oblique": dict(cam=(60.0, 60.0, 20.0), fx=4200, roll=12.0,
                    light=Lighting(ambient=120, gradient=(0.35, -0.3), noise_sigma=3.0)),
    # dim board, far camera
    "dim": dict(cam=(0.0, 130.0, 5.0), fx=6000, roll=-5.0, light=Lighting(ambient=70, background=30, noise_sigma=2.0)),
}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_marks_found_with_sub_pixel_vertices_and_centre(tmp_path, name):
    sc = SCENES[name]
    pose = look_at_pose(sc["cam"], TARGET, sc["fx"], (1280, 1024), roll_deg=sc["roll"], aim_uv_m=(0.4, -0.3))
    gray = _roundtrip(tmp_path, render_frame(TARGET, pose, lighting=sc["light"], rng=7))
    r = find_marks(gray, TARGET)
    assert r.found, r.message
    truth = project_board_points(pose, TARGET, VERTICES_M)
    err = np.linalg.norm(r.vertices_px - truth, axis=1)
    assert err.max() < 0.6, err  # sub-pixel, each vertex
    centre_truth = project_board_points(pose, TARGET, np.zeros((1, 2)))[0]
    assert np.linalg.norm(r.center_px - centre_truth) < 0.25
    assert r.reprojection_px < 0.6
    # the homography maps the true mark vertices back onto the board within 1 cm
    assert np.abs(image_to_board(r, truth) - VERTICES_M).max() < 0.01


def test_marks_found_with_a_bright_spot_next_to_a_mark(tmp_path):
    pose = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024))
    spot = Spot(center_m=(-4.2, 4.3), size_m=(0.9, 0.7), peak=160)  # right beside the TL mark, saturating
    gray = _roundtrip(tmp_path, render_frame(TARGET, pose, [spot], rng=3))
    r = find_marks(gray, TARGET)
    assert r.found, r.message
    truth = project_board_points(pose, TARGET, VERTICES_M)
    assert np.linalg.norm(r.vertices_px - truth, axis=1).max() < 0.8


def test_lens_distortion_is_undone_through_the_camera_model(tmp_path):
    k1 = -0.6  # about 6 px of barrel distortion at the frame edge for fx 5200
    cam = Camera(id="C1", target="T1", url="http://x/T1.png", intrinsics={"fx": 5200, "fy": 5200, "cx": 639.5,
                 "cy": 511.5}, distortion=[k1, 0, 0, 0, 0])
    pose = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024), aim_uv_m=(3.0, -2.0), distortion=cam.distortion)
    gray = _roundtrip(tmp_path, render_frame(TARGET, pose, rng=11))
    with_model = find_marks(gray, TARGET, cam)
    assert with_model.found, with_model.message
    truth = project_board_points(pose, TARGET, VERTICES_M)
    assert np.linalg.norm(with_model.vertices_px - truth, axis=1).max() < 0.6
    # board ↔ frame round trip through the distortion model
    pts = np.array([[0.0, 0.0], [4.0, -3.0], [-5.0, 5.0]])
    assert np.allclose(image_to_board(with_model, board_to_image(with_model, pts)), pts, atol=1e-6)
    assert np.linalg.norm(board_to_image(with_model, pts) - project_board_points(pose, TARGET, pts), axis=1).max() < 0.6


def test_marks_not_found_on_a_blank_frame_or_with_a_mark_hidden(tmp_path):
    blank = np.full((1024, 1280), 140, np.uint8)
    r = find_marks(blank, TARGET)
    assert not r.found and r.reason == "marks_not_found" and np.all(np.isnan(r.homography))
    pose = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024))
    gray = render_frame(TARGET, pose, rng=5)
    br = project_board_points(pose, TARGET, np.array([[4.9, -4.9]]))[0].astype(int)
    gray[br[1] - 40: br[1] + 40, br[0] - 60: br[0] + 60] = 200  # paint over the BR mark
    r = find_marks(_roundtrip(tmp_path, gray), TARGET)
    assert not r.found and r.reason == "marks_not_found"
    assert "mark" in r.message


def test_a_too_strict_reprojection_limit_reports_reprojection(tmp_path):
    pose = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024))
    r = find_marks(render_frame(TARGET, pose, rng=2), TARGET, max_reprojection_px=0.001)
    assert not r.found and r.reason == "reprojection" and np.isfinite(r.reprojection_px)
