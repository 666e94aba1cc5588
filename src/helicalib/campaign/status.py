"""A plant move as a status one waits on: it completes, fails with a reason, or times out.

The habit of ophyd-async's ``AsyncStatus``, in the generator form the visit runs in: a
:class:`MoveStatus` is made when the move command is sent (:func:`start_move`), each
:meth:`MoveStatus.poll` reads the heliostat's plant state once, and :func:`wait` yields
:data:`POLL_S` plant seconds between polls until the status is done. The campaign loop steps
the visit at each of those waits, so the plant is read at the same plant times whether the
clock is virtual or the plant's own. A move the controller declines before sending it (a stroke
out of the drive's range, a board whose turn is another beam's) is a status that is done and
failed from the start (:func:`refuse`): nothing is sent and the plant is not read.

A status that fails carries a reason code, the one the store records for the visit's failed
attempt, and one line naming the heliostat; :func:`wait` raises it as a :class:`MoveFailed`:

- from the plant: :data:`PLANT_FAULT`, :data:`PLANT_REFUSED`, :data:`SETTLE_TIMEOUT`;
- declined by the controller (``refused``): :data:`STROKE_OUT_OF_RANGE`, :data:`BOARD_NOT_HELD`,
  and :data:`AIM_OUT_OF_RANGE` for an aim point the model cannot reach (no move is made).
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass

import numpy as np

from helicalib.devices.registers import HeliostatState
from helicalib.errors import HelicalibError

POLL_S = 2.0
"""Plant seconds between status polls while waiting for a heliostat to settle."""

PLANT_FAULT = "plant_fault"
"""The plant answered the move command with a fault."""
PLANT_REFUSED = "plant_refused"
"""The heliostat is stowed or offline: the plant did not move it."""
SETTLE_TIMEOUT = "settle_timeout"
"""Not holding after the drive's settle time (``calibration.settle_timeout_s``)."""
STROKE_OUT_OF_RANGE = "stroke_out_of_range"
"""Strokes outside the drive's range: the controller did not send them."""
BOARD_NOT_HELD = "board_not_held"
"""A move onto a board whose turn another beam holds: the controller did not send it."""
AIM_OUT_OF_RANGE = "aim_out_of_range"
"""The model's strokes for an aim point lie outside the drive's range: no move is made."""


class MoveFailed(HelicalibError):
    """A move that cannot complete: ``refused`` when the controller itself declined the command
    (nothing was sent), else the plant's fault, refusal or a timeout; the reason code is ``code``."""

    def __init__(self, code: str, message: str, refused: bool = False):
        super().__init__(message)
        self.code = code
        self.refused = refused


@dataclass
class MoveStatus:
    """One move command sent to one heliostat, followed until it holds.

    ``sequence`` is the command's sequence number (None: declined, never sent); ``timeout_s`` the
    plant seconds it may take to hold. After a poll that ends it, ``done`` is True and either
    ``strokes_mm`` holds the read-back strokes [mm] (success) or ``failure`` the
    :class:`MoveFailed` that says why.
    """

    plant: object
    index: int
    heliostat_id: str
    sequence: int | None
    timeout_s: float
    waited_s: float = 0.0
    done: bool = False
    strokes_mm: tuple[float, float] | None = None
    failure: MoveFailed | None = None

    @property
    def success(self) -> bool:
        return self.done and self.failure is None

    def poll(self) -> bool:
        """Read the heliostat's state once; returns whether the move is over (held or failed)."""
        st = self.plant.status(self.index)
        if st.sequence_done == self.sequence and st.state == HeliostatState.HOLDING:
            self.done, self.strokes_mm = True, st.strokes_mm
        elif st.sequence_done == self.sequence and st.state == HeliostatState.FAULT:
            self._fail(PLANT_FAULT, f"{self.heliostat_id}: plant fault code {st.fault} on a move command")
        elif st.state in (HeliostatState.STOWED, HeliostatState.OFFLINE) and st.sequence_done == self.sequence:
            self._fail(PLANT_REFUSED, f"{self.heliostat_id}: heliostat is {st.state.name.lower()}")
        elif self.waited_s >= self.timeout_s:
            self._fail(SETTLE_TIMEOUT, f"{self.heliostat_id}: not holding after {self.waited_s:.0f} s")
        return self.done

    def _fail(self, code: str, message: str) -> None:
        self.done, self.failure = True, MoveFailed(code, message)


def start_move(plant, index: int, heliostat_id: str, strokes_mm: np.ndarray, timeout_s: float) -> MoveStatus:
    """Send the move command (strokes [mm], actuators 1 and 2) and return its status."""
    seq = plant.move_to(index, np.asarray(strokes_mm, dtype=float))
    return MoveStatus(plant, index, heliostat_id, seq, float(timeout_s))


def refuse(plant, index: int, heliostat_id: str, code: str, message: str) -> MoveStatus:
    """A move the controller declines: nothing is sent; the status is done and failed with ``code``
    (a :class:`MoveFailed` that is ``refused``)."""
    return MoveStatus(plant, index, heliostat_id, None, 0.0, done=True,
                      failure=MoveFailed(code, message, refused=True))


def wait(status: MoveStatus, poll_s: float | None = None) -> Generator[float, None, tuple[float, float]]:
    """Poll ``status`` until it is done, yielding ``poll_s`` plant seconds (default :data:`POLL_S`)
    between polls; returns the read-back strokes, or raises the status's :class:`MoveFailed`."""
    poll_s = POLL_S if poll_s is None else poll_s
    while not status.done and not status.poll():
        yield poll_s
        status.waited_s += poll_s
    if status.failure is not None:
        raise status.failure
    return status.strokes_mm
