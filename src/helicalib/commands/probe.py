"""``helicalib probe FIELD``: check a live plant against its field config and map, reading only."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_register_map


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("probe", help="check a live plant against its field config and map, reading only",
                       description="Read the plant once (heliostat count, field state, clock, weather, every "
                                   "heliostat's state, fault, strokes and cleanliness) and one frame from every "
                                   "camera (size, capture time against the plant clock, exposure control), and "
                                   "judge each against the field config and what is physically plausible. Never "
                                   "writes to the plant. Exit status 0: every check passed; 1: a mismatch; 2: bad "
                                   "usage or config. See docs/probe.md.")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--heliostats", default=None, help="comma-separated heliostat ids to read (default all)")
    add_register_map(p)
    p.add_argument("--json", action="store_true", help="one JSON document on stdout: every check and a summary")
    p.add_argument("--all", action="store_true",
                   help="show every heliostat's row (a big field shows only those not ok, and a count line)")
    p.add_argument("--arm", action="store_true", help="accepted and ignored: probe never writes to the plant")
    p.set_defaults(func=run)


def run(args) -> int:
    from helicalib.app.probe import run_probe

    return run_probe(args.field, register_map=args.register_map, heliostats=args.heliostats, as_json=args.json,
                     show_all=args.all, armed_asked=args.arm)
