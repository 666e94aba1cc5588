"""``helicalib run FIELD [--arm]``: a live campaign against the plant in the field config."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_spots, add_live_session, add_live_target


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run (or resume) a live calibration campaign against the plant",
                       description="A live campaign against the plant the field config names (Modbus TCP + HTTP "
                                   "cameras), driven by APScheduler on the plant clock, shown live on the terminal "
                                   "(one line per event when the output is not a terminal; JSON lines with --json). "
                                   "Without --arm it reads and plans but writes nothing to the plant (a dry run, kept "
                                   "as a campaign of its own). It resumes the field's campaign (finished or not) "
                                   "unless --new-campaign. See docs/running.md.")
    add_live_target(p, "stop after this many plant days (default 7)")
    p.add_argument("--planner", choices=("gaps", "round-robin"), default="gaps", help="who goes next (default gaps)")
    p.add_argument("--refine", action="store_true",
                   help="gaps planner: spend target time no acceptance gap needs on the heliostats whose model is "
                        "most uncertain at the present sun, accepted ones included (better year-round accuracy)")
    add_live_session(p)
    add_spots(p)
    p.set_defaults(func=run, recheck=False)


def run(args) -> int:
    from helicalib.app.session import live_session
    from helicalib.console.server import check_console_args

    check_console_args(args)  # a wrong --console is refused before the plant or the database is touched

    return live_session(args, mode="live")
