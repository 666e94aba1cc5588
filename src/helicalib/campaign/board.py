"""Several heliostats in one board visit: beams take turns on the board, the legs to and from it overlap.

A board serves up to ``spots_per_board`` heliostats at once (``--spots-per-board N|auto``). Each
runs its own visit, correction loop and record exactly as alone; what they share is the board's
**frame lock** (:class:`Board`): a visit holds it from its before frame, through all its
placements, until its beam is back at the standby point. The others meanwhile travel from
tracking to the standby point and wait there (beam off the board), or travel back to tracking
after their turn. So one beam at a time lights the board, and the board is never idle while a
heliostat slews from tracking to standby or back: those legs, tens of seconds each, run beside
the other visits' measurements.

**Why not several spots on the board at once.** Measured on the rendered simulator
(docs/campaign.md, "Several heliostats on one board"): a beam resting on the board does not stand
still. With its strokes held, its spot follows the sun (about 0.7 m a minute at 160 m) and the
wind's jitter, so between another heliostat's before and after frames (the arrival's move and
settling, 5–10 s) it moves by centimetres; the difference then holds that motion as a dipole
beside the arriving spot. Demo field, 10 heliostats on one board, 5 h: measured centres against
the truth 6.1 mm RMS alone, 48 mm RMS (102 mm max) with other spots resting on the board, and 27
of 32 such measurements refused by the vision's own checks. Taking turns keeps every measurement
as good as a lone visit's.

The lock is handed to waiting visits in the order they asked (no visit starves another).

**Whose beam may still cross the board.** A beam whose turn has ended travels from the standby
point back to tracking, and a visit on its way in travels from tracking to the standby point; on
some layouts that path crosses the board. The board remembers the plant index of every heliostat
in a visit on it and of the ones whose turn ended (:meth:`Board.movers`), so a visit whose before
frame held another beam can wait until none of them is moving any more (the plant's state) before
it takes its before frame again (:mod:`.measure`, :func:`~.measure.retake_before`).
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field

AUTO_SPOTS = 3
"""``--spots-per-board auto``: one heliostat measuring, up to two more on their way or waiting at
the standby point (at most three beams meet there; more adds little: the measured gain is in
docs/benchmarks.md)."""
LOCK_POLL_S = 1.0
"""Plant seconds a waiting visit lets pass before it asks for the board again."""
DEPARTED_KEPT = 8
"""Heliostats whose turn ended that a board remembers (the newest), until they stop moving."""


@dataclass
class Board:
    """One board's visits under way and its frame lock.

    ``cap``: at most this many visits at once. ``visitors``: the heliostats in a visit on it, in
    the order they came. ``lock_holder``: the visit whose beam may be on the board now.
    """

    target_id: str
    cap: int = 1
    visitors: list[str] = field(default_factory=list)
    lock_holder: str | None = None
    waiting: list[str] = field(default_factory=list)
    indices: dict[str, int] = field(default_factory=dict)
    """Plant index of each heliostat that came into a visit on this board (:meth:`arrive`)."""
    departed: list[str] = field(default_factory=list)
    """Heliostats whose turn on this board ended, oldest first, until the plant says they stopped
    moving (:meth:`settled`); at most :data:`DEPARTED_KEPT`."""

    @property
    def empty(self) -> bool:
        return not self.visitors

    @property
    def has_room(self) -> bool:
        return len(self.visitors) < self.cap

    def join(self, hid: str) -> None:
        if not self.has_room:
            raise ValueError(f"board {self.target_id}: {len(self.visitors)} visits under way, at most {self.cap}")
        self.visitors.append(hid)

    def leave(self, hid: str) -> None:
        """``hid``'s visit ended: its place is free; a lock it held goes to the next waiter."""
        if hid in self.visitors:
            self.visitors.remove(hid)
        if hid in self.waiting:
            self.waiting.remove(hid)
        self.release(hid)

    # ------------------------------------------------------------------ the frame lock
    def acquire(self, hid: str) -> Generator[float, None, None]:
        """Wait (yielding plant seconds) until ``hid`` holds the frame lock."""
        if self.lock_holder == hid or (self.lock_holder is None and not self.waiting):
            self.lock_holder = hid
            return
        if hid not in self.waiting:
            self.waiting.append(hid)
        try:
            while self.lock_holder != hid:
                if self.lock_holder is None and self.waiting[0] == hid:
                    self.lock_holder = hid
                    break
                yield LOCK_POLL_S
        finally:
            if hid in self.waiting:
                self.waiting.remove(hid)

    def release(self, hid: str) -> None:
        """``hid`` is done with the board: the lock goes to the longest waiter, if any. Its beam is
        still on its way back (to tracking), so the board remembers it (:attr:`departed`)."""
        if self.lock_holder == hid:
            self.lock_holder = self.waiting[0] if self.waiting else None
            if hid in self.departed:
                self.departed.remove(hid)
            self.departed.append(hid)
            del self.departed[:-DEPARTED_KEPT]

    # ------------------------------------------------------------------ beams that may cross it
    def arrive(self, hid: str, index: int) -> None:
        """``hid`` (plant index ``index``) starts a visit on this board."""
        self.indices[hid] = int(index)
        if hid in self.departed:
            self.departed.remove(hid)

    def movers(self, hid: str) -> list[tuple[str, int]]:
        """(id, plant index) of the heliostats other than ``hid`` whose beams may be travelling near
        the board: those whose turn ended (newest last) and the other visits under way."""
        out = [h for h in self.departed if h != hid]
        out += [h for h in self.visitors if h != hid and h not in out]
        return [(h, self.indices[h]) for h in out if h in self.indices]

    def settled(self, hid: str) -> None:
        """The plant says ``hid``'s beam has stopped moving: forget it as a departed one."""
        if hid in self.departed:
            self.departed.remove(hid)

    @property
    def measuring(self) -> str | None:
        """The heliostat whose turn it is (its beam may be on the board)."""
        return self.lock_holder
