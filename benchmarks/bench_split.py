"""One simulation unsplit against split over a Dask cluster: does the split change the results?

Runs ``helicalib simulate`` twice on one field, scenario, seed and start (default:
``simulations/fields/bench500.yaml``, the benchmark scenario, seed 1, the September equinox, fast
fidelity, 2 plant days): once in one process, once with ``--workers N`` (an embedded
``LocalCluster`` on 127.0.0.1; 4 boards into 2 groups by default). Prints, for both:

* days to 90 % and 95 % accepted (read from each database's verdicts; goal: within 5 %);
* accepted heliostats, visits, the true sky RMS over all and over the accepted heliostats (from the
  summaries; goal: within 0.05 mrad);
* wall time of the whole command (cluster start and merge included) and the groups' own loop times.

Usage::

    .venv/bin/python benchmarks/bench_split.py                      # bench500, equinox, 2 days, 2 workers
    .venv/bin/python benchmarks/bench_split.py --days 1 --workers 2

Writes ``benchmarks/out/bench_split.json``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
HELICALIB = [sys.executable, "-m", "helicalib"]


def days_to(db: Path, share: float) -> float | None:
    """Plant days to ``share`` of the newest campaign's heliostats accepted at once (its verdicts)."""
    from helicalib.sweep.task import days_to_share

    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        cid, start_s = con.execute("SELECT id, started_s FROM campaigns ORDER BY id DESC LIMIT 1").fetchone()
        n = con.execute("SELECT count(*) FROM heliostats WHERE campaign_id = ?", (cid,)).fetchone()[0]
        verdicts = con.execute("SELECT heliostat_id, time_s, accepted FROM verdicts WHERE campaign_id = ? "
                               "ORDER BY time_s, id", (cid,)).fetchall()
    finally:
        con.close()
    return days_to_share(verdicts, n, start_s, share)


def run(args, out: Path, extra: list[str]) -> dict:
    """One ``helicalib simulate`` into ``out``; its summary, days to 90/95 % and the wall time."""
    cmd = [*HELICALIB, "simulate", args.field, "--scenario", args.scenario, "--start", args.start, "--days",
           str(args.days), "--seed", str(args.seed), "--fidelity", "fast", "--out", str(out), "--json", *extra]
    print("$", " ".join(cmd[2:]), flush=True)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "MPLBACKEND": "Agg"})
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"bench_split: {' '.join(cmd[2:])} exited {done.returncode}:\n{done.stderr[-2000:]}")
    summary = json.loads(done.stdout)
    db = Path(summary["database"])
    return {"wall_s": round(wall, 1), "days_to_90": days_to(db, 0.90), "days_to_95": days_to(db, 0.95),
            "accepted": summary["accepted"], "heliostats": summary["heliostats"], "visits": summary["visits"],
            "valid_visits": summary["valid_visits"], "sky_rms_mrad": summary["true_sky_rms_mrad"],
            "sky_rms_accepted_mrad": summary["true_sky_rms_accepted_mrad"],
            "first_shot_rms_mrad": summary["first_shot_rms_mrad"],
            "loop_wall_s": summary.get("split", {}).get("group_wall_s") or summary.get("wall_s"),
            "split": summary.get("split")}


def _rel(a, b) -> float | None:
    return None if a is None or b is None or a == 0 else round(100.0 * (b - a) / a, 2)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--field", default=str(ROOT / "simulations" / "fields" / "bench500.yaml"))
    p.add_argument("--scenario", default=str(ROOT / "simulations" / "scenarios" / "benchmark.yaml"))
    p.add_argument("--start", default="2026-09-22T00:00:00+06:18")
    p.add_argument("--days", type=float, default=2.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--json", default=str(HERE / "out" / "bench_split.json"))
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_split_") as tmp:
        unsplit = run(args, Path(tmp) / "unsplit", [])
        split = run(args, Path(tmp) / "split", ["--workers", str(args.workers)])
    rows = [("days to 90 %", "days_to_90"), ("days to 95 %", "days_to_95"), ("accepted", "accepted"),
            ("visits (valid)", "visits"), ("sky RMS, all [mrad]", "sky_rms_mrad"),
            ("sky RMS, accepted [mrad]", "sky_rms_accepted_mrad"), ("first-shot RMS [mrad]", "first_shot_rms_mrad"),
            ("wall [s]", "wall_s")]
    print(f"\n{'':28s} {'unsplit':>10s} {'split':>10s}  difference")
    for label, key in rows:
        a, b = unsplit[key], split[key]
        diff = (f"{_rel(a, b):+.2f} %" if key.startswith("days") and _rel(a, b) is not None
                else f"{b - a:+.3f}" if isinstance(a, (int, float)) and isinstance(b, (int, float)) else "")
        if key == "visits":
            a, b = f"{a} ({unsplit['valid_visits']})", f"{b} ({split['valid_visits']})"
        print(f"{label:28s} {a!s:>10s} {b!s:>10s}  {diff}")
    print(f"groups: {split['split']['boards']}, their loop wall [s] {split['loop_wall_s']}; unsplit loop "
          f"{unsplit['loop_wall_s']} s")
    goals = {"days_to_95_within_5_percent": (d := _rel(unsplit["days_to_95"], split["days_to_95"])) is not None
             and abs(d) <= 5.0,
             "sky_rms_within_0_05_mrad": abs(split["sky_rms_mrad"] - unsplit["sky_rms_mrad"]) <= 0.05}
    print("goals:", ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in goals.items()))
    record = {"measured": dt.date.today().isoformat(), "field": args.field, "scenario": args.scenario,
              "start": args.start, "days": args.days, "seed": args.seed, "workers": args.workers,
              "fidelity": "fast", "unsplit": unsplit, "split": split, "goals": goals}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(record, indent=2), encoding="utf-8")
    print(f"written {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
