"""Several spots on one board: each isolated by the order of arrival (the frame before a heliostat
arrives is the "before" of its spot), never guessed by proximity. Rendered frames, the T/GRLM
annex A centre of :func:`measure_spot` unchanged."""

from __future__ import annotations

import numpy as np

from helicalib.sim.render import DEMO_CAMERA_ENU_M, Spot, demo_target, look_at_pose, render_frame
from helicalib.vision.spot import measure_spot

TARGET = demo_target()
POSE = look_at_pose(DEMO_CAMERA_ENU_M, TARGET, 5200, (1280, 1024))


def _arrivals(rng, n: int, spread_m: float, peak: tuple[float, float]):
    """``n`` spots within ``spread_m`` of the board centre (overlapping when it is small), and the
    frames as they arrive one after another: frames[k] holds the first k spots."""
    centres = [tuple(rng.uniform(-spread_m, spread_m, 2)) for _ in range(n)]
    spots = [Spot(c, tuple(rng.uniform(0.5, 0.9, 2)), peak=float(rng.uniform(*peak)),
                  angle_deg=float(rng.uniform(0, 180))) for c in centres]
    frames = [render_frame(TARGET, POSE, spots[:k], rng=int(rng.integers(1 << 30))) for k in range(n + 1)]
    return spots, frames


def test_overlapping_spots_are_isolated_by_their_order_of_arrival():
    rng = np.random.default_rng(3)
    seq, alone = [], []
    for _ in range(4):
        spots, frames = _arrivals(rng, 4, 1.2, (28.0, 36.0))  # four spots overlapping within 1.2 m
        centres = np.array([s.center_m for s in spots])
        assert np.max(np.linalg.norm(centres[:, None] - centres[None], axis=-1)) < 3.4  # they overlap
        for k, s in enumerate(spots):
            r = measure_spot(frames[k], [frames[k + 1]], TARGET)  # the previous arrival's frame is the before
            assert r.valid, (k, r.reason, r.message)
            seq.append(1000 * np.linalg.norm(r.offset_m - centres[k]))
            single = measure_spot(frames[0], [render_frame(TARGET, POSE, [s], rng=int(rng.integers(1 << 30)))],
                                  TARGET)
            alone.append(1000 * np.linalg.norm(single.offset_m - centres[k]))
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    assert max(seq) < 10.0, np.round(seq, 1)
    # sharing the board costs the centre no more than the noise of a second frame
    assert rms(seq) <= 1.5 * rms(alone), (rms(seq), rms(alone))


def test_a_sum_that_saturates_refuses_the_later_arrival_and_keeps_the_earlier_ones():
    rng = np.random.default_rng(8)
    spots, frames = _arrivals(rng, 3, 0.3, (70.0, 80.0))  # three bright spots on one place
    first = measure_spot(frames[0], [frames[1]], TARGET)
    last = measure_spot(frames[2], [frames[3]], TARGET)
    assert first.valid
    assert not last.valid and last.reason == "saturated"
