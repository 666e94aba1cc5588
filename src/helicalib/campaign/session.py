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
  of ``--until``/``--days`` (or of a check) ``finished``.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

from helicalib.errors import ConfigError

RUN_KINDS = ("live", "dry-run")


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


def open_campaign(store, cfg, args, mode: str, now_s: float, ids: list[str] | None) -> Opened:
    """Resume or start the session's campaign; the returned line says which and what it holds."""
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
            raise ConfigError(f"--heliostats: campaign {resumed.id} calibrates {len(held)} heliostat(s), not the "
                              f"{len(ids)} named; resume it without --heliostats, or add --new-campaign")
        was = resumed.status
        store.reopen_campaign(resumed.id)
        return Opened(resumed.id, held, f"campaign {resumed.id} ({_label(kind)}, resumed; it was {was}): "
                                        + holdings(store, resumed.id, held) + f"; database {store.path}")
    ids = ids or [h.id for h in cfg.heliostats]
    name = {"live": f"{'live' if armed else 'dry run'} {cfg.site.name}", "check": f"check {cfg.site.name}"}[mode]
    cid = store.start_campaign(
        name=name, mode=run_mode if mode == "live" else "check", started_s=now_s,
        heliostats=[(hid, cfg.heliostat_index(hid), cfg.heliostat(hid).target) for hid in ids],
        config_path=str(cfg.source), settings={"armed": armed, "planner": args.planner,
                                               "refine": getattr(args, "refine", False)})
    what = "re-check" if mode == "check" else _label(kind)
    return Opened(cid, ids, f"campaign {cid} ({what}, new): {len(ids)} heliostats{skipped}; database {store.path}")


def _label(kind: str) -> str:
    return "armed" if kind == "armed" else "dry run: nothing is written to the plant"


def holdings(store, campaign_id: int, ids: list[str]) -> str:
    """What a campaign holds, in one clause: heliostats, accepted, observations, visits."""
    verdicts = store.latest_verdicts(campaign_id)
    accepted = sum(1 for h in ids if verdicts.get(h) is not None and verdicts[h].accepted)
    n_obs = store.count_observations(campaign_id)
    n_valid = store.count_observations(campaign_id, valid=True)
    visits = len(store.visits(campaign_id=campaign_id))
    return (f"{len(ids)} heliostats, {accepted} accepted, {n_obs} observations ({n_valid} valid) in {visits} visits")


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

    from helicalib.campaign.console import make_output, site_timezone
    from helicalib.campaign.live import run_live
    from helicalib.campaign.runner import CampaignRunner
    from helicalib.config import load_field_config
    from helicalib.console.server import attach_console
    from helicalib.devices.camera_http import cameras_from_config
    from helicalib.devices.clock import make_clock
    from helicalib.devices.modbus import ModbusPlant
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.store.sqlite import Store

    cfg = load_field_config(args.field)
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
    store = Store.open(cfg.database_path, cfg.images_path, owner=f"{command} {cfg.source}")
    plant = None
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
        opened = open_campaign(store, cfg, args, mode, now, ids)
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
        if operation and getattr(args, "keep_frames", None) is not None:
            runner.retention = (int(args.keep_frames), True)  # every night: frames of the newest N and the rejected
        output = attach_console(args, runner, output)  # operator actions; the crew console with --console
        orphans = store.remove_orphan_frames(opened.campaign_id)
        if orphans:
            output.message(f"removed {orphans} frame file(s) no observation points to (a visit the previous "
                           "process was killed in)")
        result = run_live(runner, until_s, done=(runner.rechecked if args.recheck else None), output=output)
        end_s = runner.safe_now()[0]
        store.finish_campaign(opened.campaign_id, end_s, status="stopped" if result.reason == "stopped" else "finished")
        summary = _summary(store, cfg, runner, opened, result, mode)
    finally:
        if plant is not None:
            plant.close()
        store.close()
    if as_json:
        output.emit(summary)
    else:
        _print_summary(summary, mode)
    return 0


def _summary(store, cfg, runner, opened: Opened, result, mode: str) -> dict:
    campaign = store.campaign(opened.campaign_id)
    out = {"event": "summary", "campaign": opened.campaign_id, "mode": campaign.mode, "status": campaign.status,
           "ended_because": {"until": "its end time came", "done": "every heliostat re-checked",
                             "stopped": "Ctrl-C or SIGTERM"}[result.reason],
           "armed": runner.armed, "heliostats": len(runner.ids), "accepted": len(runner.accepted()),
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
    predicts for it (:mod:`helicalib.campaign.drift`); outside it, the heliostat changed since."""
    from helicalib.campaign import operation as op_rules
    from helicalib.campaign.drift import drift_evidence
    from helicalib.campaign.policy import NO_EPOCH, fit_size, prediction_error_mrad, stored_basis, stored_epochs

    limit = float(cfg.acceptance.max_rms_mrad)
    rows = []
    operated: dict[int, bool] = {}  # campaign id -> went into operation (one store read per campaign)
    for hid in runner.ids:
        first = next((p for p in runner.book.points(hid) if p.iteration == 0), None)
        latest = runner.store.latest_fit(hid)
        row = {"heliostat": hid, "visits": runner.book.h[hid].visits, "limit_mrad": limit,
               "present_error_mrad": None, "formula1_error_mrad": None, "calibrated": latest is not None,
               "drift": None}
        if first is None:
            visits = runner.store.visits(campaign_id=runner.campaign_id, heliostat_id=hid)
            why = visits[-1].reason if visits else "no visit (gated, night or not armed)"
            row["verdict"] = f"not measured: {why}"
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
    print(f"campaign {s['campaign']} {s['status']} ({s['ended_because']}): {s['accepted']}/{s['heliostats']} accepted, "
          f"{s['visits_this_run']} visits this run, {s['observations']} observations in {s['database']}")
    if "operation" in s:
        drifts = s["drifts"]
        print(f"operation ({s['operation']}): {s['checks_this_run']} checks this run; "
              + (f"drift confirmed on {', '.join(d['heliostat_id'] for d in drifts)}" if drifts else "no drift confirmed"))
    if s["off_tracking"]:
        print(f"WARNING: not confirmed back to tracking: {', '.join(s['off_tracking'])} (the next run retries them "
              "first)", file=sys.stderr)
