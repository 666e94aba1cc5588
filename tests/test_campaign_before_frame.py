"""A before frame that held another beam: the visit takes it again (campaign/measure.py,
``retake_before``) instead of losing the reading.

On the in-process simulated plant with rendered PNG frames and a real store. The board's camera
draws another heliostat's beam (a spot of a beam's power, away from the board's centre) on the
first ``dirty`` before frames of the visit, i.e. frames taken while the measured heliostat's own
beam is off the board (the simulator's truth says where it lands), as a beam crossing the board on
its way back to tracking would. The truth of where the measured beam lands comes from the
simulator, not from the campaign's models.
"""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.campaign import measure
from helicalib.campaign.board import Board
from helicalib.config import load_field_config
from helicalib.devices.registers import HeliostatState
from helicalib.geometry import optics
from helicalib.sim.fast_sensor import SpotPhysics, lost_light_share

from campaign_helpers import inprocess_campaign

CROSSING_UV_M = (-2.5, 2.0)
"""Where the other beam lies on the board [m from its centre]: clear of the measured spot."""


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def _own_beam_on_board(sim, index: int, target) -> bool:
    beams = sim.true_beams(sim.t_s)
    uv, _hit, valid = optics.intersect_target(beams.origin_enu[[index]], beams.direction_enu[[index]], target)
    return bool(valid[0] and np.all(np.abs(uv[0]) <= np.asarray(target.size_m) / 2.0))


def _crossing_camera(dirty: int, index: int, counts: list):
    """Wraps the board's simulated camera: its first ``dirty`` frames taken with heliostat ``index``'s
    beam off the board also show another beam at :data:`CROSSING_UV_M`; ``counts`` gets one entry per
    such frame (True: drawn with the other beam)."""

    def wrap(cam, sim, target):
        plain = cam.render

        def render():
            image, t = plain()
            if _own_beam_on_board(sim, index, target):
                return image, t
            drawn = len([c for c in counts if c]) < dirty
            counts.append(drawn)
            if not drawn:
                return image, t
            power = float(sim.weather().dni_wm2) * float(np.prod(sim.nominal.drives.mirror_size_m[index])) * 0.8
            spot = (np.array([CROSSING_UV_M]), np.array([power]), np.array([[2.4, 2.4]]), np.array([[0.3, 0.3]]))
            uv, pw, wd, sg = cam.renderer.spots_from_beams(*_beams(sim), others=cam.others)
            both = (np.vstack([uv, spot[0]]), np.concatenate([pw, spot[1]]), np.vstack([wd, spot[2]]),
                    np.vstack([sg, spot[3]]))
            return cam.renderer.render(both, float(sim.weather().dni_wm2), True), t

        cam.render = render
        return cam

    return wrap


def _beams(sim):
    t = sim.t_s
    sun, _ = sim.sun(t)
    b = sim.true_beams(t)
    return (b.origin_enu, b.direction_enu, sun, b.normal_enu, sim.nominal.drives.mirror_size_m,
            float(sim.weather().dni_wm2), sim.soiling.cleanliness(t))


def _first_visit(cfg, tmp_path, dirty: int):
    hid = "H0001"
    counts: list = []
    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path, 10, 3, [hid],
                                                    camera=_crossing_camera(dirty, cfg.heliostat_index(hid), counts))
    runner.run_until(sim.t_s + 900)
    obs = [o for o in store.observations(cid) if o.iteration == 0]
    store.close()
    assert obs, "no placement in 15 plant minutes"
    return obs[0], counts, tmp_path / "img"


def test_a_before_frame_that_held_another_beam_is_taken_again_and_the_reading_is_valid(cfg, tmp_path):
    """The first before frame holds another beam: the beam goes to standby, the before frame is taken
    again (clean), and the same after frames give a valid reading whose message says so. Without
    the retake the reading was refused as ``ambient_change`` (the other beam's light is gone in
    the after frame)."""
    first, counts, images = _first_visit(cfg, tmp_path, dirty=1)
    assert counts[:2] == [True, False]  # the first before frame with the other beam, the second without
    assert first.valid, (first.reason, first.message)
    assert measure.RETAKEN + " 1 time" in first.message and "another beam" in first.message
    assert first.before_frame_path is not None and (images / first.before_frame_path).is_file()
    assert first.before_frame_path.endswith("before-1.png")  # the retaken frame; the first is kept beside it


def test_after_the_limit_of_retakes_the_reading_is_refused_saying_why(cfg, tmp_path):
    """Every before frame holds another beam: after :data:`MAX_BEFORE_RETAKES` retakes the reading is
    refused as ``ambient_change`` and says the limit was reached; no further frame is taken for it."""
    n = measure.MAX_BEFORE_RETAKES
    first, counts, _ = _first_visit(cfg, tmp_path, dirty=100)
    assert not first.valid and first.reason == "ambient_change"
    assert f"{measure.RETAKEN} {n} times (the limit)" in first.message
    assert "another beam crossed the board while the before frame was taken" in first.message
    assert counts[:n + 1] == [True] * (n + 1)  # the first before frame and n retakes, each with the beam


def test_a_clean_before_frame_is_not_taken_again(cfg, tmp_path):
    first, counts, _ = _first_visit(cfg, tmp_path, dirty=0)
    assert first.valid and measure.RETAKEN not in first.message


class _Plant:
    """Plant states of heliostats by index (the others' are HOLDING)."""

    def __init__(self, moving_until: dict[int, float]):
        self.t, self.moving_until = 0.0, moving_until

    def status(self, index):
        class S:
            state = HeliostatState.MOVING if self.t < self.moving_until.get(index, -1.0) else HeliostatState.TRACKING
        return S


def _wait(ctx, plant):
    """Run the wait before a retake on ``plant``'s clock; returns (seen moving, still moving)."""
    gen = measure._beams_gone(ctx, measure.RETAKE_WAIT_S)
    try:
        while True:
            plant.t += next(gen)
    except StopIteration as stop:
        return stop.value


def test_the_retake_waits_until_the_board_s_last_heliostats_stop_moving():
    """The board remembers whose turn ended and who is on the way in; the wait before a retake lasts
    until the plant says none of them moves (at least the minimum, at most the timeout)."""
    board = Board("T1", cap=3)
    for hid, index in (("A", 0), ("B", 1), ("C", 2)):
        board.join(hid)
        board.arrive(hid, index)
    list(board.acquire("A"))
    board.release("A")  # A's turn ended: its beam travels back to tracking
    board.leave("A")
    list(board.acquire("B"))
    assert board.movers("B") == [("A", 0), ("C", 2)]
    plant = _Plant({0: 30.0, 2: 11.0})

    class Ctx:
        heliostat_id = "B"

    ctx = Ctx()
    ctx.board, ctx.plant = board, plant
    seen, still = _wait(ctx, plant)
    assert seen == ["A", "C"] and still == [] and 30.0 <= plant.t <= 30.0 + measure.move_status.POLL_S
    assert board.movers("B") == [("C", 2)]  # A arrived at tracking: forgotten; C is a visitor still
    plant.moving_until = {2: 1e9}  # one that never stops: the wait ends at the timeout
    plant.t = 0.0
    seen, still = _wait(ctx, plant)
    assert still == ["C"] and plant.t == pytest.approx(measure.BEAM_CLEAR_TIMEOUT_S)


def test_the_fast_sensor_sees_light_lost_since_the_before_frame_as_the_vision_does(cfg):
    """The fast sensor's lost-light share: another spot of the same power, clear of the measured one,
    covers about its area (refused); one far fainter, or none, nothing."""
    target = cfg.target("T1")
    ours = SpotPhysics(np.array([0.5, -0.4]), np.array([1.5, 1.5]), np.array([0.2, 0.2]), 8000.0, True)
    other = SpotPhysics(np.array(CROSSING_UV_M), np.array([1.5, 1.5]), np.array([0.2, 0.2]), 8000.0, True)
    faint = SpotPhysics(np.array(CROSSING_UV_M), np.array([1.5, 1.5]), np.array([0.2, 0.2]), 500.0, True)
    assert lost_light_share(ours, (other,), target, 0.3) == pytest.approx(1.0, abs=0.15)
    assert lost_light_share(ours, (faint,), target, 0.3) == 0.0
    assert lost_light_share(ours, (), target, 0.3) == 0.0
