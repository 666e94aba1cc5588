"""The visit's plant moves, each a status it waits on: to standby, onto the board, off it again.

Every move of a visit goes through :func:`move_and_hold`: the strokes are checked against the
drive's range and a move onto the board against the board's turn before anything is sent (a move
that fails either check is a refused :class:`~.status.MoveStatus`: nothing is sent), then the
command is sent and its status waited on until the heliostat holds, faults, is refused by the
plant or times out (:mod:`.status`). Beams rest only on the board or at its standby point.

- :func:`to_standby`: the beam to the board's standby point (off the board).
- :func:`approach_and_hold`: onto the board, each actuator arriving in the direction it moves
  while tracking, so that the gears' backlash sits as it does in tracking.
- :func:`leave_board`: back to standby, then the track command with the new corrections.
- :func:`take_turn` / :func:`end_turn`: the board's frame lock, held from the before frame until
  the beam is back at standby (one beam at a time lights a shared board).
"""

from __future__ import annotations

from collections.abc import Generator

import numpy as np

from helicalib.campaign.status import (AIM_OUT_OF_RANGE, BOARD_NOT_HELD, STROKE_OUT_OF_RANGE, MoveFailed, MoveStatus,
                                       refuse, start_move, wait)
from helicalib.campaign.visit_types import Left, VisitContext
from helicalib.errors import MeasurementError, PlantError
from helicalib.geometry.drives import strokes_in_range
from helicalib.geometry.heliostat import HeliostatModel, tracking_approach

APPROACH_LEAD_S = 300.0
"""Plant seconds ahead at which the tracking direction of each actuator is read off the model."""
APPROACH_MIN_MM = 0.01
"""A move shorter than this leaves the actuator's approach direction as it was."""
MOVE_POLL_S = 1.0
"""Plant seconds between polls of a visit's move (:func:`~.status.wait` polls every 2 s by default):
a move of a few millimetres holds within seconds, and half a poll is lost on average after each
of a visit's three or more moves, on a board whose band time is scarce (docs/benchmarks.md)."""


def in_range(ctx: VisitContext, strokes_mm: np.ndarray) -> bool:
    """Whether ``strokes_mm`` (2,) [mm] are finite and inside the drive's range."""
    s = np.asarray(strokes_mm, dtype=float).reshape(1, 2)
    return bool(np.all(np.isfinite(s)) and np.all(strokes_in_range(ctx.model.drives, s)))


def send_move(ctx: VisitContext, strokes_mm: np.ndarray, on_board: bool = True) -> MoveStatus:
    """Send one move command after the controller's own checks; returns its status (a refused one,
    :data:`~.status.STROKE_OUT_OF_RANGE` or :data:`~.status.BOARD_NOT_HELD`, when a check fails:
    nothing is sent). ``on_board``: the beam lands on the board (False: at standby or tracking)."""
    if not in_range(ctx, strokes_mm):
        return refuse(ctx.plant, ctx.index, ctx.heliostat_id, STROKE_OUT_OF_RANGE,
                      f"{ctx.heliostat_id}: strokes {np.round(strokes_mm, 1).tolist()} mm lie outside the drive's "
                      "range; not sent")
    if on_board and ctx.board is not None and ctx.board.lock_holder != ctx.heliostat_id:
        return refuse(ctx.plant, ctx.index, ctx.heliostat_id, BOARD_NOT_HELD,
                      f"{ctx.heliostat_id}: a move onto board {ctx.target.id} without its turn (another beam may be "
                      "measured there); not sent")
    ctx.on_board = bool(on_board)
    ctx.last_strokes_mm = np.asarray(strokes_mm, dtype=float)
    status = start_move(ctx.plant, ctx.index, ctx.heliostat_id, strokes_mm, ctx.settings.settle_timeout_s)
    ctx.approach = _approach_after(ctx.approach, ctx.held_mm, ctx.last_strokes_mm)
    return status


def move_and_hold(ctx: VisitContext, strokes_mm: np.ndarray, on_board: bool = True
                  ) -> Generator[float, None, tuple[float, float]]:
    """Command strokes (:func:`send_move`) and wait for "holding"; returns the read-back strokes,
    or raises the status's :class:`~.status.MoveFailed`."""
    read = yield from wait(send_move(ctx, strokes_mm, on_board), MOVE_POLL_S)
    ctx.held_mm = np.asarray(read, dtype=float)
    return read


def _approach_after(before: np.ndarray | None, held_mm: np.ndarray | None, target_mm: np.ndarray) -> np.ndarray:
    """Each actuator's last-motion direction after moving from ``held_mm`` to ``target_mm``: the
    move's sign where it moves, ``before`` where it stays (0 where that is not known either, e.g.
    the first move of a visit, whose start the controller did not hold)."""
    prev = np.zeros(2) if before is None else np.asarray(before, dtype=float)
    if held_mm is None:
        return np.zeros(2)
    move = np.asarray(target_mm, dtype=float) - np.asarray(held_mm, dtype=float)
    return np.where(np.abs(move) >= APPROACH_MIN_MM, np.sign(move), prev)


def tracking_direction(model: HeliostatModel, sun, aim_enu: np.ndarray, t_s: float) -> np.ndarray:
    """Direction (2,) of ±1 in which each actuator of the one heliostat of ``model`` moves while
    tracking ``aim_enu`` at ``t_s`` (the model's strokes now and :data:`APPROACH_LEAD_S` later, in
    one solve; +1 where it stands still or is unknown). ``sun(t_s)`` returns the sun vector first."""
    both = model.subset([0, 0]).strokes_for_aim(np.stack([sun(t_s)[0], sun(t_s + APPROACH_LEAD_S)[0]]),
                                                aim_enu).strokes_mm
    return tracking_approach(both[0], both[1])


def aim_strokes(ctx: VisitContext, aim_enu: np.ndarray, t_s: float, on_board: bool = True) -> np.ndarray:
    """The model's strokes for ``aim_enu`` at ``t_s``; on the board, for the tracking-direction
    arrival of :func:`approach_and_hold` (the model's dead bands). Outside the drive's range: a
    refused :class:`~.status.MoveFailed` (:data:`~.status.AIM_OUT_OF_RANGE`)."""
    sun_vec = ctx.sun(t_s)[0]
    approach = tracking_direction(ctx.model, ctx.sun, aim_enu, t_s) if on_board and ctx.model.has_dead_bands else None
    sol = ctx.model.strokes_for_aim(sun_vec, aim_enu, approach)
    if not bool(sol.in_range[0]):
        raise MoveFailed(AIM_OUT_OF_RANGE,
                         f"{ctx.heliostat_id}: the strokes for this aim point lie outside the drive's range now",
                         refused=True)
    return sol.strokes_mm[0]


def standby_enu(ctx: VisitContext) -> np.ndarray:
    """The board's standby point (ENU) [m]: where a beam waits off the board."""
    return ctx.target.uvw_to_enu(np.asarray(ctx.target.standby_uvw_m))


def to_standby(ctx: VisitContext) -> Generator[float, None, tuple[float, float]]:
    """The beam to the board's standby point at the model's strokes for it now, and hold there."""
    return (yield from move_and_hold(ctx, aim_strokes(ctx, standby_enu(ctx), ctx.now(), on_board=False),
                                     on_board=False))


def approach_and_hold(ctx: VisitContext, strokes_mm: np.ndarray, aim_enu: np.ndarray
                      ) -> Generator[float, None, tuple[float, float]]:
    """Move to ``strokes_mm`` so that each actuator's last motion runs ``approach_mm`` in its
    tracking direction, and hold; returns the read-back strokes.

    A heliostat's gears have backlash: where the mirror sits for given encoder strokes depends on
    the direction the actuator last moved. Tracking moves each actuator in one direction (the
    sun's), so a measurement taken after the same approach sees the mirror as tracking will, and
    the fitted model absorbs the backlash instead of taking it as noise. When the move from the
    present hold does not already end that way, the heliostat first stops ``approach_mm`` short.
    That intermediate point is used only if it is inside the stroke range and the model puts its
    beam on the board (beams rest only on the board or at standby); otherwise the move is direct.
    """
    strokes = np.asarray(strokes_mm, dtype=float)
    lead = float(ctx.settings.approach_mm)
    if lead > 0 and ctx.held_mm is not None:
        direction = tracking_direction(ctx.model, ctx.sun, aim_enu, ctx.now())
        if np.any((strokes - ctx.held_mm) * direction < lead):
            pre = strokes - direction * lead
            uv = ctx.model.spot_on_target(pre[None, :], ctx.sun(ctx.now())[0], ctx.target)[0]
            half = np.asarray(ctx.target.size_m, dtype=float) / 2.0
            if in_range(ctx, pre) and np.all(np.isfinite(uv)) and np.all(np.abs(uv) <= half):
                yield from move_and_hold(ctx, pre)
    return (yield from move_and_hold(ctx, strokes))


def take_turn(ctx: VisitContext) -> Generator[float, None, None]:
    """Wait for the board's turn (at once when the visit is alone); the beam waits at standby."""
    if ctx.board is not None:
        yield from ctx.board.acquire(ctx.heliostat_id)


def end_turn(ctx: VisitContext) -> None:
    """Give the board's turn to the next visit (the beam is off the board)."""
    if ctx.board is not None:
        ctx.board.release(ctx.heliostat_id)


def leave_board(ctx: VisitContext, stopping: bool = False) -> Generator[float, None, Left]:
    """Back to standby (beam off the board, never across the receiver), then to tracking.

    Returns a :class:`~.visit_types.Left`: what failed on the way back to tracking (the heliostat
    then stays where it is: holding at standby, or on the board if even that move failed; the
    campaign loop retries the return), or the corrections written with the track command. The track
    command is sent, not waited on here: the loop confirms that the heliostat reached tracking
    (:mod:`.tracking`). ``stopping``: the campaign stops; the heliostat leaves with the corrections
    last written."""
    try:
        try:
            if ctx.on_board:  # (a stopped visit's leg: its turn is still held, or waited for)
                yield from take_turn(ctx)
            yield from to_standby(ctx)
        except (MoveFailed, PlantError, MeasurementError):
            pass
        try:
            corrections = ctx.host.corrections(ctx, ctx.model, stopping)
        except Exception:  # noqa: BLE001 - keep the plant's corrections rather than write doubtful ones
            corrections = None
        corrections = None if corrections is None else np.asarray(corrections, dtype=float)
        try:  # None: the plant keeps the corrections it has
            ctx.plant.track(ctx.index, corrections)
        except PlantError as err:
            return Left(error=f"back to tracking failed: {err}", corrections_mm=corrections)
        return Left(corrections_mm=corrections)
    finally:
        # the next visit's turn once this beam is off the board: at standby, or sent to tracking when even
        # the standby move failed (if both failed it may rest on the board: the next visit's frames show it)
        end_turn(ctx)
