"""Clocks for live runs: the plant's own clock (``plant.clock: plant``) and UTC (``system``).

Both implement :class:`helicalib.devices.protocols.Clock`. Only these edge objects read real
time; the core is handed a clock. :class:`PlantClock` reads the plant's time and rate, then
extrapolates with a monotonic source between reads (re-reading every ``resync_s`` real
seconds), and sleeps ``plant seconds / rate`` real seconds.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from helicalib.errors import PlantError

STEP_BACK_TOLERANCE_S = 60.0
"""A plant time read this many plant seconds (or fewer) behind the controller's is a clock being set
(a time server's step): the controller's clock holds until the plant's catches up. Further back,
the plant's clock jumped (a plant restarted at an earlier date): :class:`ClockJumpError`. The
tolerance of each read grows by what the controller cannot know (:meth:`PlantClock.tolerance_s`)."""
DRIFT_SHARE = 0.02
"""The share of the plant seconds since the last read by which a plant's clock may run off the
controller's extrapolation (an emulator's clock lagging 1 % under load) before a read is a jump."""


class ClockJumpError(PlantError):
    """The plant's time jumped backwards, or forwards, beyond :meth:`PlantClock.tolerance_s`;
    ``before_s`` is the controller's plant time, ``after_s`` what the plant reads now."""

    def __init__(self, message: str, before_s: float, after_s: float):
        super().__init__(message)
        self.before_s, self.after_s = float(before_s), float(after_s)


class SystemClock:
    """UTC from the computer's clock; ``sleep`` waits real seconds."""

    rate = 1.0
    uncertainty_s = 0.0

    def __init__(self, source: Callable[[], float] = time.time, sleeper: Callable[[float], None] = time.sleep):
        self._source = source
        self._sleeper = sleeper

    def now_s(self) -> float:
        """Now [UTC s]."""
        return float(self._source())

    estimate_s = now_s

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._sleeper(float(seconds))


class PlantClock:
    """The plant's time (registers 8-13), extrapolated between reads.

    Parameters
    ----------
    plant : helicalib.devices.protocols.Plant
        Anything with ``plant_time() -> (t_s, rate)``.
    resync_s : float
        Re-read the plant's time after this many real seconds [s].
    source : callable
        Monotonic real time [s] (``time.monotonic``).
    sleeper : callable
        Real sleep [s] (``time.sleep``).

    A plant time that runs backwards between reads, or ahead of the extrapolation, by more than
    :meth:`tolerance_s` is refused (:class:`ClockJumpError`, every read until it is consistent
    again); a smaller step back is taken, and ``now_s`` holds until the plant's time catches up: it
    never decreases. :attr:`uncertainty_s` is how far the extrapolation may be off: half the plant
    seconds the last read of the plant's time took on the wire (the read answers somewhere inside
    that span).
    """

    def __init__(self, plant, resync_s: float = 30.0, source: Callable[[], float] = time.monotonic,
                 sleeper: Callable[[float], None] = time.sleep):
        self._plant = plant
        self.resync_s = float(resync_s)
        self._source = source
        self._sleeper = sleeper
        self._lock = threading.Lock()
        self._t0: float | None = None
        self._m0 = 0.0
        self.rate = 1.0
        self.uncertainty_s = 0.0
        self._last = -float("inf")

    def tolerance_s(self, rate: float, round_trip_s: float, since_s: float) -> float:
        """Plant seconds a read may lie off the controller's clock without being a jump: the step a
        time server may make (:data:`STEP_BACK_TOLERANCE_S`), the last read's uncertainty and this
        one's (half its round trip ``round_trip_s`` [real s] at ``rate``), and :data:`DRIFT_SHARE` of
        the plant seconds since the last read (``since_s`` real seconds)."""
        rate = max(float(rate), self.rate)
        return (STEP_BACK_TOLERANCE_S + self.uncertainty_s + 0.5 * rate * max(round_trip_s, 0.0)
                + DRIFT_SHARE * rate * max(since_s, 0.0))

    def sync(self) -> float:
        """Read the plant's time and rate now; returns the plant time [UTC s]."""
        m_before = float(self._source())
        t, rate = self._plant.plant_time()
        m_after = float(self._source())
        m = 0.5 * (m_before + m_after)  # the plant read its clock somewhere between the request and the answer
        with self._lock:
            if self._t0 is not None:
                self._check_jump(float(t), float(rate), m_after - m_before, m)
            self._t0, self._m0, self.rate = float(t), m, float(rate)
            self.uncertainty_s = 0.5 * float(rate) * (m_after - m_before)
        return float(t)

    def _check_jump(self, t: float, rate: float, round_trip_s: float, m: float) -> None:
        tol = self.tolerance_s(rate, round_trip_s, m - self._m0)
        if t < self._last - tol:  # behind the newest time this clock gave
            raise ClockJumpError(f"plant time went backwards: the plant reads {iso_utc(t)} after {iso_utc(self._last)} "
                                 f"({self._last - t:.0f} s back)", self._last, t)
        # ahead of where the plant's time can be now, whichever of the two rates it ran at since the last read
        high = max(self._t0 + max(rate, self.rate) * (m - self._m0), self._last)
        if t > high + tol:
            raise ClockJumpError(f"plant time jumped forwards: the plant reads {iso_utc(t)}, the controller's clock "
                                 f"{iso_utc(high)} ({t - high:.0f} s ahead)", high, t)

    def estimate_s(self) -> float:
        """Plant time extrapolated from the last read, without asking the plant (the controller's
        own clock, for records made while the plant does not answer); the computer's UTC before
        any read."""
        m = float(self._source())
        with self._lock:
            if self._t0 is None:
                return time.time()
            return max(self._t0 + self.rate * (m - self._m0), self._last)

    def now_s(self) -> float:
        """Plant time now [UTC s]."""
        m = float(self._source())
        if self._t0 is None or m - self._m0 >= self.resync_s:
            self.sync()
        with self._lock:
            t = self._t0 + self.rate * (m - self._m0)
            t = max(t, self._last)
            self._last = t
        return t

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of plant time (``seconds / rate`` real seconds)."""
        if seconds <= 0:
            return
        if self._t0 is None:
            self.sync()
        self._sleeper(float(seconds) / self.rate)


def iso_utc(t_s: float) -> str:
    """``2026-11-28T09:30:00+00:00`` (a time no calendar holds: its number of seconds)."""
    import datetime as dt

    try:
        return dt.datetime.fromtimestamp(float(t_s), tz=dt.timezone.utc).isoformat(timespec="seconds")
    except (OverflowError, ValueError, OSError):
        return f"{t_s!r} s"


def make_clock(cfg, plant) -> SystemClock | PlantClock:
    """The clock a field config asks for (``plant.clock``)."""
    return PlantClock(plant) if cfg.plant.clock == "plant" else SystemClock()
