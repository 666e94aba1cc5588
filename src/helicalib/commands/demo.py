"""``helicalib demo FIELD --out DIR``: what ``make demo`` runs.

A simulated calibration campaign on the field (in-process, virtual clock), then its report:
``DIR/helicalib.db`` (every observation), ``DIR/images/`` (every frame), ``DIR/summary.json``,
``DIR/observations.csv`` and ``DIR/report/index.html``. The same as
``helicalib simulate FIELD --days N --out DIR --report``, with a short explanation around it.
"""

from __future__ import annotations

import argparse

from helicalib.commands._args import nonnegative_int, positive_float
import json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the demo of `make demo`: a simulated campaign and its report",
                       description="Run a simulated calibration campaign on FIELD (hidden heliostat errors, weather, "
                                   "camera) and write its database, frames, summary and HTML report into --out "
                                   "(a new or empty folder, or a previous demo's output, which is replaced).")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--out", default="demo_out", help="output folder (default demo_out): new, empty or a previous demo output (replaced); "
                        "any other folder is refused")
    p.add_argument("--days", type=positive_float, default=2.0, help="plant days to simulate (default 2)")
    p.add_argument("--seed", type=nonnegative_int, default=1, help="seed of the hidden errors and weather (default 1)")
    p.set_defaults(func=run)


def run(args) -> int:
    from rich.console import Console
    from rich.markup import escape

    from helicalib.commands import simulate as sim_cmd
    from helicalib.commands._progress import DEFAULT_INTERVAL_S

    from helicalib.outdir import prepare

    console = Console(stderr=True, soft_wrap=True)   # whole lines in a log, not 80-column pieces
    # through simulate's own parser, so every simulate option keeps its default
    parser = argparse.ArgumentParser(prog="helicalib")
    sim_cmd.register(parser.add_subparsers())
    sim_args = parser.parse_args(["simulate", str(args.field), "--days", repr(float(args.days)), "--seed",
                                  str(args.seed), "--out", str(args.out), "--report"])
    inputs = sim_cmd.read_inputs(sim_args)            # every input simulate checks, before the folder is touched
    out = prepare(args.out, "demo", replace=True,     # only an empty folder or a previous demo's is replaced
                  inputs=(args.field,))
    # paths are the user's text, never rich markup (a folder named 'o[/]' is a folder, not a closing tag)
    console.print(f"[bold]helicalib demo[/]: a {args.days:g}-day calibration campaign on {escape(str(args.field))}, "
                  "against the simulated plant (hidden errors, weather, camera); every frame and observation goes "
                  f"to {escape(str(out / 'helicalib.db'))}")
    console.print(f"this takes {_duration_hint(args.days)}, then the report is built; progress follows "
                  f"(a line every {DEFAULT_INTERVAL_S:g} s when the output is not a terminal)")
    sim_cmd.run_campaign(sim_args, inputs, out)
    summary = json.loads((out / "summary.json").read_text())
    console.print(f"report: {out / 'report' / 'index.html'}  (open it in a browser)", markup=False)
    console.print(f"next: helicalib status {out / 'helicalib.db'}   ·   helicalib report {out / 'helicalib.db'} "
                  f"--out {out / 'report'}", markup=False)
    return 0 if summary["visits"] > 0 else 1


DEMO_WALL_S_PER_DAY = 30.0
"""Real seconds per plant day of the demo (demo_north.yaml, 40 heliostats, 2 boards): the 2-day
default took 59 s wall time on a 2-core machine (2026-11-25), report included."""


def _duration_hint(days: float) -> str:
    """``about 1 min on an idle 2-core machine`` for the demo field, scaled by the plant days."""
    from helicalib.commands._progress import format_elapsed

    seconds = max(DEMO_WALL_S_PER_DAY * days, 10.0)      # start-up and report take some seconds at any length
    return f"about {format_elapsed(seconds)} on an idle 2-core machine (longer when it is busy)"
