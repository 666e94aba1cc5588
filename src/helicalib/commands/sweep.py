"""``helicalib sweep SWEEP.yaml --out DIR``: a grid of simulated campaigns on Dask distributed."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from helicalib.commands._args import int_in


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="run a grid of simulated campaigns (seeds x scenarios x planners x starts) on Dask",
                       description="Runs every simulation a sweep file asks for, one whole campaign per task, on an "
                                   "embedded Dask cluster on 127.0.0.1 or on an existing one (--scheduler). Each run "
                                   "has its own database under DIR/cells/<cell>/seed-<k>/; a rerun skips finished "
                                   "runs. Writes DIR/results.csv (and results.parquet with pyarrow) and "
                                   "DIR/summary.json: per cell the mean over seeds and a 95 % interval that keeps each figure's "
                                   "scale (an RMS is never negative, a share stays in [0, 1]); docs/sweep.md.")
    p.add_argument("sweep", help="sweep file (YAML)")
    p.add_argument("--out", required=True, help="output folder (runs, table, summary): new, empty or a previous "
                   "sweep's output (its finished runs are kept); any other folder is refused")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="use this Dask scheduler and its workers instead of an embedded cluster")
    p.add_argument("--workers", type=int_in(1, 1024), default=None,
                   help="worker processes of the embedded cluster (default: the cores available)")
    p.add_argument("--json", action="store_true", help="print the summary (summary.json) as JSON on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from helicalib.commands._progress import ProgressReporter, TaskTally
    from helicalib.errors import ConfigError
    from helicalib.outdir import check, prepare, refuse_inputs
    from helicalib.sweep import engine, results
    from helicalib.sweep.spec import load_sweep

    if args.scheduler and args.workers:
        raise ConfigError("--workers sizes the embedded cluster; with --scheduler the cluster's own workers run")
    _say_reading(args.sweep)
    sweep = load_sweep(args.sweep)
    check(args.out, "sweep")
    # each unfinished run's folder under OUT/cells is cleared before it runs
    refuse_inputs(Path(args.out) / "cells", _inputs(sweep), args.out)
    runs = _lay_out(sweep, args.out, quiet=args.json)
    out = prepare(args.out, "sweep")     # never cleared: a rerun skips the finished runs
    (out / "sweep.yaml").write_text(sweep.source.read_text(encoding="utf-8-sig"), encoding="utf-8")
    workers = args.workers or len(os.sched_getaffinity(0))
    cluster = engine.cluster_for(args.scheduler, workers)
    with ProgressReporter("sweep", len(runs), transient=args.json) as bar:
        tally = TaskTally(bar, "sweep", "runs")

        def on_start(n: int) -> None:
            tally.total = n
            bar.update(0, f"0 of {n} runs ({len(runs) - n} finished before)", total=max(n, 1))

        def on_result(run, record, reason) -> None:
            tally.ended(reason)

        bar.note(f"sweep: {len(runs)} runs ({len(sweep.cells())} cells x {len(sweep.spec.seeds)} seeds) "
                 f"on {args.scheduler or f'{workers} local worker processes'}")
        def on_check(done: int, total: int) -> None:
            bar.update(0, f"looking for finished runs: {done} of {total}")

        with cluster as client:
            outcome = engine.run_sweep(sweep, runs, client, on_start=on_start, on_result=on_result,
                                       on_check=on_check)
    rows = [results.row(r, outcome.records.get(r.run_dir), outcome.failures.get(r.run_dir, (None,))[0]) for r in runs]
    document = {"sweep": str(sweep.source), "field": str(sweep.cfg.source), "days": sweep.spec.days,
                "root_seed": sweep.spec.root_seed, "seeds": sweep.spec.seeds, "interval": results.INTERVAL,
                "runs": {"total": len(runs), "skipped": outcome.skipped, "submitted": outcome.submitted,
                         "rerun_stale": outcome.stale, "finished": sum(r["status"] == "ok" for r in rows),
                         "failed": len(outcome.failures)},
                "failures": [reason for reason, _tb in outcome.failures.values()],
                "cells": results.cell_statistics(rows)}
    written = results.write_outputs(out, rows, document)
    _write_failures(out / "failures.txt", outcome.failures)
    if args.json:
        print(json.dumps(document, indent=2))
    else:
        counts = document["runs"]
        print(f"{counts['total']} runs: {counts['submitted']} run now, {counts['skipped']} finished before, "
              f"{counts['failed']} failed; mean [95 % interval over seeds] per cell:")
        for line in results.format_cells(document["cells"]):
            print(line)
        print("written " + ", ".join(str(p) for p in written))
    if outcome.failures:
        print(f"helicalib sweep: {len(outcome.failures)} of {len(runs)} runs failed (reasons in {out / 'failures.txt'}); "
              "run the sweep again to retry them", file=sys.stderr)
        return 1
    return 0


def _inputs(sweep) -> list:
    """The files a sweep reads: the sweep file, its field config and its scenarios."""
    return [sweep.source, sweep.cfg.source, *(sweep.source.parent / rel for rel in sweep.spec.scenarios or [])]


def _write_failures(path, failures: dict) -> None:
    """Each failure's line and the worker's traceback; no file when nothing failed."""
    if not failures:
        path.unlink(missing_ok=True)
        return
    path.write_text("\n".join(f"{reason}\n{tb}" for reason, tb in failures.values()), encoding="utf-8")


LARGE_SWEEP_FILE_BYTES = 256 * 1024
"""A sweep file this large is announced before it is read (a grid of 10^5 seeds takes seconds to parse)."""


def _say_reading(path) -> None:
    """``sweep: reading big.yaml (1.4 MB) ...`` on stderr for a large file; nothing for a small one."""
    try:
        size = os.path.getsize(path)
    except OSError:
        return                                      # load_sweep says what is wrong with it
    if size >= LARGE_SWEEP_FILE_BYTES:
        print(f"sweep: reading {path} ({size / 1e6:.1f} MB) ...", file=sys.stderr, flush=True)


def _lay_out(sweep, out, quiet: bool):
    """Every run of the grid, with progress while a large grid is laid out."""
    from helicalib.commands._progress import ProgressReporter
    from helicalib.sweep.spec import PROGRESS_EVERY

    total = sweep.spec.run_count()
    if total < PROGRESS_EVERY:
        return sweep.runs(out)
    with ProgressReporter("sweep", total, transient=quiet) as bar:
        return sweep.runs(out, progress=lambda done, n: bar.update(done, f"laying out runs: {done} of {n}"))
