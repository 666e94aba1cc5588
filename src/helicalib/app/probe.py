"""``helicalib probe FIELD``: a read-only check of a live plant against its field config and map.

Builds the plant client unarmed (whatever the command line says: probe never writes) and the
cameras as a run would, then reads, in this order: the heliostat count and the field state, the
plant clock, the weather, every heliostat's state, fault code, strokes and cleanliness, and one
frame from every camera (its size, its capture time against the plant time read right before and
after the grab, and its exposure control: asked once for another exposure, then set back to the
one it had). Each reading is judged by
:mod:`helicalib.app.probe_checks`; :mod:`helicalib.app.probe_view` prints the table or the JSON.

Exit status: 0 every check passed (warnings allowed), :data:`EXIT_MISMATCH` a check failed,
:data:`EXIT_CONFIG` the field config, a heliostat id or the register map is bad.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from helicalib.app.probe_checks import (MISMATCH, OK, WARNING, Check, capture_time_check, clock_checks,
                                        count_check, exposure_check, frame_check, heliostat_check, skipped_check,
                                        unread_check, weather_checks)
from helicalib.errors import ConfigError, MeasurementError, PlantError

EXIT_MISMATCH = 1
"""A check failed: the plant, its map or a camera disagrees with the field config."""
EXIT_CONFIG = 2
"""Bad usage: the field config, a ``--heliostats`` id or the register map cannot be used (one line)."""
PROGRESS_MIN_HELIOSTATS = 200
"""Fields of this many heliostats or more show the reads' progress on stderr."""
PROBE_EXPOSURE_MS = 2.0
"""The exposure asked of a camera that does not report its own [ms] (one that does is asked for
twice its present one)."""


@dataclass(frozen=True)
class ProbeResult:
    """Every check of one probe, in the order they were made."""

    field: str
    plant: str
    checks: tuple[Check, ...]

    def count(self, status: str) -> int:
        return sum(1 for c in self.checks if c.status == status)

    @property
    def passed(self) -> bool:
        return self.count(MISMATCH) == 0

    @property
    def exit_status(self) -> int:
        return 0 if self.passed else EXIT_MISMATCH


def plant_name(cfg) -> str:
    """The plant's endpoint as the crew configured it."""
    if cfg.plant.protocol == "opcua":
        return f"OPC UA {cfg.plant.opcua.endpoint}"
    scs = cfg.plant.scs
    return f"Modbus TCP {scs.host}:{scs.port} unit {scs.unit}"


def probe(cfg, plant, cameras: dict, *, plant_now: Callable[[], float] | None, clock_slack_s: Callable[[], float],
          heliostat_ids: Sequence[str] | None = None, utc_now: Callable[[], float] = time.time,
          progress=None, plant_error: str | None = None) -> ProbeResult:
    """Read the plant and the cameras once and judge every reading (never writes).

    ``plant`` is an unarmed plant client (None when it could not be built: ``plant_error`` says
    why); ``cameras`` by target id as :func:`~helicalib.devices.connect.cameras_from_config` gives
    them; ``plant_now`` reads the plant time afresh (the field's clock); ``clock_slack_s`` is that
    clock's uncertainty now; ``progress(done, total)`` is told of the heliostat reads."""
    from helicalib.devices.protocols import PlantUnreachableError

    checks: list[Check] = []
    ids = list(heliostat_ids) if heliostat_ids is not None else [h.id for h in cfg.heliostats]
    expected = len(cfg.heliostats)
    reachable, count_ok = plant is not None, False
    if plant is None:
        checks.append(count_check(expected, None, plant_error))
    else:
        try:
            found = int(plant.heliostat_count())
            checks.append(count_check(expected, found))
            count_ok = found == expected
        except PlantError as err:
            checks.append(count_check(expected, None, str(err)))
            reachable = not isinstance(err, PlantUnreachableError)
    if reachable:
        checks += _plant_reads(plant, utc_now)
    else:
        checks += [skipped_check(s, n, "the plant did not answer") for s, n in
                   (("plant", "field state"), ("clock", "plant time"), ("weather", "weather"))]
    if reachable and count_ok:
        checks += _heliostats(cfg, plant, ids, progress)
    else:
        why = "the plant did not answer" if not reachable else "the heliostat count differs from the config's"
        checks.append(skipped_check("heliostats", f"{len(ids)} heliostats", why))
    checks += _cameras(cfg, cameras, plant_now, clock_slack_s)
    return ProbeResult(str(cfg.source), plant_name(cfg), tuple(checks))


def _plant_reads(plant, utc_now) -> list[Check]:
    out: list[Check] = []
    try:
        state = plant.field_state()
        out.append(Check("plant", "field state", "tracking, stowing or stowed", state.name.lower(), OK,
                         {"field_state": state.name.lower()}))
    except PlantError as err:
        out.append(unread_check("plant", "field state", "tracking, stowing or stowed", str(err)))
    try:
        t_s, rate = plant.plant_time()
        out += clock_checks(float(t_s), float(rate), float(utc_now()))
    except PlantError as err:
        out.append(unread_check("clock", "plant time", "a time and a rate > 0", str(err)))
    try:
        out += weather_checks(plant.weather())
    except PlantError as err:
        out.append(unread_check("weather", "weather", "the weather block", str(err)))
    return out


def _heliostats(cfg, plant, ids: list[str], progress) -> list[Check]:
    from helicalib.devices.protocols import PlantUnreachableError

    out: list[Check] = []
    for k, hid in enumerate(ids):
        limits = [a.stroke_range_mm for a in cfg.drive_of(hid).actuators]
        try:
            out.append(heliostat_check(hid, plant.status(cfg.heliostat_index(hid)), limits))
        except PlantUnreachableError as err:
            out.append(unread_check("heliostats", hid, "its block readable", str(err)))
            if k + 1 < len(ids):
                out.append(skipped_check("heliostats", f"{len(ids) - k - 1} heliostats after {hid}",
                                         "the plant stopped answering"))
            break
        except PlantError as err:  # a state outside the contract, a refused read: this heliostat only
            out.append(unread_check("heliostats", hid, "its block readable, a known state", str(err)))
        if progress is not None:
            progress(k + 1, len(ids))
    return out


def _cameras(cfg, cameras: dict, plant_now, clock_slack_s) -> list[Check]:
    out: list[Check] = []
    for cam_cfg in cfg.cameras:
        first = cfg.cameras_for(cam_cfg.target)[0]
        if first is not cam_cfg:  # the controller uses a target's first camera only
            out.append(Check("cameras", f"{cam_cfg.id} frame", "", f"not probed: target {cam_cfg.target} is watched "
                             f"by {first.id} (the controller uses a target's first camera)", WARNING, {}))
            continue
        out += camera_checks(cam_cfg, cameras[cam_cfg.target], plant_now, clock_slack_s,
                             cfg.calibration.max_capture_skew_s)
    return out


def camera_checks(cam_cfg, camera, plant_now, clock_slack_s, max_skew_s: float) -> list[Check]:
    """One frame of one camera: decodes at its size, its capture time, its exposure control."""
    from helicalib.vision.frames import decode_frame

    size = cam_cfg.resolution_px if "resolution_px" in cam_cfg.model_fields_set else None
    cid = cam_cfg.id
    before_s = _plant_time(plant_now)
    try:
        frame = camera.grab()
    except (MeasurementError, PlantError) as err:
        return [frame_check(cid, None, size, f"{cam_cfg.url}: {_bare(err, cam_cfg.url)}")]
    after_s = _plant_time(plant_now)
    try:
        image = decode_frame(frame.data, what=f"camera {cid} frame")
    except MeasurementError as err:
        return [frame_check(cid, None, size, str(err))]
    out = [frame_check(cid, (int(image.shape[1]), int(image.shape[0])), size)]
    if before_s is None or after_s is None:
        out.append(skipped_check("cameras", f"{cid} capture time", "no plant time to compare it with"))
    else:
        out.append(capture_time_check(cid, float(frame.capture_time_s), before_s, after_s,
                                      max_skew_s + float(clock_slack_s())))
    out.append(_exposure(cid, camera, frame.exposure_ms))
    return out


def _exposure(cid: str, camera, current_ms: float | None) -> Check:
    """Ask for an exposure once (twice the present one, or :data:`PROBE_EXPOSURE_MS`) and say
    whether it was applied; a camera whose present exposure is known is set back to it (a stream
    or GenICam camera keeps a setting, and probe leaves the plant as it found it)."""
    known = current_ms is not None and math.isfinite(current_ms) and current_ms > 0
    asked = 2.0 * current_ms if known else PROBE_EXPOSURE_MS
    applied, error, restored = None, None, None
    try:
        applied = camera.grab(exposure_ms=asked).exposure_ms
    except (MeasurementError, PlantError) as err:
        error = str(err)
    finally:  # changed, or perhaps changed before the grab failed: set the present exposure again
        if known and (error is not None or (applied is not None and not math.isclose(applied, current_ms))):
            restored = _restore(camera, current_ms)
    check = exposure_check(cid, current_ms, asked, applied, error)
    if restored is None:
        return check
    back_ms, why = restored
    values = {**check.values, "restored_ms": back_ms}
    if back_ms is not None and math.isclose(back_ms, current_ms, rel_tol=0.01):
        return replace(check, found=f"{check.found}; set back to {back_ms:g} ms", values=values)
    found = f"{check.found}; not set back to {current_ms:g} ms ({why})"
    return replace(check, found=found, status=WARNING if check.status == OK else check.status, values=values)


def _restore(camera, exposure_ms: float) -> tuple[float | None, str]:
    """Grab once at ``exposure_ms``: the exposure the camera then reports, and why not when it failed."""
    try:
        back = camera.grab(exposure_ms=exposure_ms).exposure_ms
    except (MeasurementError, PlantError) as err:
        return None, str(err)
    return back, "it reports none" if back is None else f"it reports {back:g} ms"


def _plant_time(plant_now) -> float | None:
    if plant_now is None:
        return None
    try:
        return float(plant_now())
    except PlantError:
        return None


def _bare(err: Exception, url: str) -> str:
    """The error's text without a leading ``camera <url>:`` (the line names the camera once)."""
    text = str(err)
    prefix = f"camera {url}: "
    return text.removeprefix(prefix)


def run_probe(field: str, *, register_map: str | None = None, heliostats: str | None = None,
              as_json: bool = False, show_all: bool = False, armed_asked: bool = False) -> int:
    """The ``probe`` command: returns its exit status (0, :data:`EXIT_MISMATCH` or :data:`EXIT_CONFIG`)."""
    from helicalib.app.probe_view import print_json, print_table

    if armed_asked:
        print("helicalib probe: --arm ignored: probe never writes to the plant", file=sys.stderr)
    try:
        result = _probe_field(field, register_map, heliostats)
    except ConfigError as err:
        for line in err.problems:
            print(f"helicalib probe: error: {line}", file=sys.stderr)
        return EXIT_CONFIG
    if as_json:
        print_json(result, show_all=show_all)
    else:
        print_table(result, show_all=show_all)
    return result.exit_status


def _probe_field(field: str, register_map: str | None, heliostats: str | None) -> ProbeResult:
    from helicalib.commands._progress import ProgressReporter
    from helicalib.config import load_field_config
    from helicalib.devices.clock import PlantClock, SystemClock, make_clock
    from helicalib.devices.connect import cameras_from_config, plant_from_config

    cfg = load_field_config(field)
    ids = [s.strip() for s in heliostats.split(",") if s.strip()] if heliostats else None
    for hid in ids or ():
        cfg.heliostat(hid)  # an unknown id: one ConfigError line, exit status 2
    plant, plant_error = None, None
    try:
        plant = plant_from_config(cfg, armed=False, register_map=register_map)  # never armed: probe reads only
    except ConfigError:
        raise
    except PlantError as err:
        plant_error = str(err)
    try:
        clock = make_clock(cfg, plant) if plant is not None else SystemClock()
        plant_now = clock.sync if isinstance(clock, PlantClock) else clock.now_s
        if plant is None and cfg.plant.clock == "plant":
            plant_now = None  # no plant time to judge capture times by
        cameras = cameras_from_config(cfg, clock=clock)
        n = len(ids) if ids is not None else len(cfg.heliostats)
        reporter = ProgressReporter("probe", total=n) if n >= PROGRESS_MIN_HELIOSTATS else None
        try:
            return probe(cfg, plant, cameras, plant_now=plant_now, clock_slack_s=lambda: float(clock.uncertainty_s),
                         heliostat_ids=ids, plant_error=plant_error,
                         progress=None if reporter is None else (
                             lambda done, total: reporter.update(done, f"{done} of {total} heliostats read")))
        finally:
            if reporter is not None:
                reporter.close()
            for camera in cameras.values():
                close = getattr(camera, "close", None)
                if callable(close):
                    close()
    finally:
        if plant is not None:
            plant.close()
