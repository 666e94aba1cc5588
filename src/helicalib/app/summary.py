"""What a live session leaves on the screen: its summary, and each re-checked heliostat's verdict.

:func:`session_summary` is the dictionary ``--json`` prints as the last line (``"event":
"summary"``); :func:`print_summary` the same in sentences. A ``check`` adds one row per
re-checked heliostat (:func:`recheck_rows`): its present error beside the acceptance limit, or
exactly why it could not be measured and when it can be next (:func:`not_visited_because`).
"""

from __future__ import annotations

import math
import sys

from helicalib.app.opening import Opened, plural

EXIT_NOT_MEASURED = 3
"""``check``: a heliostat could not be measured (night, gated, not armed, no visit in time)."""


def session_summary(store, cfg, runner, opened: Opened, result, mode: str) -> dict:
    """The session's summary (``--json``'s last line): how it ended, what this run did, what the campaign holds."""
    campaign = store.campaign(opened.campaign_id)
    status = "stopped (not recorded: the database cannot be written)" if result.reason == "storage" else campaign.status
    out = {"event": "summary", "campaign": opened.campaign_id, "mode": campaign.mode, "status": status,
           "ended_because": {"until": "its end time came", "done": "every heliostat re-checked",
                             "stopped": "Ctrl-C or SIGTERM", "clock_jump": "the plant's clock jumped",
                             "storage": "the database cannot be written"}[result.reason],
           "stopped_by": result.reason, "armed": runner.state.armed, "heliostats": len(runner.state.ids),
           "accepted": len(runner.accepted()),
           "visits_this_run": runner.state.stats.visits, "valid_visits_this_run": runner.state.stats.valid_visits,
           "outcomes_this_run": dict(runner.state.stats.outcomes),
           "observations": store.count_observations(opened.campaign_id),
           "valid_observations": store.count_observations(opened.campaign_id, valid=True),
           "off_tracking": list(result.off_tracking), "database": str(cfg.database_path)}
    if runner.state.operation is not None:
        out.update(operation=runner.state.operation, checks_this_run=runner.ops.checks,
                   drifts=[{k: d.get(k) for k in ("heliostat_id", "since_s", "confirmed_s", "fixed_s", "evidence")}
                           for d in runner.ops.drifts])
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
    from helicalib.campaign.basis import stored_basis
    from helicalib.campaign.book import fit_size
    from helicalib.campaign.verdict import prediction_error_mrad
    from helicalib.store.history import NO_EPOCH, stored_epochs, was_operated

    limit = float(cfg.acceptance.max_rms_mrad)
    rows = []
    operated: dict[int, bool] = {}  # campaign id -> went into operation (one store read per campaign)
    for hid in runner.state.ids:
        first = next((p for p in runner.state.book.points(hid) if p.iteration == 0), None)
        latest = runner.devices.store.latest_fit(hid)
        row = {"heliostat": hid, "visits": runner.state.book.h[hid].visits, "limit_mrad": limit,
               "present_error_mrad": None, "formula1_error_mrad": None, "calibrated": latest is not None,
               "drift": None, "next_chance": None}
        if first is None:
            visits = runner.devices.store.visits(campaign_id=runner.campaign_id, heliostat_id=hid)
            why, next_s = (visits[-1].reason, None) if visits else not_visited_because(cfg, runner)
            row["verdict"] = f"not measured: {why}"
            row["next_chance"] = None if next_s is None else iso_utc(next_s)
        else:
            err = prediction_error_mrad(runner.state.models[hid], first, cfg.target(first.target_id))
            if latest is not None:
                # the points the stored fit stood on (its campaign's book then: since a drift or repair,
                # thinned to the visit cap), or no evidence
                epochs = stored_epochs(runner.devices.store, latest.campaign_id, latest.time_s)
                points, centre, earlier = stored_basis(runner.devices.store, latest.campaign_id, hid, latest.time_s,
                                                       epochs)
                if fit_size(points, earlier) == latest.n_points:
                    # fitted as that fit was (an operated campaign's fits model a settling pedestal)
                    if latest.campaign_id not in operated:
                        operated[latest.campaign_id] = was_operated(runner.devices.store, latest.campaign_id)
                    ep = epochs.get(hid, NO_EPOCH)
                    newest = max(p.capture_time_s for p in points) if points else -math.inf
                    row["drift"] = drift_evidence(runner.state.nominal_of(hid), runner.state.models[hid], points, first,
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

    now = runner.journal.safe_now()[0]
    lo = float(cfg.acceptance.low_band_deg[0])
    el = float(runner.sun(now)[2])
    if not runner.state.armed:
        return "not armed: a check without --arm writes nothing to the plant, so no heliostat goes onto a board " \
               "(add --arm)", None
    if runner.state.faults.plant_unreachable_since_s is not None:
        since_s = runner.state.faults.plant_unreachable_since_s
        return f"the plant did not answer (unreachable since {iso_utc(since_s)})", None
    if el < lo:
        rise = next_sun_above(runner.sun, now, lo)
        when = "not within 2 days" if rise is None else f"at {iso_utc(rise)} (in {(rise - now) / 3600.0:.1f} h)"
        return (f"night: the sun is at {el:.1f}°, below the low band's {lo:g}°; it rises past {lo:g}° {when}: "
                "check again then"), rise
    if runner.state.stowed:
        return "the field is stowed for wind: check again once the wind allows", None
    gate = runner.state.last_gate
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


def print_summary(s: dict, mode: str) -> None:
    """:func:`session_summary` in sentences on stdout (the run's warnings on stderr)."""
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
