"""Live sessions (``helicalib run`` and ``helicalib check``): devices from the config, store, runner.

The composition root of a live run: the field config, the campaign database (owned by this
process for the whole run), the plant's Modbus TCP client and HTTP cameras, the plant clock, the
runner and what the crew sees (:mod:`.console`). The campaign's life-cycle:

* ``run`` resumes the field's campaign by default (finished or not: the database keeps one
  calibration of the field, its points never expire) and starts another only with
  ``--new-campaign``; a run without ``--arm`` is a *dry run*, kept as a campaign of its own
  (mode ``dry-run``) that an armed run never resumes, because nothing was calibrated in it;
* ``check`` is one campaign per re-check (mode ``check``);
* a campaign reads ``running`` only while a process runs it; a stop leaves ``stopped``, the end
  of ``--until``/``--days`` (or of a check) ``finished``;
* a campaign is resumed only on a plant clock consistent with it (:func:`check_plant_clock`):
  a plant time before the campaign's last record, or far beyond what the time since then allows,
  is refused unless ``--accept-clock-jump``.

Exit status (``docs/running.md``): 0 done; 1 an error (one line); :data:`EXIT_NOT_MEASURED`,
:data:`EXIT_STORAGE`, :data:`EXIT_CLOCK_JUMP`.
"""

from __future__ import annotations

import math
import sqlite3
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from helicalib.errors import ConfigError, HelicalibError, PlantError, StorageError

RUN_KINDS = ("live", "dry-run")

EXIT_NOT_MEASURED = 3
"""``check``: a heliostat could not be measured (night, gated, not armed, no visit in time)."""
EXIT_STORAGE = 4
"""The database could not be written during the run (full disk, read-only): after
:data:`~helicalib.campaign.runner.STORAGE_RETRIES` attempts every beam went back to tracking."""
EXIT_CLOCK_JUMP = 5
"""The plant's clock jumped (backwards, or forwards beyond where it can be) during the run: every
beam went back to tracking."""

CLOCK_BACK_TOLERANCE_S = 60.0
"""A resumed campaign's last record may lie this many plant seconds after the plant's time now
(records stamped by the controller's own clock run slightly ahead)."""
CLOCK_FORWARD_SLACK_S = 86400.0
"""Plant seconds a plant's time may lie beyond the campaign's last record on top of what the real
time since the database was last written allows at the plant's rate (×1.5)."""


@dataclass(frozen=True)
class Opened:
    """The campaign a session runs, and the sentence that introduces it."""

    campaign_id: int
    heliostat_ids: list[str]
    line: str


def campaign_kind(campaign) -> str | None:
    """``"armed"`` (a run that calibrates), ``"dry"`` (a run without --arm) or None (check, simulate)."""
    if campaign.mode == "dry-run" or (campaign.mode == "live" and campaign.settings.get("armed") is False):
        return "dry"
    return "armed" if campaign.mode == "live" else None


def last_record_s(store, campaign_id: int) -> float | None:
    """Plant time of a campaign's newest record (event, visit start or end), None if it has none."""
    times = [e.time_s for e in store.events(campaign_id=campaign_id)]
    for v in store.visits(campaign_id=campaign_id):
        times.append(v.started_s)
        if v.ended_s is not None:
            times.append(v.ended_s)
    times = [t for t in times if t is not None and math.isfinite(t)]
    return max(times) if times else None


def check_plant_clock(store, campaign_id: int, now_s: float, rate: float, written_wall_s: float | None,
                      accept: bool) -> str | None:
    """Refuse (:class:`PlantError`, one line naming both times) to resume campaign ``campaign_id``
    on a plant whose time ``now_s`` lies before its last record (beyond
    :data:`CLOCK_BACK_TOLERANCE_S`: a plant restarted at an earlier date) or far beyond it (more than
    the real seconds since the database was last written, ``written_wall_s``, allow at
    ``rate`` ×1.5, plus :data:`CLOCK_FORWARD_SLACK_S`). With ``accept`` the jump is returned as a
    sentence to record instead; None when the clock is consistent."""
    from helicalib.campaign.events import iso_utc

    last = last_record_s(store, campaign_id)
    if last is None:
        return None
    jump = None
    if now_s < last - CLOCK_BACK_TOLERANCE_S:
        jump = (f"the plant's time {iso_utc(now_s)} lies before campaign {campaign_id}'s last record "
                f"{iso_utc(last)} ({(last - now_s) / 3600.0:.1f} h back: a plant restarted at an earlier date?)")
    elif written_wall_s is not None:
        real = max(0.0, time.time() - written_wall_s)
        if now_s - last > 1.5 * max(float(rate), 1.0) * real + CLOCK_FORWARD_SLACK_S:
            jump = (f"the plant's time {iso_utc(now_s)} lies {(now_s - last) / 86400.0:.1f} days after campaign "
                    f"{campaign_id}'s last record {iso_utc(last)}, but the database was written "
                    f"{real / 3600.0:.1f} h ago (the plant's clock jumped forwards?)")
    if jump is None:
        return None
    if not accept:
        raise PlantError(f"refusing to resume: {jump}; check the plant's clock, or resume from the plant's time "
                         "with --accept-clock-jump")
    return jump


def last_written_wall_s(db: Path) -> float | None:
    """Real time the database (or its write-ahead log) was last written; None if it does not exist."""
    times = []
    for f in (db, db.with_name(db.name + "-wal")):
        try:
            times.append(f.stat().st_mtime)
        except OSError:
            pass
    return max(times) if times else None


def open_campaign(store, cfg, args, mode: str, now_s: float, ids: list[str] | None, rate: float = 1.0,
                  written_wall_s: float | None = None) -> Opened:
    """Resume or start the session's campaign; the returned line says which and what it holds. A
    resume on a plant clock that jumped is refused (:func:`check_plant_clock`) unless
    ``args.accept_clock_jump``."""
    armed = bool(args.arm)
    kind = "armed" if armed else "dry"
    run_mode = "live" if armed else "dry-run"
    resumed = None
    skipped = ""
    if mode == "live" and not getattr(args, "new_campaign", False):
        same = [c for c in store.campaigns() if campaign_kind(c) == kind]
        resumed = same[-1] if same else None
        other = [c for c in store.campaigns() if campaign_kind(c) == ("dry" if armed else "armed")]
        if resumed is None and armed and other:
            skipped = (f"; campaign {other[-1].id} was a dry run (nothing was calibrated in it), so this armed run "
                       "starts its own")
    if resumed is not None:
        held = [h.heliostat_id for h in store.campaign_heliostats(resumed.id)]
        if ids and sorted(ids) != sorted(held):
            raise ConfigError(f"--heliostats: campaign {resumed.id} calibrates {plural(len(held), 'heliostat')}, not the "
                              f"{len(ids)} named; resume it without --heliostats, or add --new-campaign")
        jump = check_plant_clock(store, resumed.id, now_s, rate, written_wall_s, bool(args.accept_clock_jump))
        was = resumed.status
        store.reopen_campaign(resumed.id)
        accepted = f"; resumed from the plant's time although {jump} (--accept-clock-jump)" if jump else ""
        return Opened(resumed.id, held, f"campaign {resumed.id} ({_label(kind)}, resumed; it was {was}): "
                                        + holdings(store, resumed.id, held) + f"; database {store.path}{accepted}")
    ids = ids or [h.id for h in cfg.heliostats]
    name = {"live": f"{'live' if armed else 'dry run'} {cfg.site.name}", "check": f"check {cfg.site.name}"}[mode]
    cid = store.start_campaign(
        name=name, mode=run_mode if mode == "live" else "check", started_s=now_s,
        heliostats=[(hid, cfg.heliostat_index(hid), cfg.heliostat(hid).target) for hid in ids],
        config_path=str(cfg.source), settings={"armed": armed, "planner": args.planner,
                                               "refine": getattr(args, "refine", False)})
    what = "re-check" if mode == "check" else _label(kind)
    return Opened(cid, ids, f"campaign {cid} ({what}, new): {plural(len(ids), 'heliostat')}{skipped}; database {store.path}")


def _label(kind: str) -> str:
    return "armed" if kind == "armed" else "dry run: nothing is written to the plant"


def holdings(store, campaign_id: int, ids: list[str]) -> str:
    """What a campaign holds, in one clause: heliostats, accepted, observations, visits."""
    verdicts = store.latest_verdicts(campaign_id)
    accepted = sum(1 for h in ids if verdicts.get(h) is not None and verdicts[h].accepted)
    n_obs = store.count_observations(campaign_id)
    n_valid = store.count_observations(campaign_id, valid=True)
    visits = len(store.visits(campaign_id=campaign_id))
    return (f"{plural(len(ids), 'heliostat')}, {accepted} accepted, {plural(n_obs, 'observation')} ({n_valid} valid) "
            f"in {plural(visits, 'visit')}")


def check_plant(cfg, plant) -> None:
    """Refuse to start against a plant whose heliostat count differs from the config's (one line)."""
    from helicalib.errors import PlantError

    try:
        plant.heliostat_count()
    except PlantError as err:
        raise ConfigError(f"{cfg.source}: refusing to start: {err}") from None


def live_session(args, mode: str) -> int:
    """Open the store, connect the plant, resume or start a campaign, run it on APScheduler."""
    from rich.console import Console

    from helicalib.app.terminal import make_output, site_timezone
    from helicalib.app.live import run_live
    from helicalib.campaign.runner import CampaignRunner
    from helicalib.config import load_field_config
    from helicalib.console.server import attach_console
    from helicalib.devices.camera_http import cameras_from_config
    from helicalib.devices.clock import make_clock
    from helicalib.devices.modbus import ModbusPlant
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.store.sqlite import Store

    cfg = load_field_config(args.field)
    cfg.require_cameras()  # a PAINT import describes a plant; it cannot be measured
    ids = [s.strip() for s in args.heliostats.split(",") if s.strip()] if args.heliostats else None
    for hid in ids or ():
        cfg.heliostat(hid)
    operation = getattr(args, "operation", None)  # helicalib operate: the long-running service
    days = args.days if args.days is not None else (math.inf if operation else 7.0)
    if not (days > 0 and (math.isfinite(days) or (operation and args.days is None))):
        raise ConfigError(f"--days {args.days}: must be a finite number > 0")
    command = "operate" if operation else ("run" if mode == "live" else "check")
    tz = site_timezone(cfg)
    as_json = bool(getattr(args, "json", False))
    console = Console(stderr=True)
    output = make_output("json" if as_json else ("terminal" if console.is_terminal else "lines"), tz,
                         f"helicalib {command} · {cfg.site.name}")
    written = last_written_wall_s(Path(cfg.database_path))
    with storage_errors(cfg.database_path):
        store = Store.open(cfg.database_path, cfg.images_path, owner=f"{command} {cfg.source}")
    plant = None
    result = None
    try:
        plant = ModbusPlant.from_config(cfg, armed=args.arm)
        check_plant(cfg, plant)
        clock = make_clock(cfg, plant)
        now = clock.now_s()
        if args.until:
            until_s = float(to_unix_seconds([parse_time(args.until)])[0])
            if until_s <= now:
                raise ConfigError(f"--until {args.until}: lies before the plant time now")
        else:
            until_s = now + 86400.0 * days
        with storage_errors(cfg.database_path):
            opened = open_campaign(store, cfg, args, mode, now, ids, rate=float(clock.rate),
                                   written_wall_s=written)
            store.record_event(campaign_id=opened.campaign_id, time_s=now, kind="campaign", reason=opened.line,
                               data={"command": command, "operation": operation})
        if as_json:
            output.emit({"event": "campaign", "campaign": opened.campaign_id, "reason": opened.line})
        else:
            output.message(opened.line)
        if not args.arm:
            output.message("not armed: reading and planning only, nothing is written to the plant (add --arm to "
                           "calibrate)")
        cameras = cameras_from_config(cfg)
        runner = CampaignRunner(cfg, plant, cameras, clock, store, opened.campaign_id,
                                heliostat_ids=opened.heliostat_ids, planner=args.planner, recheck=args.recheck,
                                armed=args.arm, refine=getattr(args, "refine", False),
                                listeners=[output.on_event],  # a restart's own events are shown too
                                operation=operation, rota_days=getattr(args, "rota_days", 14.0),
                                spots_per_board=getattr(args, "spots_per_board", 1))
        if mode == "check":  # check resumes nothing: no --accept-clock-jump to suggest
            runner.clock_jump_hint = ""
        if operation and getattr(args, "keep_frames", None) is not None:
            runner.retention = (int(args.keep_frames), True)  # every night: frames of the newest N and the rejected
        output = attach_console(args, runner, output)  # operator actions; the crew console with --console
        with storage_errors(cfg.database_path):
            orphans = store.remove_orphan_frames(opened.campaign_id)
        if orphans:
            output.message(f"removed {orphans} frame file(s) no observation points to (a visit the previous "
                           "process was killed in)")
        result = run_live(runner, until_s, done=(runner.rechecked if args.recheck else None), output=output)
        end_s = runner.safe_now()[0]
        if result.reason != "storage":
            with storage_errors(cfg.database_path):
                store.finish_campaign(opened.campaign_id, end_s,
                                      status="finished" if result.reason in ("until", "done") else "stopped")
        summary = _summary(store, cfg, runner, opened, result, mode)
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
        _print_summary(summary, mode)
    return _exit_status(summary, result, runner, command)


def _exit_status(summary: dict, result, runner, command: str) -> int:
    """0, or a documented status with its one line on stderr (the run's stop, a check that measured nothing)."""
    if result.reason == "storage":
        print(f"helicalib {command}: error: {runner.storage_lost}; every beam went back to tracking "
              f"(exit status {EXIT_STORAGE})", file=sys.stderr)
        return EXIT_STORAGE
    if result.reason == "clock_jump":
        print(f"helicalib {command}: error: {runner.clock_jump} (exit status {EXIT_CLOCK_JUMP})", file=sys.stderr)
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
    from helicalib.campaign.runner import storage_error

    try:
        yield
    except HelicalibError:
        raise
    except (sqlite3.Error, OSError) as err:
        if not storage_error(err):
            raise
        raise StorageError(f"database {path}: cannot be written ({type(err).__name__}: {err}); a read-only file or "
                           "folder, or a full disk?") from None


def _summary(store, cfg, runner, opened: Opened, result, mode: str) -> dict:
    campaign = store.campaign(opened.campaign_id)
    status = "stopped (not recorded: the database cannot be written)" if result.reason == "storage" else campaign.status
    out = {"event": "summary", "campaign": opened.campaign_id, "mode": campaign.mode, "status": status,
           "ended_because": {"until": "its end time came", "done": "every heliostat re-checked",
                             "stopped": "Ctrl-C or SIGTERM", "clock_jump": "the plant's clock jumped",
                             "storage": "the database cannot be written"}[result.reason],
           "stopped_by": result.reason, "armed": runner.armed, "heliostats": len(runner.ids),
           "accepted": len(runner.accepted()),
           "visits_this_run": runner.stats.visits, "valid_visits_this_run": runner.stats.valid_visits,
           "outcomes_this_run": dict(runner.stats.outcomes),
           "observations": store.count_observations(opened.campaign_id),
           "valid_observations": store.count_observations(opened.campaign_id, valid=True),
           "off_tracking": list(result.off_tracking), "database": str(cfg.database_path)}
    if runner.operation is not None:
        out.update(operation=runner.operation, checks_this_run=runner.checks,
                   drifts=[{k: d.get(k) for k in ("heliostat_id", "since_s", "confirmed_s", "fixed_s", "evidence")}
                           for d in runner.drifts])
    if mode == "check":
        out["rechecks"] = recheck_rows(cfg, runner)
    return out


def recheck_rows(cfg, runner) -> list[dict]:
    """Per re-checked heliostat: its present error (first placement of this check) beside the limit,
    and a verdict.

    The present error is the beam's angle between where the camera saw the spot and where the
    heliostat's model (its newest fit, which placed it) puts it: the measure acceptance judges, with
    acceptance's limit ``acceptance.max_rms_mrad``. T/GRLM formula (1) on the board, which the loop
    uses, is given beside it. ``drift``: the same placement tested against the band the newest fit
    predicts for it (:mod:`helicalib.campaign.operation.drift`); outside it, the heliostat changed since."""
    from helicalib.campaign.operation import rules as op_rules
    from helicalib.campaign.operation.drift import drift_evidence
    from helicalib.campaign.events import iso_utc
    from helicalib.campaign.policy import NO_EPOCH, fit_size, prediction_error_mrad, stored_basis, stored_epochs

    limit = float(cfg.acceptance.max_rms_mrad)
    rows = []
    operated: dict[int, bool] = {}  # campaign id -> went into operation (one store read per campaign)
    for hid in runner.ids:
        first = next((p for p in runner.book.points(hid) if p.iteration == 0), None)
        latest = runner.store.latest_fit(hid)
        row = {"heliostat": hid, "visits": runner.book.h[hid].visits, "limit_mrad": limit,
               "present_error_mrad": None, "formula1_error_mrad": None, "calibrated": latest is not None,
               "drift": None, "next_chance": None}
        if first is None:
            visits = runner.store.visits(campaign_id=runner.campaign_id, heliostat_id=hid)
            why, next_s = (visits[-1].reason, None) if visits else not_visited_because(cfg, runner)
            row["verdict"] = f"not measured: {why}"
            row["next_chance"] = None if next_s is None else iso_utc(next_s)
        else:
            err = prediction_error_mrad(runner.models[hid], first, cfg.target(first.target_id))
            if latest is not None:
                # the points the stored fit stood on (its campaign's book then: since a drift or repair,
                # thinned to the visit cap), or no evidence
                epochs = stored_epochs(runner.store, latest.campaign_id, latest.time_s)
                points, centre, earlier = stored_basis(runner.store, latest.campaign_id, hid, latest.time_s, epochs)
                if fit_size(points, earlier) == latest.n_points:
                    # fitted as that fit was (an operated campaign's fits model a settling pedestal)
                    if latest.campaign_id not in operated:
                        operated[latest.campaign_id] = op_rules.was_operated(runner.store, latest.campaign_id)
                    ep = epochs.get(hid, NO_EPOCH)
                    newest = max(p.capture_time_s for p in points) if points else -math.inf
                    row["drift"] = drift_evidence(runner.nominal_of(hid), runner.models[hid], points, first,
                                                  prior_mean=centre, earlier=earlier,
                                                  tilt_rate=op_rules.fits_tilt_rate(operated[latest.campaign_id],
                                                                                    ep.drifted, newest, ep.confirmed_s,
                                                                                    epochs=earlier is not None))
            drifted = bool(row["drift"] and row["drift"]["drift"])
            row.update(present_error_mrad=round(err, 3), formula1_error_mrad=round(float(first.error_mrad), 3),
                       verdict=("in spec" if err <= limit else
                                "out of spec: recalibrate (helicalib run --arm)" if row["calibrated"] else
                                "out of spec: never calibrated in this database (nominal model)")
                       + ("; suspected drift: outside the band its fit predicts here (check again: outside twice, "
                          "it has changed since its calibration)" if drifted else ""))
        rows.append(row)
    return rows


def not_visited_because(cfg, runner) -> tuple[str, float | None]:
    """Why a check's heliostat got no visit, exactly, and when it can be measured next (plant time,
    or None when that is not the sun's to say): not armed; the plant unreachable; the field stowed;
    night (the sun's elevation, and when it next rises past the low band's lower edge); the gate
    (which reason); or no board time within ``--hours``."""
    from helicalib.campaign.events import iso_utc

    now = runner.safe_now()[0]
    lo = float(cfg.acceptance.low_band_deg[0])
    el = float(runner.sun(now)[2])
    if not runner.armed:
        return "not armed: a check without --arm writes nothing to the plant, so no heliostat goes onto a board " \
               "(add --arm)", None
    if runner.plant_unreachable_since_s is not None:
        return f"the plant did not answer (unreachable since {iso_utc(runner.plant_unreachable_since_s)})", None
    if el < lo:
        rise = next_sun_above(runner.sun, now, lo)
        when = "not within 2 days" if rise is None else f"at {iso_utc(rise)} (in {(rise - now) / 3600.0:.1f} h)"
        return (f"night: the sun is at {el:.1f}°, below the low band's {lo:g}°; it rises past {lo:g}° {when}: "
                "check again then"), rise
    if runner.stowed:
        return "the field is stowed for wind: check again once the wind allows", None
    gate = runner._last_gate
    if gate is not None and not gate.open:
        return f"calibration gated: {gate.reason}", None
    return "no board time for it before the check's end (--hours)", None


def next_sun_above(sun, now_s: float, level_deg: float, step_s: float = 300.0, days: float = 2.0) -> float | None:
    """The first plant time after ``now_s`` (to ``step_s``) with the sun at ``level_deg`` or higher
    and rising, within ``days``; None if none."""
    t = now_s
    while t < now_s + days * 86400.0:
        t += step_s
        if sun(t)[2] >= level_deg:
            return t
    return None


def plural(n: int, noun: str) -> str:
    """``1 heliostat``, ``2 heliostats``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _print_summary(s: dict, mode: str) -> None:
    if mode == "check":
        for r in s["rechecks"]:
            if r["present_error_mrad"] is None:
                print(f"{r['heliostat']}: {r['verdict']}")
            else:
                model = "" if r["calibrated"] else " (no fit in this database: nominal model)"
                d = r.get("drift")
                band = (f"; the fit predicts {d['band_mrad']:.2f} mrad here (1 sigma), p = {d['p_value']:.2g}"
                        if d else "")
                print(f"{r['heliostat']}: present error {r['present_error_mrad']:.2f} mrad (beam angle; formula (1) "
                      f"on the board {r['formula1_error_mrad']:.2f}), limit {r['limit_mrad']:g} mrad{band}: "
                      f"{r['verdict']}{model}")
    visits = plural(s["visits_this_run"], "visit")
    observations = plural(s["observations"], "observation")
    if mode == "check":
        measured = sum(1 for r in s["rechecks"] if r["present_error_mrad"] is not None)
        print(f"campaign {s['campaign']} {s['status']} ({s['ended_because']}): {measured} of "
              f"{plural(s['heliostats'], 'heliostat')} measured, {visits} this run, {observations} in {s['database']}"
              + ("" if measured == s["heliostats"] or s["stopped_by"] == "stopped" else
                 f" (not all measured: exit status {EXIT_NOT_MEASURED})"))
    else:
        print(f"campaign {s['campaign']} {s['status']} ({s['ended_because']}): {s['accepted']} of "
              f"{plural(s['heliostats'], 'heliostat')} accepted, {visits} this run, {observations} in {s['database']}")
    if "operation" in s:
        drifts = s["drifts"]
        print(f"operation ({s['operation']}): {s['checks_this_run']} checks this run; "
              + (f"drift confirmed on {', '.join(d['heliostat_id'] for d in drifts)}" if drifts else "no drift confirmed"))
    if s["off_tracking"]:
        print(f"WARNING: not confirmed back to tracking: {', '.join(s['off_tracking'])} (the next run retries them "
              "first)", file=sys.stderr)
