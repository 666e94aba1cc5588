"""``helicalib operate FIELD [--arm]``: year-round operation, the long-running calibration service."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_spots, add_live_session, add_live_target, nonnegative_int, positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("operate", help="run the year-round calibration service (checks, drift, tracking) on the "
                                       "field's campaign",
                       description="The long-running service after (or instead of) a campaign, on the same database "
                                   "and resumable like run: every day it keeps every calibrated heliostat's tracking "
                                   "corrections current, finishes any calibration still open, and spends spare board "
                                   "time on the checks most worth it (ranked by the expected reduction of the "
                                   "year-round error; a heliostat whose checks leave its model's band has drifted and "
                                   "is calibrated again); at night it idles and prunes old frames. Runs until stopped "
                                   "(SIGTERM or Ctrl-C: a clean stop) unless --days/--until; one line per event when "
                                   "the output is not a terminal (systemd's journal), JSON lines with --json. "
                                   "See docs/operation.md.")
    add_live_target(p, "stop after this many plant days (default: run until stopped)")
    p.add_argument("--rule", choices=("ranked", "rota"), default="ranked",
                   help="ranked (default): checks by the expected reduction of the year-round error; rota: every "
                        "heliostat every --rota-days (a baseline)")
    p.add_argument("--rota-days", type=positive_float, default=14.0, help="--rule rota: days between checks (default 14)")
    p.add_argument("--keep-frames", type=nonnegative_int, default=20,
                   help="every night keep the frames of each heliostat's newest N observations and of every rejected "
                        "one, delete the rest (default 20; the database keeps every observation)")
    add_live_session(p)
    add_spots(p)
    p.set_defaults(func=run, recheck=False, planner="gaps", refine=False)


def run(args) -> int:
    from helicalib.app.session import live_session
    from helicalib.console.server import check_console_args

    check_console_args(args)
    args.operation = args.rule
    return live_session(args, mode="live")
