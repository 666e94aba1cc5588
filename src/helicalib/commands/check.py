"""``helicalib check FIELD --heliostats H0007 [--arm]``: re-check drifted mirrors now."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_console, add_register_map, add_spots, positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="re-check one or more heliostats now and report their present error",
                       description="Visit each named heliostat once (whatever its acceptance) and print its present "
                                   "error (the beam's angle at the first placement, with its newest fitted model) "
                                   "beside the acceptance limit, and a verdict. Without --arm nothing is written to "
                                   "the plant. See docs/running.md.")
    p.add_argument("field", help="field config YAML")
    names = p.add_mutually_exclusive_group(required=True)
    names.add_argument("--heliostats", help="comma-separated heliostat ids (one or several)")
    names.add_argument("--heliostat", dest="heliostats", help=argparse.SUPPRESS)  # the old name, kept for scripts
    p.add_argument("--arm", action="store_true", help="allow writes to the plant")
    add_register_map(p)
    p.add_argument("--hours", type=positive_float, default=2.0, help="give up after this many plant hours (default 2)")
    p.add_argument("--json", action="store_true",
                   help="JSON lines on stdout: one per event, a status line every 5 s, a final summary with each "
                        "heliostat's present error, limit and verdict")
    add_console(p)
    add_spots(p)
    p.set_defaults(func=run, accept_clock_jump=False)  # check starts its own campaign: it resumes nothing


def run(args) -> int:
    from helicalib.app.session import live_session
    from helicalib.console.server import check_console_args

    check_console_args(args)  # a wrong --console is refused before the plant or the database is touched

    args.until, args.days, args.planner, args.recheck = None, args.hours / 24.0, "gaps", True
    return live_session(args, mode="check")
