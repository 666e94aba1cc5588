"""argparse ``type=`` helpers that refuse values no command can use (NaN, inf, negative sizes...).

Use them as ``p.add_argument("--days", type=positive_float)``. A refused value makes argparse
print one line, ``helicalib simulate: error: argument --days: 'nan' is not a finite number``, and
exit with status 2, before the command runs.

=====================  ====================================================================
``finite_float``       any finite number (coordinates, offsets, temperatures)
``positive_float``     finite and > 0 (durations, rates, sizes, sigmas, resolutions)
``nonnegative_float``  finite and >= 0 (noise, margins)
``fraction``           finite, 0 <= x <= 1
``float_in(lo, hi)``   finite, lo <= x <= hi (either bound may be None; ``open_lo``/``open_hi``
                       make it strict)
``nonnegative_int``    a whole number >= 0 (seeds)
``int_in(lo, hi)``     a whole number, lo <= x <= hi (years, counts); ``port`` = int_in(0, 65535)
``campaign_id``        a whole number in [1, 2^63 - 1] (a database row id)
``site_text``          ``LAT,LON[,ALT]`` with each number in range (returned as the text)
``iso_time``           an ISO 8601 instant with offset, years 1678..2261 (returned as the text)
=====================  ====================================================================

:func:`add_database` adds the positional ``DB`` of every command that reads a campaign database.
:func:`add_console` adds the crew console's ``--console [HOST:]PORT`` and ``--console-public`` to
a controller command (``run``, ``check``).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def float_in(lo: float | None = None, hi: float | None = None, *, open_lo: bool = False,
             open_hi: bool = False) -> Callable[[str], float]:
    """A ``type=`` for a finite float inside [lo, hi] (``open_lo``/``open_hi``: the bound excluded)."""

    def parse(text: str) -> float:
        value = _number(text)
        low_ok = lo is None or (value > lo if open_lo else value >= lo)
        high_ok = hi is None or (value < hi if open_hi else value <= hi)
        if not (low_ok and high_ok):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {_describe(lo, hi, open_lo, open_hi)}")
        return value

    parse.__name__ = "number"
    return parse


def _describe(lo, hi, open_lo: bool, open_hi: bool) -> str:
    if lo is not None and hi is not None:
        return f"a number in {'(' if open_lo else '['}{lo:g}, {hi:g}{')' if open_hi else ']'}"
    if lo is not None:
        return f"a number {'>' if open_lo else '>='} {lo:g}"
    return f"a number {'<' if open_hi else '<='} {hi:g}"


finite_float = float_in()
positive_float = float_in(0.0, open_lo=True)
nonnegative_float = float_in(0.0)
fraction = float_in(0.0, 1.0)


def int_in(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """A ``type=`` for a whole number inside [lo, hi] (either bound may be None)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            want = (f"a whole number in [{lo}, {hi}]" if lo is not None and hi is not None
                    else f"a whole number >= {lo}" if lo is not None else f"a whole number <= {hi}")
            raise argparse.ArgumentTypeError(f"{text!r}: expected {want}")
        return value

    parse.__name__ = "whole number"
    return parse


nonnegative_int = int_in(0)
port = int_in(0, 65535)
campaign_id = int_in(1, 2 ** 63 - 1)
"""A campaign id as SQLite stores it (``--campaign``): a larger number is refused by argparse in one line."""


def site_text(text: str) -> str:
    """A ``type=`` for ``LAT,LON[,ALT]`` (degrees, metres): checks the numbers, returns the text as given."""
    parts = text.split(",")
    limits = ((-90.0, 90.0, "LAT"), (-180.0, 180.0, "LON"), (-1000.0, 10000.0, "ALT"))
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(f"{text!r}: expected LAT,LON[,ALT]")
    for part, (lo, hi, name) in zip(parts, limits):
        try:
            float_in(lo, hi)(part.strip())
        except argparse.ArgumentTypeError as err:
            raise argparse.ArgumentTypeError(f"{text!r}: {name} {err}") from None
    return text


FIRST_YEAR, LAST_YEAR = 1678, 2261
"""Instants the sun and clock code can represent (pandas' nanosecond range)."""


def iso_time(text: str) -> str:
    """A ``type=`` for an ISO 8601 instant with a zone offset in years 1678..2261; returns the text as given."""
    from helicalib.errors import HelicalibError
    from helicalib.geometry.sun import parse_time

    try:
        year = parse_time(text).year
    except HelicalibError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    if not FIRST_YEAR <= year <= LAST_YEAR:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a time in the years {FIRST_YEAR}..{LAST_YEAR}")
    return text


def add_register_map(p: argparse.ArgumentParser) -> None:
    """``--register-map FILE``: the plant's Modbus register map, overriding the field config's
    ``plant.register_map`` (a YAML file, or a shipped map's name such as ``scs-b``)."""
    p.add_argument("--register-map", default=None, metavar="FILE",
                   help="the plant's Modbus register map (YAML, or a shipped name: plant-interface-1, scs-b); "
                        "overrides plant.register_map of the field config (docs/plant-interface.md)")


def add_live_target(p: argparse.ArgumentParser, days_help: str) -> None:
    """The arguments every live command against the plant shares: the field, ``--arm``,
    ``--heliostats`` and when to stop (``--until`` or ``--days``)."""
    p.add_argument("field", help="field config YAML")
    p.add_argument("--arm", action="store_true", help="allow writes to the plant (commands, strokes, corrections)")
    p.add_argument("--heliostats", default=None, help="comma-separated heliostat ids (default all)")
    add_register_map(p)
    g = p.add_mutually_exclusive_group()
    g.add_argument("--until", type=iso_time, default=None, help="stop at this plant time (ISO 8601 with offset)")
    g.add_argument("--days", type=positive_float, default=None, help=days_help)


def add_live_session(p: argparse.ArgumentParser) -> None:
    """``--new-campaign``, ``--accept-clock-jump``, ``--json`` and the console's arguments of the live
    commands that resume a campaign (``run``, ``operate``)."""
    p.add_argument("--new-campaign", action="store_true",
                   help="start a new campaign instead of resuming the field's (its points stay in the database)")
    p.add_argument("--accept-clock-jump", action="store_true",
                   help="resume the campaign although the plant's time lies before its last record, or far beyond "
                        "it (a plant restarted at another date): refused without it, with both times named")
    p.add_argument("--json", action="store_true",
                   help="JSON lines on stdout: one per event, a status line every 5 s, a final summary")
    add_console(p)


def spots_per_board(text: str) -> int | str:
    """``auto`` or a whole number >= 1 (``--spots-per-board``)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected 'auto' or a whole number >= 1") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected 'auto' or a whole number >= 1")
    return value


def add_spots(p: argparse.ArgumentParser) -> None:
    """``--spots-per-board N|auto`` (several heliostats in one board visit, docs/campaign.md)."""
    p.add_argument("--spots-per-board", type=spots_per_board, default=1, metavar="N|auto",
                   help="heliostats in a visit on one board at once (gaps planner): their beams take turns on the "
                        "board while the others slew to or from it or wait at its standby point; 1 (default) = one "
                        "at a time; auto = 3 (docs/campaign.md: the measured gain, and why several spots are not on "
                        "the board together)")


def add_console(p: argparse.ArgumentParser) -> None:
    """``--console [HOST:]PORT`` and ``--console-public`` (the crew console, docs/console.md)."""
    p.add_argument("--console", metavar="[HOST:]PORT", default=None,
                   help="serve the crew console (a live web page; actions with --arm) on this port, on 127.0.0.1 "
                        "unless a host is given (docs/console.md)")
    p.add_argument("--console-public", action="store_true",
                   help="allow --console to listen beyond loopback; every request then needs the token printed at "
                        "start")


DATABASE_HELP = "campaign database: a helicalib SQLite file (path or sqlite:/// URL)"
"""The help of the positional ``DB`` argument, the same in every command."""


def add_database(p: argparse.ArgumentParser) -> None:
    """The positional campaign database: ``DB`` (``args.db``), the same name and help in every command."""
    p.add_argument("db", metavar="DB", help=DATABASE_HELP)
