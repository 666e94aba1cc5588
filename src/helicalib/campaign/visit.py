"""The visit of the 2022 paper (section 2.3.2): one heliostat on one target, as its procedure.

:func:`run_visit` is the procedure, step by step:

1. **standby**: the beam to the board's standby point (:func:`~.moves.to_standby`), and the
   board's turn (:func:`~.moves.take_turn`): one beam at a time lights a shared board;
2. **before frame**: the reference with the beam off the board (:func:`~.measure.take_before`);
3. **approach and hold**: the model's strokes for the board's centre, each actuator arriving in
   the direction it moves while tracking, so that the gears' backlash sits as it does in tracking
   (:func:`~.moves.approach_and_hold`);
4. **after frames and measure**: the spot, the observed beam and the tracking error [mrad], every
   attempt recorded, valid or not, with its reason (:func:`~.measure.measure`; a before frame that
   held another beam is taken again first, :func:`~.measure.retake_before`);
5. **search**: a spot not found (or clipped, or faint) sends the beam to aim points on the board
   opposite to where the spot was seen, then on a ring around the centre (:func:`search`);
6. **correct and again**: a valid point refits the model (:func:`learn`); below the loop
   threshold the visit has converged; else the inverse model's stroke correction for the board's
   centre (:func:`correct`) and again, up to ``max_iterations`` placements;
7. **leave**: back to standby, then to tracking with the new corrections
   (:func:`~.moves.leave_board`), however the visit ended.

A visit is a generator: it talks only to device protocols (:class:`~helicalib.devices.protocols.Plant`,
the board's :class:`~helicalib.devices.protocols.SpotSensor`) and yields the plant seconds it
wants to wait, so one loop can interleave visits on several targets on a virtual clock, or drive
them from a live scheduler. A plant move is a :class:`~.status.MoveStatus` the visit waits on: it
completes with the read-back strokes, or fails with a reason code (:mod:`.status`).

What the visit needs from the campaign (store an observation or a frame, refit the model, the
tracking corrections to leave with) it asks of a :class:`~.visit_types.VisitHost`, which the
campaign loop implements (:mod:`.loop`): the store's writes and the fits happen there, in one
place, and the visit holds no store and no fit. A host call is a plain call, made at the point of
the procedure where the answer is needed. A host call that fails raises inside the visit, which
ends as a fault; the beam still leaves the board.

Safety: every stroke is checked against the drive's range before it is sent; beams rest only on
the board or at the standby point (search aims never leave the board); on any failure the
heliostat leaves the board via standby and is returned to tracking.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass

import numpy as np

from helicalib.calibration.correction import stroke_correction
from helicalib.campaign.measure import measure, record_failure, take_before
from helicalib.campaign.moves import aim_strokes, approach_and_hold, leave_board, take_turn, to_standby
from helicalib.campaign.status import MoveFailed
from helicalib.campaign.visit_types import VisitContext, VisitOutcome
from helicalib.devices.protocols import CaptureTimeError
from helicalib.errors import MeasurementError, PlantError
from helicalib.store.records import Observation

SEARCHABLE = frozenset({"no_spot", "clipped", "low_contrast"})
"""Spot results after which the visit searches for the beam instead of giving up (DNI and cleanliness
are gated before a visit, so a faint spot most likely means a beam mostly off the board)."""


@dataclass
class Placement:
    """Where the visit puts the beam next, and how often it has.

    ``aim_enu`` (3,) [m] and the strokes for it ``strokes_mm`` (2,) [mm]; ``ring`` the search aim
    points (target frame u, v [m]) not yet used; ``attempt`` the measurements taken (the next
    observation's iteration), ``placements`` those that were valid, ``searches`` the search
    placements made."""

    aim_enu: np.ndarray
    strokes_mm: np.ndarray
    ring: list[np.ndarray]
    attempt: int = 0
    placements: int = 0
    searches: int = 0

    def measured(self, out: VisitOutcome, obs: Observation) -> None:
        """Count a measurement (recorded as ``obs``) and keep it in the visit's outcome."""
        out.observations.append(obs)
        self.attempt += 1
        if obs.valid:
            self.placements += 1


def run_visit(ctx: VisitContext) -> Generator[float, None, VisitOutcome]:
    """The visit as a generator of plant-second waits; returns its :class:`~.visit_types.VisitOutcome`."""
    out = VisitOutcome(status="invalid", reason="not started", model=ctx.model)
    if ctx.board is not None:  # the board follows where this beam travels (another visit's retake waits for it)
        ctx.board.arrive(ctx.heliostat_id, ctx.index)
    try:
        yield from to_standby(ctx)
        yield from take_turn(ctx)  # every other beam is off the board until this one is back at standby
        before = yield from take_before(ctx)
        p = first_placement(ctx)
        while True:
            read = yield from approach_and_hold(ctx, p.strokes_mm, p.aim_enu)
            obs, before = yield from measure(ctx, before, p.strokes_mm, read, p.aim_enu, p.attempt)
            p.measured(out, obs)
            if not obs.valid:
                if search(ctx, p, obs):
                    continue
                out.end("invalid", obs.reason if not p.searches else
                        f"{obs.reason} (after {p.searches} search placements)")
                break
            learn(ctx, out, obs)
            if obs.error_mrad < ctx.settings.loop_threshold_mrad:
                out.end("converged", "ok")
                break
            if in_band(ctx, obs):
                lo, hi = ctx.settings.band_deg
                out.end("not_converged", f"band point: {obs.error_mrad:.2f} mrad, the {lo:g}–{hi:g}° band's time goes "
                        "to the next heliostat")
                break
            if p.placements >= ctx.settings.max_iterations:
                out.end("not_converged", f"still {obs.error_mrad:.2f} mrad after {p.placements} placements")
                break
            # the read-back of the hold measured (an exposure retake holds again)
            if not correct(ctx, p, obs, obs.strokes_read_mm if obs.strokes_read_mm is not None else read):
                out.end("refused", "the corrected strokes lie outside the drive's range")
                break
        out.iterations = p.placements
    except Exception as err:  # noqa: BLE001 - e.g. a full disk: the beam must still leave the board
        failed(ctx, out, err)
    out.left = yield from leave_board(ctx)
    return out


def first_placement(ctx: VisitContext) -> Placement:
    """The first placement: the model's strokes for the board's centre now, and the search ring."""
    aim = _centre(ctx)
    return Placement(aim, aim_strokes(ctx, aim, ctx.now()), _search_aims(ctx.target, ctx.settings.search_steps))


def search(ctx: VisitContext, p: Placement, obs: Observation) -> bool:
    """No usable spot: move ``p`` to the next search placement and return True, when the spot's
    reason is one to search for (:data:`SEARCHABLE`), an aim point is left and the search has steps
    left (``search_steps``); False: the visit ends invalid."""
    nxt = _next_search_aim(ctx.target, obs, p.aim_enu, p.ring) if obs.reason in SEARCHABLE else None
    if nxt is None or p.searches >= ctx.settings.search_steps:
        return False
    p.searches += 1
    p.aim_enu = nxt
    p.strokes_mm = aim_strokes(ctx, p.aim_enu, ctx.now())
    return True


def learn(ctx: VisitContext, out: VisitOutcome, obs: Observation) -> None:
    """A valid point: its error kept in the outcome, and the model the visit goes on with refit
    with it (the host adds it to the heliostat's points and fits)."""
    out.valid_points += 1
    if out.first_error_mrad is None:
        out.first_error_mrad = obs.error_mrad
    out.final_error_mrad = obs.error_mrad
    ctx.model = ctx.host.refit(ctx, obs)
    out.model = ctx.model


def in_band(ctx: VisitContext, obs: Observation) -> bool:
    """Whether ``obs`` was taken while the sun was in the acceptance's low band (``band_deg``)."""
    band = ctx.settings.band_deg
    return band is not None and band[0] <= obs.sun_elevation_deg <= band[1]


def correct(ctx: VisitContext, p: Placement, obs: Observation, read) -> bool:
    """The paper's inverse model: the observed normal error carried into the strokes for the
    board's centre; sets ``p`` to them and returns True, or False when they lie outside the drive's
    range (the visit is refused)."""
    p.aim_enu = _centre(ctx)
    corr = stroke_correction(ctx.model, np.asarray([read]), ctx.sun(obs.capture_time_s)[0],
                             np.asarray([obs.spot_enu_m]), p.aim_enu, ctx.sun(ctx.now())[0])
    if not bool(corr.in_range[0]):
        return False
    p.strokes_mm = corr.strokes_mm[0]
    return True


def failed(ctx: VisitContext, out: VisitOutcome, err: Exception) -> None:
    """A failure ends the visit, recorded as a failed attempt with its reason code: a move the
    controller declined is ``refused``, anything else a ``fault`` (a move's status, the plant, the
    camera with the frame that showed it, or any other error, e.g. a database that cannot be
    written)."""
    if isinstance(err, MoveFailed):
        out.end("refused" if err.refused else "fault", err.code)
        record_failure(ctx, err.code, str(err))
    elif isinstance(err, (PlantError, MeasurementError)):
        code = "plant_error" if isinstance(err, PlantError) else getattr(err, "reason", "camera_error")
        out.end("fault", code)
        record_failure(ctx, code, str(err), frame=err.frame if isinstance(err, CaptureTimeError) else None)
    else:
        code = f"error_{type(err).__name__}"
        out.end("fault", code)
        record_failure(ctx, code, f"{ctx.heliostat_id}: {type(err).__name__}: {err}")


def _centre(ctx: VisitContext) -> np.ndarray:
    return np.asarray(ctx.target.center_enu_m, dtype=float).copy()


def _search_aims(target, steps: int) -> list[np.ndarray]:
    """Aim points (target frame u, v) on a ring inside the board, to find a beam that missed it."""
    w, h = target.size_m
    r = 0.35 * min(w, h)
    angles = np.linspace(0, 2 * np.pi, steps, endpoint=False)
    return [np.array([r * np.cos(a), r * np.sin(a)]) for a in angles]


def _next_search_aim(target, obs: Observation, aim_enu: np.ndarray, search: list[np.ndarray]) -> np.ndarray | None:
    """The next aim point (ENU) of a search, always on the board; None when there is none left.

    Led by the part of the spot it sees: a clipped spot whose visible part lies ``seen`` metres from
    the current aim (an observation's offsets are from its aim point) means the beam misses its aim
    by about ``seen``, so the next aim is ``-seen`` from the board's centre, where that puts the spot
    (clipped to the inner 80 % of the board); from an aim off the centre (a ring point, an earlier
    search aim) too, so a search never chases the spot toward the rim. Without a usable centre (no
    spot, or an aim that would not move), the next point of the ring.
    """
    w, h = target.size_m
    lim = np.array([0.4 * w, 0.4 * h])
    if obs.reason == "clipped" and obs.offset_u_m is not None:
        current = target.enu_to_uvw(aim_enu)[:2]
        uv = np.clip(-np.array([obs.offset_u_m, obs.offset_v_m]), -lim, lim)
        if np.linalg.norm(uv - current) > 0.05 * min(w, h):
            return target.uvw_to_enu(uv)
    return target.uvw_to_enu(search.pop(0)) if search else None
