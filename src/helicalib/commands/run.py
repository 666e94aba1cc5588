"""``helicalib run FIELD [--arm]``: a live campaign against the plant in the field config."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_console, iso_time, positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run (or resume) a live calibration campaign against the plant",
                       description="A live campaign against the plant the field config names (Modbus TCP + HTTP "
                                   "cameras), driven by APScheduler on the plant clock, shown live on the terminal "
                                   "(one line per event when the output is not a terminal; JSON lines with --json). "
                                   "Without --arm it reads and plans but writes nothing to the plant (a dry run, kept "
                                   "as a campaign of its own). It resumes the field's campaign (finished or not) "
                                   "unless --new-campaign. See docs/running.md.")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--arm", action="store_true", help="allow writes to the plant (commands, strokes, corrections)")
    p.add_argument("--heliostats", default=None, help="comma-separated heliostat ids (default all)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--until", type=iso_time, default=None, help="stop at this plant time (ISO 8601 with offset)")
    g.add_argument("--days", type=positive_float, default=None, help="stop after this many plant days (default 7)")
    p.add_argument("--planner", choices=("gaps", "round-robin"), default="gaps", help="who goes next (default gaps)")
    p.add_argument("--refine", action="store_true",
                   help="gaps planner: spend target time no acceptance gap needs on the heliostats whose model is "
                        "most uncertain at the present sun, accepted ones included (better year-round accuracy)")
    p.add_argument("--new-campaign", action="store_true",
                   help="start a new campaign instead of resuming the field's (its points stay in the database)")
    p.add_argument("--json", action="store_true",
                   help="JSON lines on stdout: one per event, a status line every 5 s, a final summary")
    add_console(p)
    p.set_defaults(func=run, recheck=False)


def run(args) -> int:
    from helicalib.campaign.session import live_session
    from helicalib.console.server import check_console_args

    check_console_args(args)  # a wrong --console is refused before the plant or the database is touched

    return live_session(args, mode="live")
