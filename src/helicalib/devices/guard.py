"""What every plant client checks before it sends anything, whatever its protocol.

:class:`CommandGuard` holds the safety rules a plant adapter (Modbus through a register map, OPC
UA through a node map) applies in front of its own encoding, so the rules cannot differ between
protocols:

* **armed**: an unarmed client reads and plans but never writes; every write raises
  :class:`~helicalib.errors.PlantError` before anything is sent;
* **stroke ranges**: a stroke command that is not finite or lies outside the heliostat's drive
  range is refused before it is sent (a second guard behind the controller's own check);
* **the stow gate**: once the client sent STOW ALL, every move and track command is refused
  (:class:`~helicalib.devices.protocols.FieldStowedError`) until it sends RESUME TRACKING.
  :attr:`lock` serialises heliostat commands' writes against a field command, so a stow sent
  from another thread never lands inside a command and no waiting command is sent after it;
  heliostat commands in flight at once (each on its own connection) hold it together
  (:meth:`GateLock.shared`), and a field command waits for them and goes before any command that
  asks after it.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np

from helicalib.devices.protocols import FieldStowedError
from helicalib.devices.registers import FieldCommand, HeliostatCommand
from helicalib.errors import PlantError

GATED = frozenset({HeliostatCommand.MOVE, HeliostatCommand.TRACK})
"""Commands the stow gate holds back (a stow command always passes)."""


class GateLock:
    """The stow gate's lock: ``with lock:`` alone (a field command), or :meth:`shared` by heliostat
    commands in flight together (each on its own connection). Those waiting to hold it alone go in
    the order they asked, and before any :meth:`shared` asked after them (a stow is never overtaken
    by commands asked after it)."""

    def __init__(self):
        self._cond = threading.Condition(threading.Lock())
        self._sharing = 0
        self._alone = False
        self._queue: deque[object] = deque()  # tickets of those waiting to hold it alone

    @contextmanager
    def shared(self) -> Iterator[None]:
        """Held with other heliostat commands, never with one holding it alone."""
        with self._cond:
            while self._alone or self._queue:
                self._cond.wait()
            self._sharing += 1
        try:
            yield
        finally:
            with self._cond:
                self._sharing -= 1
                if not self._sharing:
                    self._cond.notify_all()

    def __enter__(self) -> GateLock:
        ticket = object()
        with self._cond:
            self._queue.append(ticket)
            try:
                while self._alone or self._sharing or self._queue[0] is not ticket:
                    self._cond.wait()
            except BaseException:  # interrupted while waiting (KeyboardInterrupt): its ticket leaves the queue
                self._queue.remove(ticket)
                self._cond.notify_all()
                raise
            self._queue.popleft()
            self._alone = True
        return self

    def __exit__(self, *exc) -> None:
        with self._cond:
            self._alone = False
            self._cond.notify_all()


class CommandGuard:
    """The safety rules of one plant client.

    Parameters
    ----------
    armed : bool
        Allow writes.
    heliostat_ids : sequence of str, optional
        Ids by block index, for messages.
    stroke_limits_mm : array_like, shape (N, 2, 2), optional
        ``[i, actuator, (min, max)]`` of every heliostat's drive.
    """

    def __init__(self, armed: bool = False, heliostat_ids: Sequence[str] | None = None, stroke_limits_mm=None):
        self.armed = bool(armed)
        self.heliostat_ids = list(heliostat_ids) if heliostat_ids is not None else None
        self.stroke_limits_mm = None if stroke_limits_mm is None else np.asarray(stroke_limits_mm, dtype=float)
        self.lock = GateLock()
        """Held alone by a field command, shared by heliostat commands in flight together."""
        self._stowed = False

    @classmethod
    def from_config(cls, cfg, armed: bool = False) -> CommandGuard:
        """The guard of a field config's plant: its heliostat ids and every drive's stroke ranges."""
        limits = np.array([[a.stroke_range_mm for a in cfg.drive_of(h.id).actuators] for h in cfg.heliostats])
        return cls(armed=armed, heliostat_ids=[h.id for h in cfg.heliostats], stroke_limits_mm=limits)

    def label(self, index: int) -> str:
        """``heliostat 3 (H0004)``: how messages name a heliostat."""
        name = self.heliostat_ids[index] if self.heliostat_ids is not None and 0 <= index < len(self.heliostat_ids) else None
        return f"heliostat {index}" + (f" ({name})" if name else "")

    @staticmethod
    def check_index(index: int, count: int) -> None:
        """A :class:`PlantError` for a heliostat index outside the plant's ``count`` blocks."""
        if not 0 <= int(index) < count:
            raise PlantError(f"heliostat index {index} outside the plant's 0..{count - 1}")

    def refuse_unarmed(self, what: str) -> None:
        if not self.armed:
            raise PlantError(f"read-only mode: not writing {what} (start with --arm to command the plant)")

    def strokes(self, index: int, strokes_mm) -> np.ndarray:
        """``strokes_mm`` as a (2,) array, or a :class:`PlantError` for strokes not to be sent."""
        s = np.asarray(strokes_mm, dtype=float).reshape(2)
        if not np.all(np.isfinite(s)):
            raise PlantError(f"refusing to send non-finite strokes {s.tolist()} to {self.label(index)}")
        if self.stroke_limits_mm is not None:
            lim = self.stroke_limits_mm[index]
            if np.any(s < lim[:, 0]) or np.any(s > lim[:, 1]):
                raise PlantError(f"refusing to send strokes {np.round(s, 3).tolist()} mm to {self.label(index)}: "
                                 f"outside its stroke ranges {lim.tolist()} mm")
        return s

    def corrections(self, index: int, corrections_mm) -> np.ndarray:
        """``corrections_mm`` as a (2,) array, or a :class:`PlantError` for non-finite ones."""
        c = np.asarray(corrections_mm, dtype=float).reshape(2)
        if not np.all(np.isfinite(c)):
            raise PlantError(f"refusing to send non-finite tracking corrections {c.tolist()} to {self.label(index)}")
        return c

    # -- the stow gate (call with :attr:`lock` held) ----------------------------------------
    @property
    def stowed(self) -> bool:
        """Whether this client sent STOW ALL and no RESUME TRACKING since."""
        return self._stowed

    def gate(self, command: HeliostatCommand, what: str) -> None:
        """Refuse a move or track command while the field is stowed for wind."""
        if self._stowed and command in GATED:
            raise FieldStowedError(f"{what} not sent: the field is stowed for wind")

    def field_sent(self, command: FieldCommand) -> None:
        """Record a field command the plant took: STOW ALL closes the gate, RESUME TRACKING opens it."""
        if command == FieldCommand.STOW_ALL:
            self._stowed = True
        elif command == FieldCommand.RESUME_TRACKING:
            self._stowed = False
