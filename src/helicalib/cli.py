"""The ``helicalib`` command.

Each sub-command lives in its own module under :mod:`helicalib.commands` and exposes
``register(subparsers)``; this module discovers them, so adding a command never edits this file.
A command's handler returns the exit status. Any :class:`~helicalib.errors.HelicalibError` is
printed as one line per problem on stderr (exit status 1); a closed stdout pipe ends the command
quietly (exit status 141); nothing else is caught, so real bugs stay visible.
"""

from __future__ import annotations

import argparse
import importlib
import os
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


EXIT_BROKEN_PIPE = 141
"""Exit status when the reader of stdout went away (``helicalib fit --json | head -1``): 128 + SIGPIPE."""


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the process exit status."""
    try:
        try:
            status = _run(build_parser(), argv)
        finally:  # also after --help or an argparse error (SystemExit)
            sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
        return status
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE


def _run(parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> int:
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except HelicalibError as err:
        for line in str(err).split("\n"):  # one line per problem (not splitlines: ids may hold \x1e...)
            print(f"helicalib {args.command}: error: {line}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"helicalib {args.command}: interrupted", file=sys.stderr)
        return 130


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush does not fail again
    (the recipe of the Python docs, "Note on SIGPIPE")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # stdout is no file (e.g. captured by a test)
        pass


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
