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
the plant's clock jumped (a plant restarted at an earlier date): :class:`ClockJumpError`."""


class ClockJumpError(PlantError):
    """The plant's time jumped backwards beyond :data:`STEP_BACK_TOLERANCE_S`; ``before_s`` is the
    controller's plant time, ``after_s`` what the plant reads now."""

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

    A plant time that runs backwards between reads by more than :data:`STEP_BACK_TOLERANCE_S` is
    refused (:class:`ClockJumpError`, every read until it is consistent again); a smaller step back
    is taken, and ``now_s`` holds until the plant's time catches up: it never decreases. :attr:`uncertainty_s` is how far the extrapolation may be off: half the
    plant seconds the last read of the plant's time took on the wire (the read answers somewhere
    inside that span).
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

    def sync(self) -> float:
        """Read the plant's time and rate now; returns the plant time [UTC s]."""
        m_before = float(self._source())
        t, rate = self._plant.plant_time()
        m_after = float(self._source())
        with self._lock:
            if self._t0 is not None and t < self._last - STEP_BACK_TOLERANCE_S:
                raise ClockJumpError(f"plant time went backwards: the plant reads {_iso(t)} after {_iso(self._last)} "
                                     f"({self._last - t:.0f} s back)", self._last, t)
            # the plant read its clock somewhere between the request and the answer: take the middle
            self._t0, self._m0, self.rate = float(t), 0.5 * (m_before + m_after), float(rate)
            self.uncertainty_s = 0.5 * float(rate) * (m_after - m_before)
        return float(t)

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


def _iso(t_s: float) -> str:
    import datetime as dt

    try:
        return dt.datetime.fromtimestamp(float(t_s), tz=dt.timezone.utc).isoformat(timespec="seconds")
    except (OverflowError, ValueError, OSError):
        return f"{t_s!r} s"


def make_clock(cfg, plant) -> SystemClock | PlantClock:
    """The clock a field config asks for (``plant.clock``)."""
    return PlantClock(plant) if cfg.plant.clock == "plant" else SystemClock()
