"""The plant clock's jump check at high rates: a slow read or an emulator's lagging clock is not a
jump; a plant time far behind, or far ahead of where it can be, is (one :class:`ClockJumpError`).

A fake plant whose clock runs at a chosen share of its stated rate, and a fake monotonic source
that each read of the plant's time moves on by the round trip.
"""

from __future__ import annotations

import pytest

from helicalib.devices.clock import ClockJumpError, PlantClock

RATE = 240.0
START = 1.78e9


class _Plant:
    """A plant stating ``RATE`` whose clock runs at ``pace`` × RATE; each read takes ``rtt_s`` real
    seconds (the read answers in its middle); ``offset_s`` is added from the moment it is set."""

    def __init__(self, real, pace=1.0, rtt_s=0.0):
        self.real, self.pace, self.rtt_s, self.offset_s = real, pace, rtt_s, 0.0

    def plant_time(self):
        self.real[0] += self.rtt_s / 2
        t = START + self.pace * RATE * self.real[0] + self.offset_s
        self.real[0] += self.rtt_s / 2
        return t, RATE


def _clock(plant, real):
    return PlantClock(plant, resync_s=30.0, source=lambda: real[0], sleeper=lambda s: None)


@pytest.mark.parametrize("pace, rtt_s", [(0.99, 0.0), (1.0, 0.5), (0.99, 0.5), (1.01, 0.5)],
                         ids=["lags-1pct", "rtt-0.5s", "both", "runs-1pct-fast"])
def test_a_slow_read_or_a_lagging_emulator_at_240x_is_no_jump(pace, rtt_s):
    real = [0.0]
    plant = _Plant(real, pace, rtt_s)
    clock = _clock(plant, real)
    last = clock.now_s()
    for _ in range(30_000):  # five real minutes (20 plant hours), read every 10 ms (a tick), a resync every 30 s
        real[0] += 0.01
        t = clock.now_s()
        assert t >= last
        last = t


@pytest.mark.parametrize("offset_s, words", [(-86400.0, "went backwards"), (86400.0, "jumped forwards"),
                                             (-1800.0, "went backwards"), (1800.0, "jumped forwards")])
def test_a_plant_clock_that_jumps_either_way_during_a_run_is_refused(offset_s, words):
    real = [0.0]
    plant = _Plant(real, 1.0, 0.05)
    clock = _clock(plant, real)
    for _ in range(4500):  # 45 real seconds read every 10 ms (a tick): a resync on the way
        real[0] += 0.01
        clock.now_s()
    plant.offset_s = offset_s  # the plant restarted at another date (or its clock was set by hand)
    with pytest.raises(ClockJumpError, match=words) as err:
        for _ in range(3100):  # seen at the next resync, within 30 real seconds
            real[0] += 0.01
            clock.now_s()
    assert abs(err.value.after_s - err.value.before_s) > 1000.0
    with pytest.raises(ClockJumpError):  # every read until it is consistent again
        clock.now_s()
