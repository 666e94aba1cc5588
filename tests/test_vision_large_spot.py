"""Large spots: a beam whose faint tails cover most of the board, and a spot clipped by the edge.

Both met in the campaign on the simulated plant: a 20 m² mirror at 130 m throws a spot whose
3-sigma tails reach across a 12 m board, and a new heliostat's first placement often lands
partly off the board.
"""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.vision.frames import read_frame, write_png
from helicalib.vision.marks import find_marks
from helicalib.sim.render import DEMO_CAMERA_ENU_M, Lighting, Spot, demo_target, look_at_pose, render_frame
from helicalib.vision.spot import measure_spot

TARGET = demo_target()
POSE = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024))
LIGHT = Lighting(ambient=40.0, gradient=(0.05, -0.03), background=12.0, noise_sigma=1.5)


def _frame(tmp_path, name, spots=(), lighting=LIGHT, seed=0):
    return read_frame(write_png(tmp_path / name, render_frame(TARGET, POSE, spots, lighting, rng=seed)))


@pytest.mark.parametrize("ambient_change", [1.0, 1.1])
@pytest.mark.parametrize("spot", [
    Spot(center_m=(0.6, -0.4), size_m=(1.8, 1.8), peak=160.0),                        # tails over most of the board
    Spot(center_m=(-0.3, 0.2), size_m=(5.6, 4.6), peak=70.0, shape="flat", edge=0.4),  # covers more than half of it
])
def test_spot_over_most_of_the_board_is_measured(tmp_path, ambient_change, spot):
    before = _frame(tmp_path, "b.png", seed=1)
    after_light = Lighting(ambient=LIGHT.ambient * ambient_change, gradient=LIGHT.gradient,
                           background=LIGHT.background, noise_sigma=LIGHT.noise_sigma)
    after = _frame(tmp_path, "a.png", [spot], after_light, seed=2)
    res = measure_spot(before, [after], TARGET, method="grlm-centroid")
    assert res.valid, (res.reason, res.message)
    assert res.frames[0].ambient_ratio == pytest.approx(ambient_change, abs=0.03)
    assert np.hypot(*(res.offset_m - np.array(spot.center_m))) < 0.05


def test_clipped_spot_is_invalid_but_says_where_its_visible_part_lies(tmp_path):
    spot = Spot(center_m=(5.4, 0.3), size_m=(1.2, 1.2), peak=120.0)  # centre near the right edge (u = +6 m)
    before = _frame(tmp_path, "b.png", seed=3)
    after = _frame(tmp_path, "a.png", [spot], seed=4)
    marks = find_marks(before, TARGET)
    res = measure_spot(before, [after], TARGET, marks=marks)
    assert not res.valid and res.reason == "clipped"
    assert res.offset_m is not None
    # the visible part lies toward the spot's side of the board, biased toward the centre
    assert 3.0 < res.offset_m[0] <= 6.0
    assert abs(res.offset_m[1] - 0.3) < 0.5
