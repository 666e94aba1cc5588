"""Band throughput against the band-capacity bound: how fast a field can be accepted, and how fast it is.

The paper's acceptance rule (1) needs a valid point while the sun rises through the 5–15° band and
one while it sets through it. A board takes at most ``rate`` heliostats an hour through a band, so
a field of ``N`` heliostats on ``B`` boards cannot have 95 % accepted before both the rising and
the setting crossings have offered ``0.95 N`` band points: the **band-capacity bound**. This
benchmark computes it from the field's own band crossings (the SPA sun at its site, from the start
date) for the measured band rates one at a time and with turns (``--rate-one``, ``--rate-turns``:
heliostats with a band point per board-hour), runs a simulated campaign (or reads a finished or
interrupted one's database) and prints, against the bound:

* days to 90 % and 95 % accepted (the store's verdict timeline);
* per band crossing: its hours, the hours the weather left open (the run's gated / ungated events),
  visits started and heliostats with a valid point in it, band points per board-hour;
* the bound again at the run's own band rate, and with the run's weather (open hours only); the
  run's rate is taken over the crossings after which heliostats that got that band's point later
  still lacked it (1 % of the field or more: the boards were the limit, not the heliostats left
  to serve), or over all its crossings if none was.

A run resumes where an interrupted one stopped (its database in ``--work``; ``--fresh`` starts
over); ``--db`` reads a database without running anything. Progress (plant day and hour, accepted,
wall time) goes to stderr every plant hour.

Usage::

    .venv/bin/python benchmarks/bench_band.py                                  # bench500, equinox, 1 day, turns
    .venv/bin/python benchmarks/bench_band.py --spots-per-board 1 --seed 2
    .venv/bin/python benchmarks/bench_band.py --seeds 1,2,3 --work benchmarks/out/band3       # the seed mean
    .venv/bin/python benchmarks/bench_band.py --field benchmarks/out/field10k.yaml --n 10000 --targets 8 --days 20
    .venv/bin/python benchmarks/bench_band.py --db benchmarks/out/band/helicalib.db --json

``--field`` that does not exist is generated (``helicalib sim-field --n N --targets T`` at the
demo site). Writes ``benchmarks/out/bench_band.json`` (git-ignored).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sqlite3
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "simulations" / "fields" / "bench500.yaml"
SCENARIO = ROOT / "simulations" / "scenarios" / "benchmark.yaml"
OUT = ROOT / "benchmarks" / "out"
SITE = (40.063, 94.426, 1267.0)
EQUINOX = "2026-09-22T00:00:00+06:18"
RATE_ONE = 80.0
"""Heliostats with a band point per board-hour, one visit on a board at a time: bench500 at the
equinox, fast fidelity, 265 and 307 heliostats in the first 0.89 h crossings on 4 boards
(measured 2026-11-26, before the one-point band visit; docs/benchmarks.md)."""
HORIZON_DAYS = 45.0
"""Days of band crossings over which the bound is looked for (a slower field's is "not within")."""
RATE_TURNS = 140.0
"""The same with three visits per board whose beams take turns (``--spots-per-board auto``) and one
point per visit in the band: 499 heliostats in the first rising crossing (0.89 h, 4 boards;
measured 2026-11-28, docs/benchmarks.md "Band throughput at the physical bound")."""


@dataclass(frozen=True)
class Crossing:
    """One crossing of the acceptance's low band: ``kind`` rising or setting, from ``start_s`` to
    ``end_s`` [UTC s], on plant day ``day`` of the run."""

    kind: str
    day: int
    start_s: float
    end_s: float

    @property
    def hours(self) -> float:
        return (self.end_s - self.start_s) / 3600.0


def crossings(cfg, start_s: float, end_s: float) -> list[Crossing]:
    """The field's band crossings between ``start_s`` and ``end_s`` (cut to them), in time order
    (the sun every 2 minutes, crossings interpolated, as the campaign's book times them)."""
    from helicalib.calibration.sun_days import sun_days

    acc = cfg.acceptance
    out = []
    for d in sun_days(cfg.site, start_s, end_s, acc.low_band_deg, acc.high_elevation_deg, step_s=120.0):
        for kind, a, b in (("rising", d.rise_band_start_s, d.rise_band_end_s),
                           ("setting", d.set_band_start_s, d.set_band_end_s)):
            if a is None or b is None:
                continue
            a, b = max(a, start_s), min(b, end_s)
            if b > a:
                out.append(Crossing(kind, int((a - start_s) // 86400), float(a), float(b)))
    return sorted(out, key=lambda c: c.start_s)


def capacity_bound(cross: list[Crossing], n: int, boards: int, rate: float, fraction: float,
                   hours: list[float] | None = None) -> float | None:
    """The band-capacity bound [UTC s]: the earliest time at which both the rising and the setting
    crossings so far can have given ``ceil(fraction * n)`` heliostats a band point, at ``rate``
    heliostats per board-hour on ``boards`` boards (each crossing's capacity accrues evenly over
    it); None if ``cross`` does not get there. ``hours``: each crossing's usable hours (default
    its length; e.g. the hours the weather left open)."""
    need = math.ceil(fraction * n - 1e-9)
    if need <= 0:
        return cross[0].start_s if cross else None
    done = {"rising": 0.0, "setting": 0.0}
    reached: dict[str, float] = {}
    for k, c in enumerate(cross):
        usable = c.hours if hours is None else hours[k]
        cap = boards * rate * usable
        if c.kind not in reached and cap > 0 and done[c.kind] + cap >= need:
            share = (need - done[c.kind]) / cap  # the capacity accrues over the crossing's usable part
            reached[c.kind] = c.start_s + share * (c.end_s - c.start_s)
        done[c.kind] += cap
        if len(reached) == 2:
            return max(reached.values())
    return None


VISIT_STARTS = "SELECT started_s FROM visits WHERE campaign_id = ?"
VALID_POINTS = ("SELECT capture_time_s, heliostat_id FROM observations WHERE campaign_id = ? AND valid = 1 "
                "AND iteration >= 0")
"""The latest campaign's visit starts, and its valid points (time, heliostat) (:func:`latest_rows`)."""


def latest_rows(db: Path, *queries: tuple[str, tuple]) -> list[list[tuple]]:
    """The rows of each ``(sql, params)`` for the latest campaign of ``db`` (read-only): each query's
    first ``?`` is the campaign id, ``params`` fill the rest."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        cid = con.execute("SELECT id FROM campaigns ORDER BY id DESC LIMIT 1").fetchone()[0]
        return [con.execute(sql, (cid, *params)).fetchall() for sql, params in queries]
    finally:
        con.close()


def open_hours(db: Path, cross: list[Crossing]) -> list[float]:
    """Each crossing's hours with the field gate open, from the run's ``gated`` / ``ungated`` events
    (the weather: DNI, wind); the gate counts as open at the start until an event says otherwise."""
    gated = "SELECT time_s, kind FROM events WHERE campaign_id = ? AND kind IN ('gated', 'ungated') ORDER BY time_s, id"
    (events,) = latest_rows(db, (gated, ()))
    out = []
    for c in cross:
        before = [k for t, k in events if t <= c.start_s]
        is_open = not before or before[-1] == "ungated"
        t0, total = c.start_s, 0.0
        for t, kind in events:
            if c.start_s < t < c.end_s:
                if is_open:
                    total += t - t0
                is_open, t0 = kind == "ungated", t
        if is_open:
            total += c.end_s - t0
        out.append(total / 3600.0)
    return out


def crossing_stats(db: Path, cross: list[Crossing], boards: int) -> list[dict]:
    """Per crossing: visits started in it, heliostats with a valid point in it, those of them that
    had no point of that kind before (new), band points per board-hour."""
    visits, points = latest_rows(db, (VISIT_STARTS, ()), (VALID_POINTS, ()))
    starts = np.sort(np.array([t for (t,) in visits], dtype=float))
    times = np.array([t for t, _h in points], dtype=float)
    order = np.argsort(times, kind="stable")
    times, ids_sorted = times[order], [points[k][1] for k in order]
    had = {"rising": set(), "setting": set()}
    out = []
    for c in cross:
        lo, hi = np.searchsorted(times, c.start_s, "left"), np.searchsorted(times, c.end_s, "right")
        ids = set(ids_sorted[lo:hi])
        new = ids - had[c.kind]
        had[c.kind] |= ids
        visits_in = int(np.searchsorted(starts, c.end_s) - np.searchsorted(starts, c.start_s))
        board_hours = max(c.hours * boards, 1e-9)
        out.append({"day": c.day, "band": c.kind, "start_days": None, "hours": round(c.hours, 3),
                    "visits": visits_in, "visits_per_board_hour": round(visits_in / board_hours, 1),
                    "heliostats_with_point": len(ids), "new_heliostats": len(new),
                    "points_per_board_hour": round(len(ids) / board_hours, 1),
                    "heliostats_with_kind": len(had[c.kind])})
    return out


def accepted_now(db: Path) -> int:
    """Heliostats whose newest verdict accepts them (the latest campaign of ``db``)."""
    if campaign_of(db) is None:
        return 0
    newest = ("SELECT COUNT(*) FROM verdicts WHERE id IN (SELECT MAX(id) FROM verdicts WHERE campaign_id = ? "
              "GROUP BY heliostat_id) AND accepted = 1")
    (rows,) = latest_rows(db, (newest, ()))
    return int(rows[0][0])


def campaign_of(db: Path) -> tuple[float, bool, dict] | None:
    """(start [UTC s], finished, settings) of the latest campaign in ``db``, or None."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        row = con.execute("SELECT started_s, ended_s, settings_json FROM campaigns ORDER BY id DESC LIMIT 1").fetchone()
    finally:
        con.close()
    return None if row is None else (float(row[0]), row[1] is not None, json.loads(row[2] or "{}"))


def ensure_field(path: Path, n: int, targets: int) -> Path:
    """The field config at ``path``; generated (``sim-field --n n --targets targets``) if missing."""
    if not path.exists():
        from helicalib.sim.field import generate_field, write_field

        print(f"generating {path} ({n} heliostats, {targets} boards)", file=sys.stderr, flush=True)
        data, rows = generate_field(n, *SITE, targets=targets, name=f"Benchmark {n} (Dunhuang)")
        write_field(data, rows, path)
    return path


def run(cfg, work: Path, days: float, seed: int, scenario, start_s: float, fidelity: str, spots) -> dict:
    """The simulated campaign into ``work`` (resumed if an interrupted one is there); its summary."""
    from helicalib.app.simulated import SimulationOptions, simulate_campaign

    db = work / "helicalib.db"
    state = {"hour": None, "wall0": time.perf_counter()}

    def progress(now_s: float) -> None:
        hour = int((now_s - start_s) // 3600.0)
        if hour != state["hour"]:
            state["hour"] = hour
            if hour % 24 == 0:  # frames are not kept: the database holds every observation
                shutil.rmtree(work / "images", ignore_errors=True)
            print(f"  plant day {hour // 24} hour {hour % 24:2d}: {accepted_now(db) if db.exists() else 0} accepted, "
                  f"{time.perf_counter() - state['wall0']:.0f} s wall", file=sys.stderr, flush=True)

    options = SimulationOptions(days, seed=seed, scenario=scenario, planner="gaps", start_s=start_s,
                                fidelity=fidelity, spots_per_board=spots)
    result = simulate_campaign(cfg, work, options, progress=progress)
    shutil.rmtree(work / "images", ignore_errors=True)
    return result.summary


def report(cfg, db: Path, start_s: float, days: float, rates: dict[str, float], run_rate_key: str) -> dict:
    """The figures of the run in ``db`` against the band-capacity bound."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_campaign import acceptance_timeline, days_to

    n = len(cfg.heliostats)
    boards = len(cfg.targets)
    cross = crossings(cfg, start_s, start_s + days * 86400.0)
    far = crossings(cfg, start_s, start_s + max(days, HORIZON_DAYS) * 86400.0)  # the bound may lie past the run
    stats = crossing_stats(db, cross, boards)
    hours_open = open_hours(db, cross)
    for s, h, c in zip(stats, hours_open, cross):
        s["start_days"] = round((c.start_s - start_s) / 86400.0, 3)
        s["open_hours"] = round(h, 3)
        s["points_per_open_board_hour"] = round(s["heliostats_with_point"] / (h * boards), 1) if h > 0 else None
    _start, timeline = acceptance_timeline(db, n)
    first = [s for s in stats if s["heliostats_with_point"]]
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:  # how far the run got (an interrupted one)
        reached = con.execute("SELECT MAX(capture_time_s) FROM observations").fetchone()[0] or start_s
    done = [s["open_hours"] > 0 and c.end_s <= reached for s, c in zip(stats, cross)]
    used = [s for s, ok in zip(stats, done) if ok]
    # the boards' capacity shows where heliostats that got the band's point later still lacked it after
    # the crossing (1 % of the field or more): a crossing whose demand ran out (or was left to heliostats
    # no search ever found) measures fewer points than its boards could take
    final = {kind: max((s["heliostats_with_kind"] for s, c in zip(stats, cross) if c.kind == kind), default=0)
             for kind in ("rising", "setting")}
    limited = [s for s, c, ok in zip(stats, cross, done) if ok and s["heliostats_with_point"]
               and final[c.kind] - s["heliostats_with_kind"] >= max(1.0, 0.01 * n)]
    basis = limited or used
    measured = (sum(s["heliostats_with_point"] for s in basis) / sum(s["open_hours"] * boards for s in basis)
                if basis else None)

    def bound(rate, fraction, hours=None, over=far):
        t = capacity_bound(over, n, boards, rate, fraction, hours)
        return None if t is None else round((t - start_s) / 86400.0, 3)

    bounds = {f"{name} ({rate:g} per board-hour)": {"rate": rate, "days_to_90": bound(rate, 0.90),
                                                   "days_to_95": bound(rate, 0.95)}
              for name, rate in rates.items()}
    if measured:
        bounds[f"this run's band rate ({measured:.1f} per open board-hour)"] = {
            "rate": round(measured, 1), "days_to_90": bound(measured, 0.90), "days_to_95": bound(measured, 0.95)}
        bounds["this run's band rate and weather (open hours only)"] = {
            "rate": round(measured, 1), "days_to_90": bound(measured, 0.90, hours_open, cross),
            "days_to_95": bound(measured, 0.95, hours_open, cross)}
    d90, d95 = days_to(start_s, timeline, n, 0.90), days_to(start_s, timeline, n, 0.95)
    key = next((k for k in bounds if k.startswith(run_rate_key)), None)
    b95 = bounds[key]["days_to_95"] if key else None
    return {"heliostats": n, "boards": boards, "days": days,
            "accepted": timeline[-1][1] if timeline else 0,
            "days_to_90": d90, "days_to_95": d95, "bounds": bounds,
            "days_to_95_over_bound": None if d95 is None or not b95 else round(d95 / b95, 3),
            "band_points_per_open_board_hour": None if measured is None else round(measured, 1),
            "crossings": stats, "crossings_with_points": len(first)}


def table(doc: dict) -> str:
    lines = [(f"{doc['heliostats']} heliostats on {doc['boards']} boards, {doc['days']:g} days from {doc['start']}, "
              f"{doc['mode']}, seed {doc['seed']}: {doc['accepted']} accepted"),
             f"days to 90 % / 95 %: {doc['days_to_90']} / {doc['days_to_95']}"
             + ("" if doc["days_to_95_over_bound"] is None else f" ({doc['days_to_95_over_bound']}× the bound "
                                                               f"at this mode's rate)"),
             "band-capacity bound, days to 90 % / 95 %:"]
    for name, b in doc["bounds"].items():
        lines.append(f"  {name}: {b['days_to_90']} / {b['days_to_95']}")
    lines.append("band crossings (day band start: hours, open hours, visits, heliostats with a point (new), "
                 "points per board-hour, per open board-hour):")
    for s in doc["crossings"]:
        lines.append(f"  day {s['day']} {s['band']:7s} {s['start_days']:.3f}: {s['hours']:.2f} h, {s['open_hours']:.2f} "
                     f"open, {s['visits']} visits, {s['heliostats_with_point']} ({s['new_heliostats']} new), "
                     f"{s['points_per_board_hour']:g} / {s['points_per_open_board_hour']}")
    if doc.get("summary"):
        s = doc["summary"]
        lines.append(f"mean iterations {s.get('mean_iterations')}, first-shot RMS {s.get('first_shot_rms_mrad')} mrad, "
                     f"true sky RMS {s.get('true_sky_rms_mrad')} mrad (accepted {s.get('true_sky_rms_accepted_mrad')})")
    return "\n".join(lines)


def _iso(start_s: float, given: str) -> str:
    """``given`` if it names ``start_s``, else ``start_s`` in UTC (a database read with ``--db``)."""
    from helicalib.geometry.sun import parse_time, to_unix_seconds

    if abs(float(to_unix_seconds([parse_time(given)])[0]) - start_s) < 1.0:
        return given
    return time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime(start_s))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--field", type=Path, default=FIELD, help="field config (default bench500); generated if missing")
    ap.add_argument("--n", type=int, default=10000, help="heliostats of a generated field (default 10000)")
    ap.add_argument("--targets", type=int, default=8, help="boards of a generated field (default 8)")
    ap.add_argument("--start", default=EQUINOX, help=f"plant start, ISO 8601 with offset (default {EQUINOX})")
    ap.add_argument("--days", type=float, default=1.0, help="plant days to run (default 1)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--seeds", default=None, help="several seeds, e.g. 1,2,3: each run in --work/seed-N, then their "
                    "mean (days to 90 / 95 %%, band rate, sky RMS)")
    ap.add_argument("--scenario", type=Path, default=SCENARIO)
    ap.add_argument("--fidelity", choices=("render", "fast"), default="fast")
    ap.add_argument("--spots-per-board", default="auto", help="visits per board whose beams take turns: N or auto "
                    "(default auto)")
    ap.add_argument("--rate-one", type=float, default=RATE_ONE,
                    help=f"band points per board-hour one at a time, for the bound (default {RATE_ONE:g})")
    ap.add_argument("--rate-turns", type=float, default=RATE_TURNS,
                    help=f"band points per board-hour with turns, for the bound (default {RATE_TURNS:g})")
    ap.add_argument("--work", type=Path, default=OUT / "band", help="the run's folder (its database; resumed)")
    ap.add_argument("--fresh", action="store_true", help="start over: delete --work first")
    ap.add_argument("--db", type=Path, default=None, help="read this campaign database; run nothing")
    ap.add_argument("--out", type=Path, default=OUT / "bench_band.json")
    ap.add_argument("--json", action="store_true", help="print the JSON document instead of the table")
    args = ap.parse_args(argv)

    from helicalib.config import load_field_config
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.sim.scenario import load_scenario

    cfg = load_field_config(ensure_field(args.field, args.n, args.targets))
    start_s = float(to_unix_seconds([parse_time(args.start)])[0])
    spots = args.spots_per_board if args.spots_per_board == "auto" else int(args.spots_per_board)
    seeds = [int(x) for x in str(args.seeds).split(",")] if args.seeds else [args.seed]
    rates = {"one at a time": args.rate_one, "with turns": args.rate_turns}
    docs = []
    for seed in seeds:
        work = args.work / f"seed-{seed}" if len(seeds) > 1 else args.work
        if args.db is not None:
            docs.append(_read_db(cfg, args.db, args, rates, spots))
            break
        docs.append(_run_seed(cfg, work, seed, start_s, spots, rates, args, load_scenario(str(args.scenario))))
        if len(seeds) > 1:
            print(table(docs[-1]), file=sys.stderr, flush=True)
    doc = docs[0] if len(docs) == 1 else {"benchmark": "band", "runs": docs, "mean": seed_mean(docs)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2))
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        print(table(docs[0]) if len(docs) == 1 else "\n".join(
            f"{k}: {v}" for k, v in {"seeds": seeds, **doc["mean"]}.items()))
    print(f"written {args.out}", file=sys.stderr)
    return 0


SUMMARY_KEYS = ("visits", "valid_visits", "mean_iterations", "first_shot_rms_mrad", "true_sky_rms_mrad",
                "true_sky_rms_accepted_mrad", "true_tracking_rms_mrad", "acceptance_rate")


def _mode(spots) -> str:
    return "one at a time" if spots in (1, "1") else f"turns ({spots} visits per board)"


def _read_db(cfg, db: Path, args, rates: dict, spots) -> dict:
    """The figures of an existing database (nothing run)."""
    if not db.exists():
        raise SystemExit(f"--db {db}: no such database")
    found = campaign_of(db)
    if found is None:
        raise SystemExit(f"--db {db}: no campaign in it")
    start_s, _finished, settings = found
    spots = settings.get("spots_per_board", spots)
    days = float(settings.get("days", args.days))
    doc = report(cfg, db, start_s, days, rates, "one at a time" if spots in (1, "1") else "with turns")
    doc.update({"benchmark": "band", "field": str(args.field), "start": _iso(start_s, args.start),
                "seed": settings.get("seed", args.seed), "mode": _mode(spots), "database": str(db), "summary": None})
    return doc


def _run_seed(cfg, work: Path, seed: int, start_s: float, spots, rates: dict, args, scenario) -> dict:
    """One seed's run into ``work`` (resumed if interrupted, read if finished) and its figures."""
    if args.fresh:
        shutil.rmtree(work, ignore_errors=True)
    db = work / "helicalib.db"
    found = campaign_of(db) if db.exists() else None
    summary = None
    if found is not None and found[1]:
        print(f"{db}: a finished run; read as it is (--fresh runs again)", file=sys.stderr, flush=True)
    else:
        if found is not None:
            print(f"{db}: resuming the interrupted run", file=sys.stderr, flush=True)
        summary = run(cfg, work, args.days, seed, scenario, start_s, args.fidelity, spots)
    doc = report(cfg, db, start_s, args.days, rates, "one at a time" if spots in (1, "1") else "with turns")
    doc.update({"benchmark": "band", "field": str(args.field), "start": args.start, "seed": seed,
                "mode": _mode(spots), "database": str(db),
                "summary": None if summary is None else {k: summary.get(k) for k in SUMMARY_KEYS}})
    return doc


def seed_mean(docs: list[dict]) -> dict:
    """The seeds' mean of days to 90 / 95 % (None if a seed did not get there), band points per open
    board-hour and the summary figures."""
    def mean(values):
        return None if not values or any(v is None for v in values) else round(float(np.mean(values)), 3)

    out = {k: mean([d[k] for d in docs]) for k in ("days_to_90", "days_to_95", "band_points_per_open_board_hour")}
    out["days_to_95_by_seed"] = [d["days_to_95"] for d in docs]
    for k in SUMMARY_KEYS:
        out[k] = mean([(d["summary"] or {}).get(k) for d in docs])
    return out


if __name__ == "__main__":
    sys.exit(main())
