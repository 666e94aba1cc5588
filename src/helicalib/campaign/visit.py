"""The visit of the 2022 paper (section 2.3.2): one heliostat on one target, as its procedure.

A visit is a generator: it talks only to device protocols (:class:`~helicalib.devices.protocols.Plant`,
the board's :class:`~helicalib.devices.protocols.SpotSensor`) and yields the plant seconds it
wants to wait, so one loop can interleave visits on several targets on a virtual clock, or drive
them from a live scheduler. A plant move is a :class:`~.status.MoveStatus` the visit waits on
(:func:`~.status.wait`): it completes with the read-back strokes, or fails with a reason code.

What the visit needs from the campaign (store an observation or a frame, refit the model, the
tracking corrections to leave with) it asks of a :class:`VisitHost`, which the campaign loop
implements (:mod:`.loop`): the store's writes and the fits happen there, in one place, and the
visit holds no store and no fit. A host call is a plain call, made at the point of the procedure
where the answer is needed (the loop has the whole state at hand; a request handed back at a
phase boundary would split the procedure in the middle of a placement). A host call that fails
raises inside the visit, which decides: a failed record of a measurement ends the visit as a
fault, and the beam still leaves the board. It returns a :class:`VisitOutcome`.

Steps: park the beam at the standby point → "before" reference from the visit's spot sensor (the
board's camera, :mod:`.sensor`) → on-target strokes from the current model, each actuator arriving in the direction it moves while tracking (so the gears' backlash
sits as it does in tracking; see :func:`approach_and_hold`) → wait for "holding" → "after"
frame(s) → spot → tracking error. Above the loop threshold:
the inverse model's stroke correction and again, up to ``max_iterations``. A spot not found (or
clipped) starts a search: aim points on the board opposite to where the spot was seen, then a
ring around the centre. Every attempt is recorded, valid or not, with its reason. At the end the
heliostat goes back to standby, then to tracking with its new corrections.

Several heliostats in one board visit (:mod:`.board`): each visit holds the board's frame lock
from its before frame until its beam is back at standby, so one beam at a time lights the board;
the other visits travel to the standby point and wait there meanwhile.

A before frame that held another beam (the previous heliostat's on its way back to tracking, a
visit's on its way to the standby point, a neighbouring board's): the reading says so
(``before_beam``). Before it is called invalid, :func:`retake_before` moves the beam to the standby
point, waits until the board's other heliostats have stopped moving (their plant state) and takes
the before frame again, up to :data:`MAX_BEFORE_RETAKES` times; the same after frames are judged
against each new one, so a clean frame makes the reading valid (its message says the before frame
was retaken, and why).

Safety: every stroke is checked against the drive's range before it is sent; beams rest only on
the board or at the standby point (search aims never leave the board); on any fault the
heliostat is returned to tracking.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from helicalib.calibration.correction import stroke_correction
from helicalib.campaign.board import Board
from helicalib.campaign.status import POLL_S, MoveFailed, start_move, wait
from helicalib.devices.protocols import Before, CaptureTimeError, Plant, SpotSensor
from helicalib.devices.registers import HeliostatState
from helicalib.errors import HelicalibError, MeasurementError, PlantError
from helicalib.geometry import optics
from helicalib.geometry.drives import strokes_in_range
from helicalib.geometry.heliostat import HeliostatModel, tracking_approach
from helicalib.store.records import Observation

SEARCHABLE = frozenset({"no_spot", "clipped", "low_contrast"})
"""Spot results after which the visit searches for the beam instead of giving up (DNI and cleanliness
are gated before a visit, so a faint spot most likely means a beam mostly off the board)."""
APPROACH_LEAD_S = 300.0
"""Plant seconds ahead at which the tracking direction of each actuator is read off the model."""
MAX_BEFORE_RETAKES = 3
"""A reading whose before frame held another beam takes the before frame again at most this many
times (each with the beam at the standby point); then it is refused (``ambient_change``)."""
RETAKE_WAIT_S = 4.0
"""Plant seconds at least between the beam reaching the standby point and a retaken before frame,
doubled at each further retake (4, 8, 16 s): a beam whose plant state the visit does not follow (a
neighbouring board's) passes meanwhile."""
BEAM_CLEAR_TIMEOUT_S = 60.0
"""At most this many plant seconds of waiting, per retake, for the board's other heliostats to stop
moving (:meth:`.board.Board.movers`); the before frame is taken again then even if one still moves
(the new frame is judged by the same check)."""
RETAKEN = "before frame retaken"
"""Words in the message of a reading whose before frame was taken again."""


@dataclass(frozen=True)
class VisitSettings:
    """What a visit needs from the field config."""

    loop_threshold_mrad: float
    max_iterations: int
    after_frames: int
    spot_method: str
    settle_timeout_s: float
    search_steps: int = 6
    reflectivity_clean: float = 0.93
    approach_mm: float = 1.0
    """Length of the last move of each actuator in its tracking direction, to take up backlash
    (0 = arrive from wherever the previous hold was)."""
    max_jitter_mrad: float = 2.0
    """With several after frames: their spot centres' RMS spread, as an angle seen from the
    heliostat, above which the measurement is refused ("jitter")."""
    max_capture_skew_s: float = 5.0
    """A frame whose capture time lies further than this outside the plant time around its grab
    is refused ("capture_time") [plant s]: its sun would be another sun."""

    @classmethod
    def from_config(cls, cfg) -> VisitSettings:
        c = cfg.calibration
        return cls(c.loop_threshold_mrad, c.max_iterations, c.after_frames, c.spot_method, c.settle_timeout_s,
                   reflectivity_clean=c.reflectivity_clean, approach_mm=c.approach_mm,
                   max_jitter_mrad=c.max_jitter_mrad, max_capture_skew_s=c.max_capture_skew_s)


@dataclass
class VisitContext:
    """Everything one visit touches. ``sun(t_s) -> (vector_enu (3,), azimuth_deg, elevation_deg, rising)``."""

    campaign_id: int
    visit_id: int
    heliostat_id: str
    index: int
    target: object
    sensor: SpotSensor
    plant: Plant
    now: Callable[[], float]
    sun: Callable[[float], tuple[np.ndarray, float, float, bool]]
    model: HeliostatModel
    settings: VisitSettings
    last_strokes_mm: np.ndarray | None = None
    held_mm: np.ndarray | None = None
    """Read-back strokes of the last hold [mm] (None before the first)."""
    approach: np.ndarray | None = None
    """Direction (2,) of each actuator's last motion (±1; 0 not known) after the last hold: where
    the backlash left the mirror. Recorded with each observation for the error model's dead bands."""
    before_path: str | None = None
    time_slack_s: Callable[[], float] | None = None
    """How far the plant time read by ``now`` may be off [plant s] (the clock's uncertainty),
    added to the capture-time tolerance."""
    board: Board | None = None
    """The board shared with other visits (its frame lock); None: the visit is alone."""
    on_board: bool = False
    """True while the beam was last commanded onto the board (False at standby or tracking)."""
    host: VisitHost | None = None
    """The campaign's side: the store's writes, the refits, the corrections to leave with."""


class VisitHost(Protocol):
    """What a visit asks of the campaign that runs it (the campaign loop implements it).

    Each call may raise (a database that cannot be written): the visit then records what it can
    and leaves the board."""

    def record(self, ctx: VisitContext, observation: Observation, frames: dict) -> int:
        """Store ``observation`` (its frames first: ``before_frame`` and/or ``after_frames``);
        returns its id."""

    def save_frame(self, ctx: VisitContext, data: bytes, iteration: int, capture_time_s: float, kind: str) -> str:
        """Store one frame of the visit; returns its stored path."""

    def refit(self, ctx: VisitContext, observation: Observation) -> HeliostatModel:
        """A valid observation of the visit's heliostat: add it to its points and refit; returns
        the model the visit goes on with."""

    def corrections(self, ctx: VisitContext, model: HeliostatModel, stopping: bool) -> np.ndarray | None:
        """The tracking stroke corrections [mm] to write with the track command as the visit
        leaves with ``model`` (``stopping``: the campaign stops; the corrections last written);
        None: the plant keeps its own."""


@dataclass(frozen=True)
class Left:
    """How a heliostat left the board: ``error`` is None when the plant took the command back to
    tracking (whether it reached state 1 is confirmed by the runner), else what failed;
    ``corrections_mm`` are the tracking corrections sent with that command (None: the plant keeps
    its own), written if ``error`` is None."""

    error: str | None = None
    corrections_mm: np.ndarray | None = None


@dataclass
class VisitOutcome:
    status: str                       # converged | not_converged | invalid | refused | fault
    reason: str
    iterations: int = 0
    valid_points: int = 0
    first_error_mrad: float | None = None
    final_error_mrad: float | None = None
    observations: list[Observation] = field(default_factory=list)
    model: HeliostatModel | None = None
    left: Left | None = None
    """How the heliostat left the board (None: the visit has not left it)."""


VisitAborted = MoveFailed
"""A visit cannot go on: ``refused`` when the controller itself declined a command (a stroke out
of the drive's range: nothing was sent), else a fault (the plant's fault, refusal or a timeout,
:class:`~.status.MoveStatus`); the reason code is ``code``."""


def _in_range(ctx: VisitContext, strokes_mm: np.ndarray) -> bool:
    s = np.asarray(strokes_mm, dtype=float).reshape(1, 2)
    return bool(np.all(np.isfinite(s)) and np.all(strokes_in_range(ctx.model.drives, s)))


def move_and_hold(ctx: VisitContext, strokes_mm: np.ndarray, on_board: bool = True
                  ) -> Generator[float, None, tuple[float, float]]:
    """Command strokes (after the range check) and wait for "holding"; returns the read-back strokes.
    ``on_board``: the beam lands on the board (False: at standby or tracking)."""
    if not _in_range(ctx, strokes_mm):
        raise VisitAborted("stroke_out_of_range",
                           f"{ctx.heliostat_id}: strokes {np.round(strokes_mm, 1).tolist()} mm lie outside the drive's range; not sent",
                           refused=True)
    if on_board and ctx.board is not None and ctx.board.lock_holder != ctx.heliostat_id:
        raise VisitAborted("board_not_held", f"{ctx.heliostat_id}: a move onto board {ctx.target.id} without its "
                                             "turn (another beam may be measured there); not sent", refused=True)
    ctx.on_board = bool(on_board)
    ctx.last_strokes_mm = np.asarray(strokes_mm, dtype=float)
    status = start_move(ctx.plant, ctx.index, ctx.heliostat_id, strokes_mm, ctx.settings.settle_timeout_s)
    ctx.approach = _approach_after(ctx.approach, ctx.held_mm, ctx.last_strokes_mm)
    read = yield from wait(status)
    ctx.held_mm = np.asarray(read, dtype=float)
    return read


APPROACH_MIN_MM = 0.01
"""A move shorter than this leaves the actuator's approach direction as it was."""


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
            if _in_range(ctx, pre) and np.all(np.isfinite(uv)) and np.all(np.abs(uv) <= half):
                yield from move_and_hold(ctx, pre)
    return (yield from move_and_hold(ctx, strokes))


def _aim_strokes(ctx: VisitContext, aim_enu: np.ndarray, t_s: float, on_board: bool = True) -> np.ndarray:
    """The model's strokes for ``aim_enu`` at ``t_s``; on the board, for the tracking-direction
    arrival of :func:`approach_and_hold` (the model's dead bands)."""
    sun_vec = ctx.sun(t_s)[0]
    approach = tracking_direction(ctx.model, ctx.sun, aim_enu, t_s) if on_board and ctx.model.has_dead_bands else None
    sol = ctx.model.strokes_for_aim(sun_vec, aim_enu, approach)
    if not bool(sol.in_range[0]):
        raise VisitAborted("aim_out_of_range", f"{ctx.heliostat_id}: the strokes for this aim point lie outside the drive's range now",
                           refused=True)
    return sol.strokes_mm[0]


def _lock(ctx: VisitContext) -> Generator[float, None, None]:
    """Wait for the board's turn (at once when the visit is alone); the beam waits at standby."""
    if ctx.board is not None:
        yield from ctx.board.acquire(ctx.heliostat_id)


def _unlock(ctx: VisitContext) -> None:
    if ctx.board is not None:
        ctx.board.release(ctx.heliostat_id)


def _standby(ctx: VisitContext) -> np.ndarray:
    return ctx.target.uvw_to_enu(np.asarray(ctx.target.standby_uvw_m))


def run_visit(ctx: VisitContext) -> Generator[float, None, VisitOutcome]:
    """The visit as a generator of plant-second waits; returns its :class:`VisitOutcome`."""
    out = VisitOutcome(status="invalid", reason="not started", model=ctx.model)
    target = ctx.target
    centre = np.asarray(target.center_enu_m, dtype=float)
    if ctx.board is not None:  # the board follows where this beam travels (another visit's retake waits for it)
        ctx.board.arrive(ctx.heliostat_id, ctx.index)
    try:
        yield from move_and_hold(ctx, _aim_strokes(ctx, _standby(ctx), ctx.now(), on_board=False), on_board=False)
        yield from _lock(ctx)  # the board's turn: every other beam is off it until this one is back at standby
        before = ctx.sensor.before(ctx)
        if before.data is not None:  # saved once: every observation of the visit points to it
            ctx.before_path = ctx.host.save_frame(ctx, before.data, 0, before.capture_time_s, "before")
        aim = centre.copy()
        strokes = _aim_strokes(ctx, aim, ctx.now())
        search = _search_aims(target, ctx.settings.search_steps)
        attempt, placements, searches = 0, 0, 0
        while True:
            read = yield from approach_and_hold(ctx, strokes, aim)
            obs, before = yield from _measure(ctx, before, strokes, read, aim, attempt)
            out.observations.append(obs)
            attempt += 1
            if not obs.valid:
                nxt = _next_search_aim(target, obs, aim, search) if obs.reason in SEARCHABLE else None
                if nxt is not None and searches < ctx.settings.search_steps:
                    searches += 1
                    aim = nxt
                    strokes = _aim_strokes(ctx, aim, ctx.now())
                    continue
                out.status = "invalid"
                out.reason = obs.reason if not searches else f"{obs.reason} (after {searches} search placements)"
                break
            placements += 1
            out.valid_points += 1
            if out.first_error_mrad is None:
                out.first_error_mrad = obs.error_mrad
            out.final_error_mrad = obs.error_mrad
            ctx.model = ctx.host.refit(ctx, obs)
            out.model = ctx.model
            if obs.error_mrad < ctx.settings.loop_threshold_mrad:
                out.status, out.reason = "converged", "ok"
                break
            if placements >= ctx.settings.max_iterations:
                out.status, out.reason = "not_converged", f"still {obs.error_mrad:.2f} mrad after {placements} placements"
                break
            # the paper's inverse model: observed normal error carried into the strokes for the board centre
            aim = centre.copy()
            corr = stroke_correction(ctx.model, np.asarray([read]), ctx.sun(obs.capture_time_s)[0],
                                     np.asarray([obs.spot_enu_m]), aim, ctx.sun(ctx.now())[0])
            if not bool(corr.in_range[0]):
                out.status, out.reason = "refused", "the corrected strokes lie outside the drive's range"
                break
            strokes = corr.strokes_mm[0]
        out.iterations = placements
    except VisitAborted as err:
        out.status, out.reason = ("refused" if err.refused else "fault"), err.code
        _record_failure(ctx, err.code, str(err))
    except (PlantError, MeasurementError) as err:
        code = "plant_error" if isinstance(err, PlantError) else getattr(err, "reason", "camera_error")
        out.status, out.reason = "fault", code
        _record_failure(ctx, code, str(err), frame=err.frame if isinstance(err, CaptureTimeError) else None)
    except Exception as err:  # noqa: BLE001 - e.g. a full disk: the beam must still leave the board
        code = f"error_{type(err).__name__}"
        out.status, out.reason = "fault", code
        _record_failure(ctx, code, f"{ctx.heliostat_id}: {type(err).__name__}: {err}")
    out.left = yield from leave_board(ctx)
    return out


def _measure(ctx, before: Before, strokes_cmd, strokes_read, aim, iteration):
    """One "after" measurement at the held strokes; always returns an Observation (recorded) and the
    before reference the visit goes on with (a new one when it was taken again: :func:`retake_before`)."""
    approach = ctx.approach  # of this placement (a retake moves the beam to standby and back)
    reading = yield from ctx.sensor.after(ctx, before)
    if reading.before_beam:
        before, reading = yield from retake_before(ctx, before, reading, iteration)
    capture_s = reading.capture_time_s
    sun_vec, az, el, rising = ctx.sun(capture_s)
    weather = _safe(ctx.plant.weather)
    status = _safe(lambda: ctx.plant.status(ctx.index))
    base = dict(
        campaign_id=ctx.campaign_id, heliostat_id=ctx.heliostat_id, target_id=ctx.target.id,
        visit_id=ctx.visit_id, iteration=iteration, capture_time_s=float(capture_s),
        strokes_cmd_mm=tuple(float(x) for x in strokes_cmd),
        strokes_read_mm=None if strokes_read is None else tuple(float(x) for x in strokes_read),
        approach=None if approach is None else tuple(int(x) for x in approach),
        sun_enu=tuple(float(x) for x in sun_vec), sun_azimuth_deg=float(az), sun_elevation_deg=float(el),
        sun_rising=bool(rising), before_frame_path=ctx.before_path,
        wind_ms=getattr(weather, "wind_ms", None), wind_direction_deg=getattr(weather, "wind_direction_deg", None),
        dni_wm2=getattr(weather, "dni_wm2", None), temperature_c=getattr(weather, "temperature_c", None),
        cleanliness=getattr(status, "cleanliness", None),
    )
    extra = {}
    if reading.spot_px is not None:
        extra.update(spot_x_px=reading.spot_px[0], spot_y_px=reading.spot_px[1])
    extra.update(spot_area_px=reading.spot_area_px, threshold=reading.threshold)
    if reading.offset_m is not None:
        spot_enu = ctx.target.uvw_to_enu(np.asarray(reading.offset_m, dtype=float))
        aim_uvw = ctx.target.enu_to_uvw(aim)
        extra.update(offset_u_m=float(reading.offset_m[0] - aim_uvw[0]),
                     offset_v_m=float(reading.offset_m[1] - aim_uvw[1]),
                     spot_enu_m=tuple(float(x) for x in spot_enu))
    if reading.valid:
        held = np.asarray([strokes_read if strokes_read is not None else strokes_cmd], dtype=float)
        predicted_uv = ctx.model.spot_on_target(held, sun_vec, ctx.target, approach)[0]
        predicted = ctx.target.uvw_to_enu(predicted_uv)
        extra["error_mrad"] = float(optics.tracking_error_mrad(np.asarray(extra["spot_enu_m"]), predicted,
                                                               ctx.model.pivots_enu[0]))
        clean = ctx.sensor.cleanliness(ctx, before, reading, held[0], weather, sun_vec)
        if clean is not None:
            extra["cleanliness_measured"] = clean
    obs = Observation(valid=bool(reading.valid), reason=reading.reason, message=reading.message, **base, **extra)
    obs_id = ctx.host.record(ctx, obs, {"before_frame": _before_data(ctx, before), "after_frames": list(reading.frames)})
    return _with_id(obs, obs_id), before


def retake_before(ctx: VisitContext, before: Before, reading, iteration: int):
    """A reading whose before frame held another beam, judged again against new before frames.

    Up to :data:`MAX_BEFORE_RETAKES` times: the beam to the standby point (the board's turn is kept),
    a wait of at least :data:`RETAKE_WAIT_S` (doubled each time) and until none of the board's other
    heliostats is moving by the plant's state (at most :data:`BEAM_CLEAR_TIMEOUT_S`), a new before
    frame (saved; the visit's later placements use it), and the same after frames judged against it:
    a clean frame gives the reading the after frames hold; one that holds a beam again is retaken.
    Returns ``(before, reading)``; the reading's message says how many times and why. A frame that
    cannot be had ends the retakes (the refusal stands, with that said)."""
    retake = ctx.sensor.retake
    n, waited_for, still = 0, [], []
    while reading.before_beam and n < MAX_BEFORE_RETAKES:
        n += 1
        yield from move_and_hold(ctx, _aim_strokes(ctx, _standby(ctx), ctx.now(), on_board=False), on_board=False)
        seen, still = yield from _beams_gone(ctx, RETAKE_WAIT_S * 2 ** (n - 1))
        waited_for += [h for h in seen if h not in waited_for]
        try:
            before, reading = retake(ctx, before, reading)
        except MeasurementError as err:
            return before, replace(reading, message=f"{reading.message.rstrip('.')} [{RETAKEN} {n - 1} time(s); "
                                                    f"then no before frame could be had: {err}].")
        if before.data is not None:
            ctx.before_path = ctx.host.save_frame(ctx, before.data, iteration, before.capture_time_s, "before")
    if n == 0:
        return before, reading
    times = f"{n} time{'s' if n > 1 else ''}"
    waits = f"; waited for {', '.join(waited_for)} to stop moving" if waited_for else ""
    if reading.before_beam:
        note = (f"{RETAKEN} {times} (the limit), another beam on the board in each{waits}"
                + (f"; {', '.join(still)} still moving after {BEAM_CLEAR_TIMEOUT_S:.0f} s" if still else ""))
    else:
        note = f"{RETAKEN} {times}: another beam lay on the board in the first{waits}"
    return before, replace(reading, message=f"{reading.message.rstrip('.')} [{note}].")


def _beams_gone(ctx: VisitContext, least_s: float) -> Generator[float, None, tuple[list[str], list[str]]]:
    """Wait at least ``least_s`` plant seconds and until none of the board's other heliostats (whose
    turn ended, or on their way in) is moving by the plant's state, at most
    :data:`BEAM_CLEAR_TIMEOUT_S`; returns the ids seen moving and those still moving at the end
    (none: the beams have left)."""
    waited, seen = 0.0, []
    while True:
        moving = _moving(ctx)
        seen += [h for h in moving if h not in seen]
        if waited >= least_s and (not moving or waited >= BEAM_CLEAR_TIMEOUT_S):
            return seen, moving
        yield POLL_S
        waited += POLL_S


def _moving(ctx: VisitContext) -> list[str]:
    """The board's other heliostats the plant says are moving (one unreadable is not waited for:
    the new before frame is judged anyway)."""
    if ctx.board is None:
        return []
    out = []
    for hid, index in ctx.board.movers(ctx.heliostat_id):
        try:
            state = ctx.plant.status(index).state
        except PlantError:
            continue
        if state == HeliostatState.MOVING:
            out.append(hid)
        else:
            ctx.board.settled(hid)
    return out


def _before_data(ctx: VisitContext, before: Before):
    """The before frame's bytes, unless it was saved already (then its path is in the observation)."""
    return None if ctx.before_path is not None else before.data


def _with_id(obs: Observation, obs_id: int) -> Observation:
    return replace(obs, id=obs_id)


def _safe(fn):
    try:
        return fn()
    except HelicalibError:
        return None


def _search_aims(target, steps: int) -> list[np.ndarray]:
    """Aim points (target frame u, v) on a ring inside the board, to find a beam that missed it."""
    w, h = target.size_m
    r = 0.35 * min(w, h)
    angles = np.linspace(0, 2 * np.pi, steps, endpoint=False)
    return [np.array([r * np.cos(a), r * np.sin(a)]) for a in angles]


def _next_search_aim(target, obs: Observation, aim_enu: np.ndarray, search: list[np.ndarray]) -> np.ndarray | None:
    """The next aim point (ENU) of a search, always on the board; None when there is none left.

    Led by the part of the spot it sees: a clipped spot seen ``seen`` metres from the current aim
    means the beam lands about there, so the next aim is the current one minus ``seen`` (clipped to
    the inner 80 % of the board). Without a usable centre (no spot, or an aim that would not move),
    the next point of the ring.
    """
    w, h = target.size_m
    lim = np.array([0.4 * w, 0.4 * h])
    if obs.reason == "clipped" and obs.offset_u_m is not None:
        current = target.enu_to_uvw(aim_enu)[:2]
        uv = np.clip(current - np.array([obs.offset_u_m, obs.offset_v_m]), -lim, lim)
        if np.linalg.norm(uv - current) > 0.05 * min(w, h):
            return target.uvw_to_enu(uv)
    return target.uvw_to_enu(search.pop(0)) if search else None


def _record_failure(ctx: VisitContext, code: str, message: str, frame=None) -> None:
    t = ctx.now()
    sun_vec, az, el, rising = ctx.sun(t)
    obs = Observation(campaign_id=ctx.campaign_id, heliostat_id=ctx.heliostat_id, target_id=ctx.target.id,
                      visit_id=ctx.visit_id, iteration=-1, capture_time_s=float(t),
                      strokes_cmd_mm=tuple(float(x) for x in (ctx.last_strokes_mm if ctx.last_strokes_mm is not None
                                                              else (float("nan"),) * 2)),
                      strokes_read_mm=None, sun_enu=tuple(float(x) for x in sun_vec), sun_azimuth_deg=float(az),
                      sun_elevation_deg=float(el), sun_rising=bool(rising), valid=False, reason=code, message=message,
                      before_frame_path=ctx.before_path)
    try:
        ctx.host.record(ctx, obs, {} if frame is None else {"before_frame": frame.data})
    except Exception:  # noqa: BLE001 - recording the failure must not stop the beam leaving the board
        pass


def leave_board(ctx: VisitContext, stopping: bool = False) -> Generator[float, None, Left]:
    """Back to standby (beam off the board, never across the receiver), then to tracking.

    Returns a :class:`Left`: what failed on the way back to tracking (the heliostat then stays
    where it is: holding at standby, or on the board if even that move failed; the runner retries
    the return), or the corrections written with the track command. ``stopping``: the campaign
    stops; the heliostat leaves with the corrections last written."""
    try:
        try:
            if ctx.on_board:  # (a stopped visit's leg: its turn is still held, or waited for)
                yield from _lock(ctx)
            standby = _standby(ctx)
            sol = ctx.model.strokes_for_aim(ctx.sun(ctx.now())[0], standby)
            if bool(sol.in_range[0]):
                yield from move_and_hold(ctx, sol.strokes_mm[0], on_board=False)
        except (VisitAborted, PlantError, MeasurementError):
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
        _unlock(ctx)
