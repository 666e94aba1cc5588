"""Live sessions (``helicalib run``, ``operate`` and ``check``): devices from the config, store, runner.

The composition root of a live run: the field config, the campaign database (owned by this
process for the whole run), the plant's Modbus TCP client and HTTP cameras, the plant clock, the
runner and what the crew sees (:mod:`.terminal`, the web console). The campaign's life-cycle:

* ``run`` resumes the field's campaign by default and starts another only with
  ``--new-campaign``; a run without ``--arm`` is a *dry run*, kept as a campaign of its own;
  ``check`` is one campaign per re-check (:mod:`.resume`);
* a campaign reads ``running`` only while a process runs it; a stop leaves ``stopped``, the end
  of ``--until``/``--days`` (or of a check) ``finished``;
* a campaign is resumed only on a plant clock consistent with it
  (:func:`~helicalib.app.opening.check_plant_clock`) unless ``--accept-clock-jump``.

Exit status (``docs/running.md``): 0 done; 1 an error (one line);
:data:`~helicalib.app.summary.EXIT_NOT_MEASURED`, :data:`EXIT_STORAGE`, :data:`EXIT_CLOCK_JUMP`.
"""

from __future__ import annotations

import math
import sqlite3
import sys
from contextlib import contextmanager
from pathlib import Path

from helicalib.app.opening import last_written_wall_s, open_campaign
from helicalib.app.settings import LiveSettings
from helicalib.app.summary import EXIT_NOT_MEASURED, print_summary, session_summary
from helicalib.errors import ConfigError, HelicalibError, StorageError

EXIT_STORAGE = 4
"""The database could not be written during the run (full disk, read-only): after
:data:`~helicalib.campaign.journal.STORAGE_RETRIES` attempts every beam went back to tracking."""
EXIT_CLOCK_JUMP = 5
"""The plant's clock jumped (backwards, or forwards beyond where it can be) during the run: every
beam went back to tracking."""


def live_session(args, mode: str) -> int:
    """The live session a parsed ``run``/``operate``/``check`` command line asks for (:func:`run_session`)."""
    return run_session(LiveSettings.from_args(args, mode))


def session_days(settings: LiveSettings) -> float:
    """Plant days the session runs: ``--days``, else 7 (``run``, ``check``) or until stopped (``operate``)."""
    operation = settings.operation
    days = settings.days if settings.days is not None else (math.inf if operation else 7.0)
    if not (days > 0 and (math.isfinite(days) or (operation and settings.days is None))):
        raise ConfigError(f"--days {settings.days}: must be a finite number > 0")
    return days


def check_plant(cfg, plant) -> None:
    """Refuse to start against a plant whose heliostat count differs from the config's (one line)."""
    from helicalib.errors import PlantError

    try:
        plant.heliostat_count()
    except PlantError as err:
        raise ConfigError(f"{cfg.source}: refusing to start: {err}") from None


def run_session(settings: LiveSettings) -> int:
    """Open the store, connect the plant, resume or start a campaign, run it on APScheduler."""
    from rich.console import Console

    from helicalib.app.terminal import make_output, site_timezone
    from helicalib.app.live import run_live
    from helicalib.campaign.loop import CampaignRunner
    from helicalib.config import load_field_config
    from helicalib.console.server import attach_console
    from helicalib.devices.clock import make_clock
    from helicalib.devices.connect import cameras_from_config, plant_from_config
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.store.sqlite import Store

    cfg = load_field_config(settings.field)
    cfg.require_cameras()  # a PAINT import describes a plant; it cannot be measured
    for hid in settings.heliostat_ids or ():
        cfg.heliostat(hid)
    days = session_days(settings)
    mode, operation, command, as_json = settings.mode, settings.operation, settings.command, settings.as_json
    tz = site_timezone(cfg)
    console = Console(stderr=True)
    output = make_output("json" if as_json else ("terminal" if console.is_terminal else "lines"), tz,
                         f"helicalib {command} · {cfg.site.name}")
    written = last_written_wall_s(Path(cfg.database_path))
    with storage_errors(cfg.database_path):
        store = Store.open(cfg.database_path, cfg.images_path, owner=f"{command} {cfg.source}")
    plant = None
    result = None
    try:
        plant = plant_from_config(cfg, armed=settings.armed, register_map=settings.register_map)
        check_plant(cfg, plant)
        clock = make_clock(cfg, plant)
        now = clock.now_s()
        if settings.until:
            until_s = float(to_unix_seconds([parse_time(settings.until)])[0])
            if until_s <= now:
                raise ConfigError(f"--until {settings.until}: lies before the plant time now")
        else:
            until_s = now + 86400.0 * days
        with storage_errors(cfg.database_path):
            opened = open_campaign(store, cfg, settings, now, rate=float(clock.rate), written_wall_s=written)
            store.record_event(campaign_id=opened.campaign_id, time_s=now, kind="campaign", reason=opened.line,
                               data={"command": command, "operation": operation})
        if as_json:
            output.emit({"event": "campaign", "campaign": opened.campaign_id, "reason": opened.line})
        else:
            output.message(opened.line)
        if not settings.armed:
            output.message("not armed: reading and planning only, nothing is written to the plant (add --arm to "
                           "calibrate)")
        cameras = cameras_from_config(cfg, clock=clock)
        runner = CampaignRunner(cfg, plant, cameras, clock, store, opened.campaign_id,
                                heliostat_ids=opened.heliostat_ids, planner=settings.planner,
                                recheck=settings.recheck, armed=settings.armed, refine=settings.refine,
                                listeners=[output.on_event],  # a restart's own events are shown too
                                operation=operation, rota_days=settings.rota_days,
                                spots_per_board=settings.spots_per_board)
        if mode == "check":  # check resumes nothing: no --accept-clock-jump to suggest
            runner.state.faults.clock_jump_hint = ""
        if operation and settings.keep_frames is not None:
            # every night: the frames of all but the newest N observations, and the rejected ones
            runner.state.retention = (int(settings.keep_frames), True)
        output = attach_console(settings.console, runner, output)  # operator actions; the crew console with --console
        with storage_errors(cfg.database_path):
            orphans = store.remove_orphan_frames(opened.campaign_id)
        if orphans:
            output.message(f"removed {orphans} frame file(s) no observation points to (a visit the previous "
                           "process was killed in)")
        result = run_live(runner, until_s, done=(runner.rechecked if settings.recheck else None), output=output)
        end_s = runner.journal.safe_now()[0]
        if result.reason != "storage":
            with storage_errors(cfg.database_path):
                store.finish_campaign(opened.campaign_id, end_s,
                                      status="finished" if result.reason in ("until", "done") else "stopped")
        summary = session_summary(store, cfg, runner, opened, result, mode)
    finally:
        if plant is not None:
            plant.close()
        try:
            store.close()
        except (sqlite3.Error, OSError):  # a full disk: the close's last commit fails too; the records are in
            if result is None or result.reason != "storage":
                raise
    if as_json:
        output.emit(summary)
    else:
        print_summary(summary, mode)
    return exit_status(summary, result, runner, command)


def exit_status(summary: dict, result, runner, command: str) -> int:
    """0, or a documented status with its one line on stderr (the run's stop, a check that measured nothing)."""
    if result.reason == "storage":
        print(f"helicalib {command}: error: {runner.state.faults.storage_lost}; every beam went back to tracking "
              f"(exit status {EXIT_STORAGE})", file=sys.stderr)
        return EXIT_STORAGE
    if result.reason == "clock_jump":
        print(f"helicalib {command}: error: {runner.state.faults.clock_jump} (exit status {EXIT_CLOCK_JUMP})",
              file=sys.stderr)
        return EXIT_CLOCK_JUMP
    if result.reason == "stopped":  # a clean stop (Ctrl-C, SIGTERM) is 0, whatever it measured
        return 0
    if "rechecks" in summary and any(r["present_error_mrad"] is None for r in summary["rechecks"]):
        return EXIT_NOT_MEASURED
    return 0


@contextmanager
def storage_errors(path):
    """SQLite's and the system's errors of a database that cannot be written (read-only file or
    folder, full disk) become one :class:`StorageError` line naming the file."""
    from helicalib.campaign.state import storage_error

    try:
        yield
    except HelicalibError:
        raise
    except (sqlite3.Error, OSError) as err:
        if not storage_error(err):
            raise
        raise StorageError(f"database {path}: cannot be written ({type(err).__name__}: {err}); a read-only file or "
                           "folder, or a full disk?") from None
