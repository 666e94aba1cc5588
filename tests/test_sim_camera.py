"""The board renderer and SimCamera: PNG frames, marks where they belong, the spot where the beam is."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_at_site, to_unix_seconds
from helicalib.sim.camera import SimCamera
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))
QUIET = {"camera": {"noise_counts": 0.0}}


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def _aim_one(cfg, plant, index, t_hold):
    sun = sun_at_site(cfg.site, t_hold).vector_enu
    model = HeliostatModel.from_config(cfg, [cfg.heliostats[index].id])
    sol = model.strokes_for_aim(sun, np.array(cfg.target(cfg.heliostats[index].target).center_enu_m))
    plant.move_to(index, sol.strokes_mm[0])
    plant.advance_to(t_hold)


def test_frame_is_png_of_camera_size_with_capture_time(cfg):
    p = SimulatedPlant(cfg, start_s=START)
    for cam in cfg.cameras:
        frame = SimCamera(p, cam.id).grab()
        img = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and img.shape == (cam.resolution_px[1], cam.resolution_px[0])
        assert frame.capture_time_s == START and frame.source == cam.url


def test_board_and_four_marks_visible(cfg):
    p = SimulatedPlant(cfg, parse_scenario(QUIET), start_s=START)
    cam = cfg.cameras[0]
    img, _ = SimCamera(p, cam.id).render()
    board = img > np.median(img) + 5            # the lit board stands out from the background
    n, labels, stats, _ = cv2.connectedComponentsWithStats(board.astype(np.uint8))
    biggest = 1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])
    x, y, w, h = stats[biggest, :4]
    inside = img[y:y + h, x:x + w]
    dark = (inside < 0.5 * np.median(inside[labels[y:y + h, x:x + w] == biggest])).astype(np.uint8)
    dark[labels[y:y + h, x:x + w] != biggest] = 0
    # marks are holes in the board region: find them as dark blobs enclosed by the board
    filled = cv2.morphologyEx((labels == biggest).astype(np.uint8), cv2.MORPH_CLOSE, np.ones((25, 25), np.uint8))
    holes = (filled[y:y + h, x:x + w] > 0) & (labels[y:y + h, x:x + w] != biggest)
    k, _, st, cent = cv2.connectedComponentsWithStats(holes.astype(np.uint8))
    blobs = [cent[j] + (x, y) for j in range(1, k) if st[j, cv2.CC_STAT_AREA] > 50]
    assert len(blobs) == 4
    c = np.array(blobs)
    # the camera looks at the board centre: the marks surround the principal point
    centre = np.array([cam.intrinsics.cx, cam.intrinsics.cy])
    assert np.linalg.norm(c.mean(axis=0) - centre) < 20
    assert np.sum(c[:, 0] < centre[0]) == 2 and np.sum(c[:, 1] < centre[1]) == 2


def test_spot_centred_on_board_centre_with_zero_errors(cfg):
    p = SimulatedPlant(cfg, parse_scenario(QUIET), start_s=START, zero_errors=True)
    cam = SimCamera(p, "C1")
    before, _ = cam.render()
    i = next(k for k, h in enumerate(cfg.heliostats) if h.target == "T1")
    _aim_one(cfg, p, i, START + 300.0)
    after, _ = cam.render()
    diff = after.astype(float) - before.astype(float)
    assert diff.max() > 30
    # aimed at the board centre, which the camera looks at: the spot centroid is the principal point
    w = np.clip(diff - 0.2 * diff.max(), 0, None)
    ys, xs = np.indices(w.shape)
    cx, cy = (w * xs).sum() / w.sum(), (w * ys).sum() / w.sum()
    k = cfg.cameras[0].intrinsics
    # a few pixels: the board's obliquity stretches the spot a little off-symmetric
    assert abs(cx - k.cx) < 6 and abs(cy - k.cy) < 6


def test_spot_scales_with_dni_and_cleanliness_and_saturates(cfg):
    p = SimulatedPlant(cfg, parse_scenario(QUIET), start_s=START, zero_errors=True)
    cam = SimCamera(p, "C1")
    r = cam.renderer
    uv = np.array([[0.0, 0.0]])
    width = np.array([[4.0, 4.0]])
    sigma = np.array([[0.4, 0.4]])
    base = r.render(None, 900.0, True).astype(float)
    one = r.render((uv, np.array([2000.0]), width, sigma), 900.0, True).astype(float) - base
    two = r.render((uv, np.array([4000.0]), width, sigma), 900.0, True).astype(float) - base
    assert one.max() > 10
    sel = one > 5
    assert np.median(two[sel] / one[sel]) == pytest.approx(2.0, rel=0.05)
    hot = r.render((uv, np.array([1e7]), width, sigma), 900.0, True)
    assert hot.max() == 255
    # total power on the board: the flux raster integrates to the beam power
    flux = r.spot_flux_wm2(uv, np.array([1000.0]), width, sigma)
    cell = (cfg.targets[0].size_m[0] / r.nu) * (cfg.targets[0].size_m[1] / r.nv)
    assert flux.sum() * cell == pytest.approx(1000.0, rel=1e-3)


def test_dark_at_night(cfg):
    night = float(to_unix_seconds("2026-03-20T20:00:00Z"))
    p = SimulatedPlant(cfg, parse_scenario(QUIET), start_s=night)
    img, _ = SimCamera(p, "C2").render()
    assert img.max() == 0


def test_a_board_stops_the_beams_that_meet_it_before_another_board():
    """Boards are opaque: a beam aimed at the centre board of the cylinder is drawn on a board moved
    into its path (between the field and the centre board) and not on the centre board; a board behind
    the centre board, or beside the beams, stops nothing. The truth is the ray's own geometry: the
    distance along each beam to each board's plane."""
    from helicalib.sim.camera import stopped_before

    from conftest import ROOT

    cfg = load_field_config(ROOT / "simulations" / "fields" / "dots_cylinder.yaml")
    tn = cfg.target("TN")
    helios = [h for h in cfg.heliostats if h.target == "TN"]
    origin = np.array([h.position_enu_m for h in helios], dtype=float)
    direction = np.asarray(tn.center_enu_m) - origin
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    w = np.asarray(tn.normal_enu)
    front = tn.model_copy(update={"id": "F", "center_enu_m": tuple(np.asarray(tn.center_enu_m) + 10.0 * w)})
    behind = tn.model_copy(update={"id": "B", "center_enu_m": tuple(np.asarray(tn.center_enu_m) - 10.0 * w)})
    assert stopped_before(tn, (front,), origin, direction).all()
    assert not stopped_before(tn, (behind,), origin, direction).any()
    assert not stopped_before(tn, tuple(t for t in cfg.targets if t.id != "TN"), origin, direction).any()
    # and the front board itself is not stopped by the centre board behind it
    assert not stopped_before(front, (tn,), origin, direction).any()
