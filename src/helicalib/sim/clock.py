"""Plant clocks for the simulated plant: a virtual clock (sleep advances time) and a rate clock.

Both implement :class:`helicalib.devices.protocols.Clock`. Neither reads the wall clock on its
own: :class:`RateClock` is given a monotonic time source (``time.monotonic`` at the CLI edge, a
fake in tests), so plant time = ``start_s + rate · (source() − source at start)``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable


class VirtualClock:
    """Plant time that only moves when told to: ``sleep(dt)`` advances it by ``dt`` at once.

    Parameters
    ----------
    start_s : float
        Initial plant time [UTC s].
    rate : float
        Rate reported to clients (a virtual clock has no real-time rate; default 0 = "as fast as
        the caller runs" is not part of the interface, so 1.0 is reported unless told otherwise).

    Listeners registered with :meth:`on_advance` are called with the new time after every advance
    (the in-process plant uses this to move its actuators).
    """

    def __init__(self, start_s: float, rate: float = 1.0):
        self._now_s = float(start_s)
        self.rate = float(rate)
        self._listeners: list[Callable[[float], None]] = []
        self._lock = threading.Lock()

    uncertainty_s = 0.0
    """A virtual clock is exact."""

    def now_s(self) -> float:
        """Current plant time [UTC s]."""
        return self._now_s

    estimate_s = now_s

    def sleep(self, seconds: float) -> None:
        """Advance plant time by ``seconds`` (negative values are refused)."""
        if seconds < 0:
            raise ValueError(f"sleep({seconds}): negative duration")
        self.advance_to(self._now_s + float(seconds))

    def advance_to(self, t_s: float) -> None:
        """Set plant time to ``t_s`` (never backwards) and notify the listeners."""
        with self._lock:
            if t_s < self._now_s:
                raise ValueError(f"advance_to({t_s}): before the current plant time {self._now_s}")
            self._now_s = float(t_s)
        for listener in list(self._listeners):
            listener(self._now_s)

    def on_advance(self, listener: Callable[[float], None]) -> None:
        """Call ``listener(now_s)`` after every advance."""
        self._listeners.append(listener)


class RateClock:
    """Plant time running ``rate`` times faster than a monotonic source.

    Parameters
    ----------
    start_s : float
        Plant time at construction [UTC s].
    rate : float
        Plant seconds per source second (600 = ten simulated minutes per real second).
    source : callable
        Monotonic time source in seconds (inject ``time.monotonic`` at the edge).
    sleeper : callable, optional
        Real sleep function for :meth:`sleep` (inject ``time.sleep`` at the edge); default: none,
        then :meth:`sleep` busy-waits on ``source`` (only useful with a fake source in tests).
    """

    def __init__(self, start_s: float, rate: float, source: Callable[[], float],
                 sleeper: Callable[[float], None] | None = None):
        if not rate > 0:
            raise ValueError(f"rate {rate}: must be > 0")
        self.start_s = float(start_s)
        self.rate = float(rate)
        self._source = source
        self._sleeper = sleeper
        self._t0 = float(source())

    uncertainty_s = 0.0

    def now_s(self) -> float:
        """Current plant time [UTC s]."""
        return self.start_s + self.rate * (float(self._source()) - self._t0)

    estimate_s = now_s

    def sleep(self, seconds: float) -> None:
        """Wait until ``seconds`` of plant time have passed."""
        if seconds <= 0:
            return
        end = self.now_s() + float(seconds)
        while True:
            left = end - self.now_s()
            if left <= 0:
                return
            if self._sleeper is None:
                continue
            self._sleeper(left / self.rate)
