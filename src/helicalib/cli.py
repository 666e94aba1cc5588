"""The ``helicalib`` command.

Each sub-command lives in its own module under :mod:`helicalib.commands` and exposes
``register(subparsers)``; this module discovers them, so adding a command never edits this file.
A command's handler returns the exit status. Any :class:`~helicalib.errors.HelicalibError` is
printed as one line on stderr (exit status 1); nothing else is caught, so real bugs stay visible.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from helicalib import __version__
from helicalib.errors import HelicalibError


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command found in :mod:`helicalib.commands`."""
    import helicalib.commands as commands

    parser = argparse.ArgumentParser(
        prog="helicalib",
        description="Closed-loop calibration controller for heliostat fields.",
    )
    parser.add_argument("--version", action="version", version=f"helicalib {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"helicalib.commands.{info.name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the process exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except HelicalibError as err:
        print(f"helicalib {args.command}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"helicalib {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
