"""Nine-dot (田) boards: the dot finder, its homography against the renderer's truth, the spot on a
dot board, the config kind, the simulated plant's dot boards and a short campaign on them.

Ground truth: the renderer's camera pose projects board points into the frame independently of
the detector (``cv2.projectPoints`` of the 3-D board points; the simulated camera's own
board→pixel homography).
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from helicalib.config import ConfigError, DotMarks, load_field_config, parse_field_config
from helicalib.vision.frames import read_frame, write_png
from helicalib.vision.homography import apply_homography as _apply_h
from helicalib.vision.homography import image_to_board
from helicalib.vision.marks import find_marks
from helicalib.sim.render import (DEMO_CAMERA_ENU_M, DOT_ALBEDO, Lighting, Spot, demo_dot_target, demo_target,
                                     look_at_pose, project_board_points, render_frame)
from helicalib.vision.spot import measure_spot

from conftest import ROOT

TARGET = demo_dot_target()
DOTS_M = TARGET.marks.dots_m()
CYLINDER = ROOT / "simulations" / "fields" / "dots_cylinder.yaml"

BLACK = 0.06
"""Black dots (as T/GRLM's L marks), the hardest paint for a spot on a dot; the default is light grey
(``DOT_ALBEDO``)."""

SCENES = {
    # the demo camera: ~70 m in front of the 12 m board at 95 m, a steep upward view
    "frontal": dict(cam=DEMO_CAMERA_ENU_M, fx=5200, roll=0.0, light=Lighting(dot_albedo=BLACK)),
    # from the side (about 50° off the normal), rolled, strong light gradient, more noise
    "oblique": dict(cam=(60.0, 60.0, 20.0), fx=4200, roll=12.0,
                    light=Lighting(ambient=120, gradient=(0.35, -0.3), noise_sigma=3.0, dot_albedo=BLACK)),
}


def _roundtrip(tmp_path, img, name="f.png"):
    return read_frame(write_png(tmp_path / name, img))


def _pose(name):
    sc = SCENES[name]
    return look_at_pose(sc["cam"], TARGET, sc["fx"], (1280, 1024), roll_deg=sc["roll"], aim_uv_m=(0.4, -0.3))


def _check_homography(r, pose, dots_max_px=0.5):
    assert r.found and r.kind == "dots", r.message
    truth = project_board_points(pose, TARGET, DOTS_M)
    # the board centre (the reference dot) and every true dot centre, through the homography
    centre = project_board_points(pose, TARGET, np.zeros((1, 2)))[0]
    assert np.linalg.norm(r.center_px - centre) < 0.1
    assert np.abs(image_to_board(r, truth) - DOTS_M).max() < 0.005  # 5 mm on the board
    # board points far from the dots too (the board's corners)
    corners = np.array([[-6.0, 6.0], [6.0, 6.0], [6.0, -6.0], [-6.0, -6.0]])
    assert np.abs(image_to_board(r, project_board_points(pose, TARGET, corners)) - corners).max() < 0.01
    used = np.all(np.isfinite(r.dots_px), axis=1)
    # the measured ellipse centres sit within a fraction of a pixel of the projected circle centres
    # (the ellipse centre is not the projected centre: the difference is corrected in the fit)
    assert np.linalg.norm(r.dots_px[used] - truth[used], axis=1).max() < dots_max_px
    assert r.reprojection_px < 0.2
    return used


@pytest.mark.parametrize("name", sorted(SCENES))
def test_dot_board_found_and_its_homography_matches_the_renderer(tmp_path, name):
    pose = _pose(name)
    gray = _roundtrip(tmp_path, render_frame(TARGET, pose, lighting=SCENES[name]["light"], rng=7))
    r = find_marks(gray, TARGET)
    used = _check_homography(r, pose)
    assert used.all()
    # the outer dots are the result's vertices (TL, TR, BR, BL)
    truth = project_board_points(pose, TARGET, DOTS_M[[0, 2, 8, 6]])
    assert np.linalg.norm(r.vertices_px - truth, axis=1).max() < 0.1


@pytest.mark.parametrize("name", sorted(SCENES))
def test_dot_board_found_with_the_centre_dot_washed_out_by_the_spot(tmp_path, name):
    pose = _pose(name)
    # a concentrated beam on the reference dot, 40 times the ambient light: the dot is lit nearly as
    # bright as the white board around it and the frame saturates
    spot = Spot(center_m=(0.1, -0.15), size_m=(0.9, 0.8), peak=6000.0)
    gray = _roundtrip(tmp_path, render_frame(TARGET, pose, [spot], lighting=SCENES[name]["light"], rng=3))
    r = find_marks(gray, TARGET)
    used = _check_homography(r, pose)
    assert not used[4] and used.sum() == 8  # the centre dot is not used; the other eight are


def test_dot_board_found_with_a_dot_painted_over(tmp_path):
    pose = _pose("frontal")
    gray = render_frame(TARGET, pose, rng=5)
    x, y = project_board_points(pose, TARGET, DOTS_M[[2]])[0].astype(int)  # the top-right dot
    gray[y - 45: y + 45, x - 60: x + 60] = 150
    r = find_marks(_roundtrip(tmp_path, gray), TARGET)
    used = _check_homography(r, pose)
    assert not used[2] and used.sum() == 8


def test_dots_not_found_on_a_mark_board_a_blank_frame_or_with_five_dots_hidden(tmp_path):
    blank = np.full((1024, 1280), 140, np.uint8)
    r = find_marks(blank, TARGET)
    assert not r.found and r.reason == "marks_not_found" and np.all(np.isnan(r.homography))
    pose = _pose("frontal")
    # a frame of the L-mark board: no dots in it, whatever the dot finder sees
    r = find_marks(render_frame(demo_target(), pose, rng=1), TARGET)
    assert not r.found and r.reason == "marks_not_found"
    gray = render_frame(TARGET, pose, rng=5)
    for k in (0, 1, 2, 4, 6):  # five dots hidden: four remain, one short of a checked homography
        x, y = project_board_points(pose, TARGET, DOTS_M[[k]])[0].astype(int)
        gray[y - 45: y + 45, x - 60: x + 60] = 150
    r = find_marks(_roundtrip(tmp_path, gray), TARGET)
    assert not r.found and r.reason == "marks_not_found" and "dots" in r.message


def test_a_too_strict_reprojection_limit_reports_reprojection():
    r = find_marks(render_frame(TARGET, _pose("frontal"), rng=2), TARGET, max_reprojection_px=0.001)
    assert not r.found and r.reason == "reprojection" and np.isfinite(r.reprojection_px)


@pytest.mark.parametrize("centre, tol_mm", [((2.2, -1.9), 5.0), ((0.45, 0.35), 25.0)])
def test_spot_centre_on_a_dot_board_off_and_on_the_reference_dot(centre, tol_mm):
    """Off the dots the spot is measured as on a mark board; on the reference dot (the usual aim)
    its light, dimmed by the dot, is restored from the before frame (without that the centre is
    pushed 0.1-0.7 m off the dot)."""
    pose = _pose("frontal")
    black = Lighting(dot_albedo=BLACK)
    before = render_frame(TARGET, pose, lighting=black, rng=11)
    errs = []
    for seed in range(3):
        after = render_frame(TARGET, pose, [Spot(centre, (0.8, 0.7), peak=60, angle_deg=30)], lighting=black,
                             rng=20 + seed)
        r = measure_spot(before, [after], TARGET)
        assert r.valid, r.message
        errs.append(1000 * np.linalg.norm(r.offset_m - centre))
    assert max(errs) < tol_mm, errs


def _reference_dot_errors_mm(target, lighting, n=12, seed=1):
    """Centre errors [mm] of ``n`` spots (Gaussian and flat, 0.6-1.2 m, 50-75 grey levels) centred
    within 0.6 m of the board centre (a dot board's reference dot) in the demo view, each with its own
    before frame; the renderer places them exactly."""
    pose = look_at_pose(DEMO_CAMERA_ENU_M, target, 5200, (1280, 1024))
    rng = np.random.default_rng(seed)
    errs = []
    for _ in range(n):
        before = render_frame(target, pose, lighting=lighting, rng=int(rng.integers(1 << 30)))
        centre = tuple(rng.uniform(-0.6, 0.6, 2))
        spot = Spot(centre, tuple(rng.uniform(0.6, 1.2, 2)), peak=float(rng.uniform(50, 75)),
                    shape=str(rng.choice(["gaussian", "flat"])), angle_deg=float(rng.uniform(0, 180)))
        after = render_frame(target, pose, [spot], lighting=lighting, rng=int(rng.integers(1 << 30)))
        r = measure_spot(before, [after], target)
        assert r.valid, r.message
        errs.append(1000 * np.linalg.norm(r.offset_m - centre))
    return np.array(errs)


def test_spots_on_the_reference_dot_are_centred_within_10_mm_rms():
    """Twelve spots near the reference dot on black dots. On a 6 % dot the restored light carries the
    after frame's noise (1.5 grey levels) times 17, so the centre of one spot scatters by several mm;
    the set's RMS is held to 11 mm (0.09 mrad at 120 m). Without the before frame's model on the dot
    and the smoother detection estimate the same set is 17 mm RMS."""
    errs = _reference_dot_errors_mm(TARGET, Lighting(dot_albedo=BLACK))
    assert np.sqrt(np.mean(np.square(errs))) < 11.0, np.round(errs, 1)


def test_light_grey_dots_measure_spots_on_the_reference_dot_as_well_as_a_mark_board():
    """The same twelve spots near the reference dot (the usual aim) on the board with light-grey dots
    (the default paint, ``DOT_ALBEDO``), with black dots and with T/GRLM's L marks instead: light-grey
    dots are no worse than the mark board (the issue's goal), black dots lose most of the spot's
    light there and are more than twice as far off."""
    def rms(errs):
        return float(np.sqrt(np.mean(np.square(errs))))

    assert Lighting().dot_albedo == DOT_ALBEDO > 0.5
    grey = rms(_reference_dot_errors_mm(TARGET, Lighting()))
    black = rms(_reference_dot_errors_mm(TARGET, Lighting(dot_albedo=BLACK)))
    marks = rms(_reference_dot_errors_mm(demo_target(), Lighting()))
    assert grey <= marks and black > 2 * marks, (grey, black, marks)


def test_dot_fill_leaves_a_spot_off_the_dots_and_mark_boards_unchanged(monkeypatch):
    """The restoration touches only the dots' neighbourhood: a spot off the dots is measured exactly
    as without it, and a mark board never builds it."""
    import helicalib.vision.dots as dots

    pose = _pose("frontal")
    before = render_frame(TARGET, pose, rng=11)
    centre = (2.2, -1.9)
    after = render_frame(TARGET, pose, [Spot(centre, (0.5, 0.4), peak=60, angle_deg=30)], rng=20)
    with_fill = measure_spot(before, [after], TARGET)

    class NoFill:
        def __init__(self, *args):
            pass

        def correct(self, D, k=1.0):
            return D, D

    monkeypatch.setattr(dots, "DotFill", NoFill)
    without = measure_spot(before, [after], TARGET)
    assert with_fill.valid and without.valid
    np.testing.assert_allclose(with_fill.offset_m, without.offset_m, atol=1e-9)
    assert 1000 * np.linalg.norm(with_fill.offset_m - centre) < 5.0

    class Refuse:
        def __init__(self, *args):
            raise AssertionError("a mark board does not restore light on its marks")

    monkeypatch.setattr(dots, "DotFill", Refuse)
    marks_board = demo_target()
    before = render_frame(marks_board, pose, rng=11)
    after = render_frame(marks_board, pose, [Spot(centre, (0.8, 0.7), peak=60, angle_deg=30)], rng=20)
    r = measure_spot(before, [after], marks_board)
    assert r.valid and 1000 * np.linalg.norm(r.offset_m - centre) < 5.0, r.message


# ---------------------------------------------------------------------------- config
def _demo_data(demo_field_path):
    return yaml.safe_load(demo_field_path.read_text())


def test_marks_kind_defaults_to_right_angles_and_dots_take_the_article_sizes(demo_field_path):
    data = _demo_data(demo_field_path)
    cfg = parse_field_config(data, "f.yaml")
    assert all(t.marks.kind == "right-angles" for t in cfg.targets)
    data["targets"][1]["marks"] = {"kind": "dots"}
    m = parse_field_config(data, "f.yaml").targets[1].marks
    assert isinstance(m, DotMarks) and (m.large_diameter_m, m.small_diameter_m, m.pitch_m) == (1.7, 0.85, 4.25)
    assert m.diameters_m().tolist() == [1.7, 0.85, 1.7, 0.85, 1.7, 0.85, 1.7, 0.85, 1.7]
    # the reference dot lies at the board centre, the grid around it
    data["targets"][1]["marks"] = {"kind": "dots", "reference": "top-left", "pitch_m": 2.5}
    m = parse_field_config(data, "f.yaml").targets[1].marks
    assert m.dots_m()[0].tolist() == [0.0, 0.0] and m.dots_m()[8].tolist() == [5.0, -5.0]


@pytest.mark.parametrize("marks, where, says", [
    ({"kind": "circles"}, "targets[1].marks", "kind: expected right-angles"),
    ({"kind": "dots", "pitch_m": 1.5}, "targets[1].marks.pitch_m", "less than a quarter of a large dot"),
    ({"kind": "dots", "pitch_m": 5.5}, "targets[1].marks", "the top-left dot"),
    ({"kind": "dots", "layout": ["LsL", "sXs", "LsL"]}, "targets[1].marks.layout", "row [1]"),
    ({"kind": "dots", "small_diameter_m": 2.0}, "targets[1].marks.small_diameter_m", "larger than large_diameter_m"),
    ({"kind": "dots", "reference": "middle"}, "targets[1].marks.reference", "centre"),
    ({"kind": "dots", "arm_m": 1.4}, "targets[1].marks.arm_m", "unknown key"),
    ({"kind": "right-angles", "pitch_m": 4.0, "vertices_m": [[-5.5, 5.5], [5.5, 5.5], [5.5, -5.5], [-5.5, -5.5]],
      "arm_m": 1.4, "thickness_m": 0.35}, "targets[1].marks.pitch_m", "unknown key"),
])
def test_bad_dot_marks_name_their_key_path(demo_field_path, marks, where, says):
    data = _demo_data(demo_field_path)
    data["targets"][1]["marks"] = marks
    with pytest.raises(ConfigError) as exc:
        parse_field_config(data, "f.yaml")
    first = str(exc.value).splitlines()[0]
    assert first.startswith(f"f.yaml: {where}: ") and says in first, first


# ---------------------------------------------------------------------------- simulated plant
@pytest.fixture(scope="module")
def cylinder():
    return load_field_config(CYLINDER)


def test_simulated_cameras_render_dot_boards_the_vision_finds(cylinder):
    from helicalib.app.simulated import default_start_s
    from helicalib.sim.camera import SimCamera
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario

    # black dots, as T/GRLM's marks: the tightest check of the renderer's geometry (light-grey dots,
    # the default, on one spot-exposed frame: test_light_grey_dots_are_found_on_frames_exposed_for_the_spot)
    sc = Scenario()
    sc = sc.model_copy(update={"camera": sc.camera.model_copy(update={"dot_albedo": 0.04})})
    plant = SimulatedPlant(cylinder, sc, start_s=default_start_s(cylinder) + 11 * 3600)
    normals, obliquity = [], {}
    for cam in cylinder.cameras:
        target = cylinder.target(cam.target)
        normals.append(np.asarray(target.normal_enu))
        sim = SimCamera(plant, cam.id)
        img, _ = sim.render()
        r = find_marks(img, target, cam)
        assert r.found and r.kind == "dots", (cam.id, r.message)
        H = sim.renderer.h_board  # the renderer's own board → pixel homography
        truth = _apply_h(H, DOTS_M)
        assert np.linalg.norm(r.center_px - _apply_h(H, np.zeros((1, 2)))[0]) < 0.1, cam.id
        assert np.abs(image_to_board(r, truth) - DOTS_M).max() < 0.01, cam.id
        to_cam = np.asarray(cam.position_enu_m) - np.asarray(target.center_enu_m)
        obliquity[target.id] = np.degrees(np.arccos(to_cam @ np.asarray(target.normal_enu) / np.linalg.norm(to_cam)))
    # the side boards are seen more obliquely than the centre board, which its camera sees along its azimuth
    assert min(obliquity["TW"], obliquity["TE"]) > obliquity["TN"] + 15, obliquity
    # the boards stand on a cylinder: each normal points away from the tower axis at its own azimuth
    for t, n in zip(cylinder.targets, normals):
        radial = np.asarray(t.center_enu_m[:2]) / np.linalg.norm(t.center_enu_m[:2])
        assert n[:2] @ radial / np.linalg.norm(n[:2]) > 0.9999


def test_short_simulated_campaign_on_dot_boards_gives_valid_observations(cylinder, tmp_path):
    from helicalib.app.simulated import default_start_s, SimulationOptions, simulate_campaign
    from helicalib.store.sqlite import Store

    start = default_start_s(cylinder) + 9.5 * 3600
    ids = ["H0001", "H0004", "H0008"]  # one on each board (west, north, east)
    res = simulate_campaign(cylinder, tmp_path, SimulationOptions(days=1.0 / 24, seed=5, start_s=start,
                                                                  heliostat_ids=ids))
    store = Store.open(res.database)
    obs = store.observations()
    store.close()
    valid = [o for o in obs if o.valid]
    assert {o.heliostat_id for o in valid} == set(ids), sorted({(o.heliostat_id, o.reason) for o in obs})
    assert not [o for o in obs if o.reason in ("marks_not_found", "reprojection")]


@pytest.mark.parametrize("name", sorted(SCENES))
def test_light_grey_dots_are_found_whole_and_the_homography_matches(tmp_path, name):
    """Dots of albedo 0.65 (light grey, the default ``DOT_ALBEDO``) are found, all nine used: near the
    board's dark rim a light dot comes out whole only in an adaptive block clear of the rim, and the
    finder keeps the blob whose white ring is the flattest (with the first blob found, the top-right dot
    of the frontal scene sat 1.8 px off and was dropped)."""
    import dataclasses

    pose = _pose(name)
    light = dataclasses.replace(SCENES[name]["light"], dot_albedo=DOT_ALBEDO)
    gray = _roundtrip(tmp_path, render_frame(TARGET, pose, lighting=light, rng=7))
    r = find_marks(gray, TARGET)
    assert r.found and r.kind == "dots", r.message
    used = np.all(np.isfinite(r.dots_px), axis=1)
    assert used.all()
    truth = project_board_points(pose, TARGET, DOTS_M)
    assert np.linalg.norm(r.dots_px - truth, axis=1).max() < 0.5
    assert np.linalg.norm(r.center_px - project_board_points(pose, TARGET, np.zeros((1, 2)))[0]) < 0.15


def test_the_scenario_paints_dot_boards_with_dot_albedo_and_mark_boards_with_mark_albedo(cylinder, demo_field_path):
    """``camera.dot_albedo`` of the scenario is the dots' paint in the simulated camera's board
    raster (light grey by default, 0.65 of the white board), and leaves mark boards to ``mark_albedo``."""
    from helicalib.sim.boards import dark_mask
    from helicalib.sim.camera import SimCamera
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario
    from helicalib.app.simulated import default_start_s

    def painted(cfg, **camera):
        sc = Scenario()
        sc = sc.model_copy(update={"camera": sc.camera.model_copy(update=camera)})
        cam = cfg.cameras[0]
        board = SimCamera(SimulatedPlant(cfg, sc, start_s=default_start_s(cfg) + 11 * 3600), cam.id).renderer
        uu, vv = np.meshgrid(board.u_m, board.v_m)
        dark = dark_mask(cfg.target(cam.target), uu, vv)

        def values(a):
            return {round(float(x), 4) for x in np.unique(a)}

        return values(board.albedo[dark]), values(board.albedo[~dark])

    assert painted(cylinder) == ({0.585}, {0.9})
    assert painted(cylinder, dot_albedo=0.04) == ({0.04}, {0.9})
    assert painted(cylinder, dot_albedo=0.45, mark_albedo=0.1) == ({0.45}, {0.9})
    demo = load_field_config(demo_field_path)
    assert painted(demo, dot_albedo=0.45, mark_albedo=0.1) == ({0.1}, {0.9})


def test_light_grey_dots_are_found_on_frames_exposed_for_the_spot(cylinder):
    """The simulated cameras expose for the spot, so the ambient-lit board shows at some 25 grey
    levels and light-grey dots (the scenario's default ``dot_albedo`` 0.585, 0.65 of the white) only about 9 levels
    below it: the finder's contrast floor follows the ring's noise (``CONTRAST_NOISE``), not a fixed
    10 levels, and finds all three boards of the cylinder. The board is fixed less well than with black
    dots (their contrast is about 2.7 times larger), still within 0.25 px of the renderer's centre."""
    from helicalib.sim.camera import SimCamera
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario
    from helicalib.app.simulated import default_start_s

    sc = Scenario()
    assert sc.camera.dot_albedo / sc.camera.board_albedo == pytest.approx(DOT_ALBEDO)
    plant = SimulatedPlant(cylinder, sc, start_s=default_start_s(cylinder) + 11 * 3600)
    for cam in cylinder.cameras:
        sim = SimCamera(plant, cam.id)
        img, _ = sim.render()
        target = cylinder.target(cam.target)
        r = find_marks(img, target, cam)
        assert r.found and r.kind == "dots", (cam.id, r.message)
        centre = _apply_h(sim.renderer.h_board, np.zeros((1, 2)))[0]
        assert np.linalg.norm(r.center_px - centre) < 0.25, cam.id
        assert np.abs(image_to_board(r, _apply_h(sim.renderer.h_board, DOTS_M)) - DOTS_M).max() < 0.02, cam.id


def test_the_camera_sensor_fixes_the_board_on_the_mean_of_its_before_frames(cylinder):
    """``CameraSensor`` finds a board's marks on its first before frame, then again on the mean of
    the last ``MARKS_MEAN_FRAMES`` before frames: on the simulated plant's spot-exposed frames of the
    cylinder's three boards (light-grey dots, 09:00), the board centre from the mean lands nearer the
    renderer's truth than from single frames (RMS over the boards against RMS over every single frame:
    measured 0.02 against 0.06 px; averaging 8 frames takes the sensor noise out of the fix, a bias
    stays); a reading that doubts the marks starts over on one frame."""
    from helicalib.campaign.sensor import MARKS_MEAN_FRAMES, CameraSensor
    from helicalib.sim.camera import SimCamera
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario
    from helicalib.app.simulated import default_start_s

    plant = SimulatedPlant(cylinder, Scenario(), start_s=default_start_s(cylinder) + 9 * 3600)
    singles, means = [], []
    for cam in cylinder.cameras:
        target = cylinder.target(cam.target)
        sim = SimCamera(plant, cam.id)
        truth = _apply_h(sim.renderer.h_board, np.zeros((1, 2)))[0]
        sensor = CameraSensor(sim, cam)
        frames = [sim.render()[0] for _ in range(MARKS_MEAN_FRAMES)]
        errors = [float(np.linalg.norm(sensor._marks_for(f, target).center_px - truth)) for f in frames]
        one = [float(np.linalg.norm(find_marks(f, target, cam).center_px - truth)) for f in frames]
        assert errors[:-1] == [one[0]] * (MARKS_MEAN_FRAMES - 1)  # the first frame's marks until 8 are there
        singles += one
        means.append(errors[-1])
        sensor._forget_marks()  # as after a "reprojection" reading: the next frame alone
        assert float(np.linalg.norm(sensor._marks_for(frames[1], target).center_px - truth)) == pytest.approx(one[1])
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert rms(means) < 0.7 * rms(singles), (means, singles)


def test_the_camera_sensor_finds_dim_light_grey_dots_on_more_frames_of_the_same_visit(cylinder):
    """A board lit dimly (the camera exposed for the spot, little diffuse light: the white at about
    13 grey levels) shows light-grey dots some 4.5 levels below it, under the finder's floor on one
    frame: ``CameraSensor.before`` then grabs ``MARKS_MEAN_FRAMES`` − 1 more frames and finds the
    board on their mean, so the visit is not lost to ``marks_not_found``; the visit's before frame
    is still its first one. Black dots are found on the first frame, with no extra grab."""
    from types import SimpleNamespace

    from helicalib.campaign.sensor import MARKS_MEAN_FRAMES, CameraSensor
    from helicalib.sim.camera import SimCamera
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario
    from helicalib.app.simulated import default_start_s
    from helicalib.vision.frames import decode_frame

    class Counting:
        def __init__(self, camera):
            self.camera, self.grabs = camera, 0

        def grab(self):
            self.grabs += 1
            return self.camera.grab()

    def sensor_on(dot_albedo):
        sc = Scenario()
        dim = {"ambient_fraction": 0.05, "ambient_offset_wm2": 25.0, "dot_albedo": dot_albedo}
        sc = sc.model_copy(update={"camera": sc.camera.model_copy(update=dim)})
        plant = SimulatedPlant(cylinder, sc, start_s=default_start_s(cylinder) + 11 * 3600)
        cam = cylinder.cameras[1]
        sim = SimCamera(plant, cam.id)
        ctx = SimpleNamespace(now=lambda: plant.t_s, settings=SimpleNamespace(max_capture_skew_s=5.0),
                              time_slack_s=None, heliostat_id="H0004", target=cylinder.target(cam.target))
        camera = Counting(sim)
        return CameraSensor(camera, cam), camera, sim, ctx

    sensor, camera, sim, ctx = sensor_on(Scenario().camera.dot_albedo)
    target = ctx.target
    one = sim.render()[0]
    x, y = _apply_h(sim.renderer.h_board, np.array([[4.0, 2.0]]))[0].astype(int)  # white board between dots
    white = float(np.median(one[y - 3:y + 4, x - 3:x + 4]))
    assert 11 < white < 15, white  # the white board, dimly lit
    assert not find_marks(one, target, sensor.camera_config).found  # one frame shows no dots
    before = sensor.before(ctx)
    image, marks = before.state
    assert camera.grabs == MARKS_MEAN_FRAMES and marks.found and marks.kind == "dots", marks.message
    assert np.array_equal(decode_frame(before.data, expected_shape=None), image)  # the visit's own first frame
    truth = _apply_h(sim.renderer.h_board, np.zeros((1, 2)))[0]
    assert np.linalg.norm(marks.center_px - truth) < 0.1
    sensor.before(ctx)  # the next visit reuses them: one grab
    assert camera.grabs == MARKS_MEAN_FRAMES + 1

    sensor, camera, sim, ctx = sensor_on(0.04)  # black dots
    assert sensor.before(ctx).state[1].found and camera.grabs == 1


def test_a_mean_that_shows_no_marks_is_not_sought_again_on_every_visit(monkeypatch):
    """When the marks are not found on the mean of the first ``MARKS_MEAN_FRAMES`` before frames, the
    sensor keeps the first frame's marks and does not look again at every visit (a find costs 10-50 ms)
    until they expire after ``MARKS_REUSE_VISITS`` visits."""
    from types import SimpleNamespace

    import helicalib.campaign.sensor as sensor_mod

    calls = []

    def fake_find(image, target, camera):
        calls.append(float(image.mean()))
        return SimpleNamespace(found=len(calls) == 1)  # only the first frame's marks are found

    monkeypatch.setattr(sensor_mod, "find_marks", fake_find)
    sensor = sensor_mod.CameraSensor(camera=None, camera_config=None)
    frames = [np.full((4, 4), k, dtype=np.uint8) for k in range(20)]
    marks = [sensor._marks_for(f, target=None) for f in frames]
    assert len(calls) == 2 and all(m is marks[0] and m.found for m in marks)
    assert calls[1] == pytest.approx(np.mean(range(sensor_mod.MARKS_MEAN_FRAMES)), abs=0.5)  # the mean of 8
