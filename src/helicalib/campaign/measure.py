"""One measurement of a visit at a held placement, recorded: the after frames, the spot, the error.

:func:`measure` asks the visit's spot sensor for the "after" reading against the before
reference, takes the sun at the frame's capture time and the plant's weather and cleanliness,
and, for a valid reading, the tracking error [mrad] between the spot seen and the spot the model
predicts for the held strokes. In a live run (a camera with a frame worker) the weather and
cleanliness are read while the beam holds, just before the after frames, so that the reading's
way to the next command holds no plant request of theirs (read again after a retake). Every attempt is recorded through the visit's host, valid or not,
with its reason; :func:`record_failure` records a failed attempt (a move that failed, a camera
that did not answer) the same way.

A before frame that held another beam (the previous heliostat's on its way back to tracking, a
visit's on its way to the standby point, a neighbouring board's): the reading says so
(``before_beam``). Before it is called invalid, :func:`retake_before` moves the beam to the standby
point, waits until the board's other heliostats have stopped moving (their plant state) and takes
the before frame again, up to :data:`MAX_BEFORE_RETAKES` times; the same after frames are judged
against each new one, so a clean frame makes the reading valid (its message says the before frame
was retaken, and why).

A reading refused as too bright (``saturated``, or ``clipped`` by a saturated plateau) or too faint
(``low_contrast``) by a camera that sets its exposure: :func:`retake_exposure` takes the before
frame (beam at standby) and the after frames (the beam back at the same strokes, by the same
approach) again at the exposure the sensor offers, up to
:data:`~.exposure.MAX_EXPOSURE_RETAKES` times; the observation is the last reading's, at its hold.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import replace

import numpy as np

from helicalib.campaign import status as move_status
from helicalib.campaign.exposure import MAX_EXPOSURE_RETAKES
from helicalib.campaign.moves import approach_and_hold, to_standby
from helicalib.campaign.visit_types import VisitContext
from helicalib.devices.protocols import Before
from helicalib.devices.registers import HeliostatState
from helicalib.errors import HelicalibError, MeasurementError, PlantError
from helicalib.geometry import optics
from helicalib.store.records import Observation

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
EXPOSED = "frames retaken at"
"""Words in the message of a reading taken again at another exposure."""


def take_before(ctx: VisitContext) -> Generator[float, None, Before]:
    """The visit's "before" reference from its spot sensor (the beam at standby); its frame is
    saved once, and every observation of the visit points to it. A sensor that waits for its frame
    off the loop's thread (``before_waiting``: a live run's camera) yields meanwhile."""
    waiting = getattr(ctx.sensor, "before_waiting", None)
    before = (yield from waiting(ctx)) if waiting is not None else ctx.sensor.before(ctx)
    if before.data is not None:
        ctx.before_path = ctx.host.save_frame(ctx, before.data, 0, before.capture_time_s, "before")
    return before


def measure(ctx: VisitContext, before: Before, strokes_cmd, strokes_read, aim, iteration: int
            ) -> Generator[float, None, tuple[Observation, Before]]:
    """One "after" measurement at the held strokes; always returns an Observation (recorded) and the
    before reference the visit goes on with (a new one when it was taken again: :func:`retake_before`)."""
    early = _plant_reads(ctx) if getattr(ctx.sensor, "frames", None) is not None else None
    reading = first = yield from ctx.sensor.after(ctx, before)
    if reading.before_beam:
        before, reading = yield from retake_before(ctx, before, reading, iteration)
    if not reading.valid and getattr(ctx.sensor, "exposure_retake", None) is not None:
        before, reading, held = yield from retake_exposure(ctx, before, reading, strokes_cmd, aim, iteration)
        strokes_read = strokes_read if held is None else held
    approach = ctx.approach  # of this placement's last hold (a retake moves the beam to standby and back)
    capture_s = reading.capture_time_s
    sun_vec, az, el, rising = ctx.sun(capture_s)
    weather, status = early if early is not None and reading is first else _plant_reads(ctx)
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
        exposure_ms=getattr(before.state, "exposure_ms", None),
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
    return replace(obs, id=obs_id), before


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
        yield from to_standby(ctx)
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


def retake_exposure(ctx: VisitContext, before: Before, reading, strokes_cmd, aim, iteration: int):
    """A reading refused as too bright or too faint, taken again at the exposure the sensor offers
    (``ctx.sensor.exposure_retake(before, reading)``; None: none can mend it), at most
    :data:`~.exposure.MAX_EXPOSURE_RETAKES` times: the beam to standby, a new before frame at that
    exposure (saved; the visit's later placements use it), the beam back to ``strokes_cmd`` by the
    same approach, new after frames. Returns ``(before, reading, held)``: ``held`` the read-back
    strokes of the last hold (None: no retake). The reading's message says what was retaken and why;
    a frame that cannot be had ends the retakes (the last reading stands, with that said)."""
    offer = ctx.sensor.exposure_retake
    first, steps, held = reading.reason, [getattr(before.state, "exposure_ms", None)], None
    for _ in range(MAX_EXPOSURE_RETAKES):
        exposure_ms = offer(before, reading)
        if exposure_ms is None:
            break
        yield from to_standby(ctx)
        try:
            new = ctx.sensor.before(ctx, exposure_ms)
        except MeasurementError as err:
            return before, replace(reading, message=f"{reading.message.rstrip('.')} [no before frame at "
                                                    f"{exposure_ms:.3g} ms could be had: {err}]."), held
        before = new
        steps.append(getattr(before.state, "exposure_ms", exposure_ms))
        if before.data is not None:
            ctx.before_path = ctx.host.save_frame(ctx, before.data, iteration, before.capture_time_s, "before")
        held = yield from approach_and_hold(ctx, strokes_cmd, aim)
        reading = yield from ctx.sensor.after(ctx, before)
        if reading.before_beam:
            before, reading = yield from retake_before(ctx, before, reading, iteration)
    if len(steps) == 1:
        return before, reading, held
    path = " → ".join(f"{e:.3g}" for e in steps)
    n = len(steps) - 1
    note = f"{EXPOSED} {path} ms after a {first} reading ({n} time{'s' if n > 1 else ''})"
    return before, replace(reading, message=f"{reading.message.rstrip('.')} [{note}]."), held


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
        yield move_status.POLL_S
        waited += move_status.POLL_S


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


def record_failure(ctx: VisitContext, code: str, message: str, frame=None) -> None:
    """Record a failed attempt of the visit (``iteration`` -1) with reason ``code`` at plant time now,
    and the frame that showed it, if any; a failure to record it is let go (the beam must still
    leave the board)."""
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


def _before_data(ctx: VisitContext, before: Before):
    """The before frame's bytes, unless it was saved already (then its path is in the observation)."""
    return None if ctx.before_path is not None else before.data


def _plant_reads(ctx: VisitContext):
    """The plant's weather and the heliostat's status now (None each where the plant does not answer)."""
    return _safe(ctx.plant.weather), _safe(lambda: ctx.plant.status(ctx.index))


def _safe(fn):
    try:
        return fn()
    except HelicalibError:
        return None
