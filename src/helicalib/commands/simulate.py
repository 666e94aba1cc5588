"""``helicalib simulate FIELD --days N --seed S --out DIR``: a whole campaign on the simulated plant.

With ``--workers N`` or ``--scheduler ADDR`` the campaign is split over a Dask cluster
(:mod:`helicalib.app.split`; the cluster is :func:`helicalib.app.cluster.cluster_for`, the one
``sweep`` uses): a line per group of boards as it ends, tasks done of all and the elapsed time
while they run, then the merged summary as one run's. The exit status is then 1 when a group
failed (the merged database holds the others; the summary's ``split.failed`` says which and why).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from helicalib.commands._args import (add_register_map, add_spots, float_in, int_in, iso_time, nonnegative_int,
                                      positive_float)
from helicalib.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run a calibration campaign against the simulated plant",
                       description="A whole campaign against the simulated plant: in-process on a virtual clock "
                                   "(fast), or over loopback Modbus TCP + HTTP with --over-network. Writes the "
                                   "database, frames, observations.csv and summary.json into --out.")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--days", type=float_in(0.0, 3660.0, open_lo=True), default=3.0, help="plant days to simulate (default 3)")
    p.add_argument("--seed", type=nonnegative_int, default=1, help="seed of the hidden errors, weather and noise (default 1)")
    p.add_argument("--out", required=True, help="output folder (database, images, summary): new, empty or a previous simulate output "
                        "(its unfinished campaign resumes); any other folder is refused")
    p.add_argument("--scenario", default=None, help="scenario YAML (weather, errors, faults; see docs/simulator.md)")
    p.add_argument("--start", default=None, type=iso_time, help="plant start time, ISO 8601 with offset (default 2026-06-01, local midnight)")
    p.add_argument("--planner", choices=("gaps", "round-robin"), default="gaps",
                   help="who goes next: fill acceptance gaps fastest (default) or the paper's round robin")
    p.add_argument("--refine", action="store_true",
                   help="gaps planner: spend target time no acceptance gap needs on the heliostats whose model is "
                        "most uncertain at the present sun, accepted ones included (better year-round accuracy)")
    p.add_argument("--heliostats", default=None, help="comma-separated heliostat ids (default all)")
    p.add_argument("--over-network", action="store_true", help="serve the plant on loopback and use the real clients")
    p.add_argument("--rate", type=positive_float, default=3000.0, help="plant time rate with --over-network (default 3000)")
    p.add_argument("--protocol", choices=("modbus", "opcua"), default="modbus",
                   help="with --over-network: serve and reach the SCS over Modbus TCP (default) or OPC UA")
    add_register_map(p)
    p.add_argument("--lockstep", action="store_true",
                   help="with --over-network: the served plant keeps the controller's virtual clock (a repeatable "
                        "run: the same seed gives the same campaign over any protocol or register map)")
    p.add_argument("--fidelity", choices=("render", "fast"), default="render",
                   help="render (default): every frame drawn and measured by the vision; fast: the simulator's "
                        "true spot plus the fitted measurement-error model, no frames (large fields; "
                        "docs/simulator.md)")
    p.add_argument("--drift-share", type=float_in(0.0, 1.0), default=None, metavar="F",
                   help="this share of the heliostats drifts once during the run (a pedestal settling, an "
                        "actuator swapped or a slow creep, at a random time after the first day; the scenario's "
                        "drift section otherwise; docs/simulator.md)")
    p.add_argument("--operate", nargs="?", const="ranked", choices=("ranked", "rota"), default=None,
                   help="after (or during) the campaign, year-round operation for the rest of --days: checks of "
                        "fitted heliostats ranked by the expected reduction of the year-round error (default), or "
                        "'rota' (every heliostat every --rota-days, the baseline); drift confirmed by checks reopens "
                        "the calibration (docs/operation.md)")
    p.add_argument("--rota-days", type=positive_float, default=14.0,
                   help="--operate rota: days between checks of each heliostat (default 14)")
    p.add_argument("--keep-frames", type=nonnegative_int, default=None, metavar="N",
                   help="every night delete the frames of all but each heliostat's newest N observations and of the "
                        "rejected ones, as helicalib operate does (default: keep every frame)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--report", action="store_true", help="also write the HTML report into OUT/report")
    add_spots(p)
    p.add_argument("--workers", type=int_in(1, 4096), default=None, metavar="N",
                   help="split the field into groups of boards run side by side on an embedded Dask cluster of N "
                        "worker processes on 127.0.0.1, then merge them into one database (docs/simulator.md)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                   help="split the field over the workers of this existing Dask cluster instead")
    p.add_argument("--groups", type=int_in(1, 100_000), default=None, metavar="K",
                   help="with --workers/--scheduler: groups of boards (default: one per worker, at most one per board)")
    p.set_defaults(func=run)


@dataclass(frozen=True)
class Inputs:
    """What a simulated campaign reads, checked (:func:`read_inputs`)."""

    cfg: Any
    scenario: Any
    start_s: float | None
    heliostat_ids: list[str] | None


def read_inputs(args) -> Inputs:
    """The field config (with cameras), ``--days``, the scenario (and ``--drift-share``), ``--start`` and
    ``--heliostats``, checked: a ConfigError here comes before any folder is touched (``demo`` calls
    this before it replaces its folder too)."""
    from helicalib.config import load_field_config
    from helicalib.errors import ConfigError
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.sim.scenario import load_scenario

    cfg = load_field_config(args.field)
    cfg.require_cameras()  # a PAINT import describes a plant; it cannot be measured
    if args.days <= 0:
        raise ConfigError(f"--days {args.days}: must be > 0")
    scenario = load_scenario(args.scenario)
    if args.drift_share is not None:
        scenario = with_drift_share(scenario, args.drift_share, args.days)
    start_s = float(to_unix_seconds([parse_time(args.start)])[0]) if args.start else None
    ids = [s.strip() for s in args.heliostats.split(",")] if args.heliostats else None
    if ids:
        for hid in ids:
            cfg.heliostat(hid)
    return Inputs(cfg, scenario, start_s, ids)


def run(args) -> int:
    from helicalib.outdir import check, prepare

    inputs = read_inputs(args)
    check(args.out, "simulate")
    if args.workers or args.scheduler or args.groups:
        check_split(args)
    if args.report:   # OUT/report is replaced after the campaign: a folder that may not be is refused now
        check(Path(args.out) / "report", "report", inputs=(args.field, args.scenario))
    if args.workers or args.scheduler:
        return run_split(args, inputs, prepare(args.out, "simulate"))
    return run_campaign(args, inputs, prepare(args.out, "simulate"))


def run_campaign(args, inputs: Inputs, out: Path) -> int:
    """The campaign of ``args`` into ``out`` (checked and marked by the caller), then its summary and
    report."""
    from helicalib.app.simulated import simulate_campaign
    from helicalib.commands._progress import ProgressReporter

    cfg = inputs.cfg
    with ProgressReporter("simulate", args.days * 86400.0, transient=args.json) as bar:
        state = {"t0": None}

        def progress(now_s: float) -> None:
            if state["t0"] is None:
                state["t0"] = now_s
            done = now_s - state["t0"]
            bar.update(done, lambda: _progress_text(done, args.days, out / "helicalib.db"))

        options = simulation_options(args, inputs)
        result = simulate_campaign(cfg, out, options, progress=progress)
    finish(args, result.summary, result.database, out)
    return 0


def finish(args, summary: dict, database: Path, out: Path) -> None:
    """Write ``summary.json`` (and with ``--report`` the report of ``database``), then print the
    summary: as JSON with ``--json``, else in a few lines."""
    from helicalib.commands._progress import timed_step
    from helicalib.outdir import prepare

    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if args.report:
        from helicalib.report.build import build_report

        with timed_step("simulate", f"building the report in {out / 'report'}"):
            build_report(database, prepare(out / "report", "report", replace=True))
    if args.json:
        print(json.dumps(summary, indent=2))
        return
    s = summary
    print(f"{s['accepted']}/{s['heliostats']} heliostats accepted ({100 * s['acceptance_rate']:.0f} %) after "
          f"{s['days']} days; {s['visits']} visits ({s['valid_visits']} valid), "
          f"{s['visits_per_target_hour']} visits per target-hour")
    print(f"first-shot RMS (last day) {s['first_shot_rms_mrad']} mrad; simulator truth: calibrated models "
          f"{s['true_sky_rms_mrad']} mrad RMS over a year of sun, the plant's tracking {s['true_tracking_rms_mrad']} "
          f"mrad (uncorrected {s['true_tracking_uncorrected_rms_mrad']}); gated {s['gated_hours']} h, "
          f"stowed {s['stowed_hours']} h")
    if s.get("monthly_plant_tracking_rms_mrad"):
        print("the plant's true tracking per 30 days [mrad RMS]: "
              + ", ".join("-" if m is None else f"{m:.2f}" for m in s["monthly_plant_tracking_rms_mrad"]))
    if args.operate:
        print(f"operation: {s['checks']} checks; drift in {s['drifted']} heliostat(s), {s['drift_detected']} "
              f"detected ({s['drift_false_alarms']} false alarms), median {s['drift_median_days_to_fix']} days "
              f"to fix; board time after commissioning {s['board_time_share_after_commissioning']}")
    print(f"written {out / 'summary.json'} and {database}")


def simulation_options(args, inputs: Inputs):
    """The :class:`~helicalib.app.simulated.SimulationOptions` of ``args``."""
    from helicalib.app.simulated import SimulationOptions

    return SimulationOptions(args.days, seed=args.seed, scenario=inputs.scenario, start_s=inputs.start_s,
                             over_network=args.over_network, planner=args.planner, heliostat_ids=inputs.heliostat_ids,
                             rate=args.rate, refine=args.refine, fidelity=args.fidelity, operation=args.operate,
                             rota_days=args.rota_days, keep_frames=args.keep_frames,
                             spots_per_board=args.spots_per_board, protocol=args.protocol,
                             register_map=args.register_map, lockstep=args.lockstep)


# ---------------------------------------------------------------- split over a Dask cluster
TASK_MODULE = "helicalib.app.split"
"""The module a split's workers run (checked on every worker of ``--scheduler``)."""


def check_split(args) -> None:
    """Refuse options a split run cannot take, before any folder is touched."""
    if args.workers and args.scheduler:
        raise ConfigError("--workers sizes an embedded cluster; with --scheduler the cluster's own workers run")
    if args.groups and not (args.workers or args.scheduler):
        raise ConfigError("--groups splits the field over a cluster: add --workers N or --scheduler ADDR")
    if args.over_network:
        raise ConfigError("--over-network serves one plant on loopback; it cannot be split over --workers/--scheduler")
    if (Path(args.out) / "helicalib.db").exists():
        raise ConfigError(f"--out {args.out}: holds a database already; a split simulation does not resume "
                          "(give a new or empty folder)")


def run_split(args, inputs, out: Path) -> int:
    """The split campaign of ``args`` into ``out`` (checked and marked by the caller)."""
    from helicalib.app.cluster import cluster_for
    from helicalib.app.split import simulate_split
    from helicalib.commands._progress import ProgressReporter, TaskTally

    workers = args.workers or len(os.sched_getaffinity(0))
    options = simulation_options(args, inputs)
    with ProgressReporter("simulate", None, transient=args.json) as bar, \
            cluster_for(args.scheduler, workers, TASK_MODULE) as client:
        n_groups = args.groups or (len(client.nthreads()) if args.scheduler else workers)
        tally = TaskTally(bar, "simulate", "groups done")

        def on_start(groups) -> None:
            tally.total = len(groups)
            bar.note(f"simulate: {len(groups)} groups of boards ("
                     + "; ".join(f"{', '.join(g.boards)}: {len(g.heliostats)} heliostats" for g in groups)
                     + f") on {args.scheduler or f'{workers} local worker processes'}")
            bar.update(0, f"0 of {len(groups)} groups done", total=len(groups))

        def on_group(group, reason) -> None:
            tally.ended(reason)

        result = simulate_split(inputs.cfg, args.field, out, options, client, n_groups,
                                on_start=on_start, on_group=on_group)
    if "accepted" in result.summary:
        finish(args, result.summary, result.database, out)
    else:  # no group finished: nothing to print but what is missing
        (out / "summary.json").write_text(json.dumps(result.summary, indent=2))
        if args.json:
            print(json.dumps(result.summary, indent=2))
    if result.failures:
        print(f"simulate: {len(result.failures)} of {result.summary['split']['groups']} groups failed "
              f"({result.summary['split']['missing_heliostats']} heliostats not simulated); their reasons are in "
              f"{out / 'summary.json'} (split.failed), the tracebacks in {out / 'failed_groups.log'}", file=sys.stderr)
        return 1
    return 0


def _progress_text(done_s: float, days: float, db_path) -> str:
    """``day 0.42 of 2, 113 visits, 12 accepted`` (the counts read from the campaign's database)."""
    text = f"day {done_s / 86400:.2f} of {days:g}"
    counts = campaign_counts(db_path)
    if counts is not None:
        text += f", {counts[0]} visits, {counts[1]} accepted"
    return text


def campaign_counts(db_path) -> tuple[int, int] | None:
    """(visits, heliostats accepted by their latest verdict) of the newest campaign, read-only; None if
    the database cannot be read yet."""
    import sqlite3

    try:
        con = sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=0.2)
    except sqlite3.Error:
        return None
    try:
        cid = con.execute("SELECT max(id) FROM campaigns").fetchone()[0]
        if cid is None:
            return None
        visits = con.execute("SELECT count(*) FROM visits WHERE campaign_id = ?", (cid,)).fetchone()[0]
        accepted = con.execute(
            "SELECT count(*) FROM verdicts v WHERE v.campaign_id = ? AND v.accepted = 1 AND v.id = "
            "(SELECT max(w.id) FROM verdicts w WHERE w.campaign_id = v.campaign_id AND w.heliostat_id = v.heliostat_id)",
            (cid,)).fetchone()[0]
        return int(visits), int(accepted)
    except sqlite3.Error:
        return None
    finally:
        con.close()


def with_drift_share(scenario, share: float, days: float):
    """``scenario`` with ``drift.share`` set and the events spread over the run (after its first day,
    or its first tenth when shorter)."""
    from helicalib.sim.scenario import parse_scenario

    after = min(scenario.drift.after_days, 0.1 * days)
    drift = dict(scenario.drift.model_dump(), share=share, after_days=after, within_days=days - after)
    return parse_scenario({**scenario.model_dump(), "drift": drift}, "--drift-share")
