"""How ``helicalib probe`` shows its checks: a rich table and one line per failure on stdout, or
one JSON document (``--json``).

A big field's heliostats are collapsed: past :data:`COLLAPSE_ABOVE` heliostat rows only those
that are not ``ok`` are shown, beside one count line (``--all`` shows every row).
"""

from __future__ import annotations

import json
import math
import sys

from helicalib.app.probe_checks import MISMATCH, OK, SKIPPED, STATUSES, WARNING, Check

COLLAPSE_ABOVE = 50
"""Heliostat rows shown whole up to this many; beyond, the failures and a count line."""
PLAIN_WIDTH = 200
"""Characters per line of the table when stdout is no terminal (a log keeps each row on one line)."""
STATUS_WORDS = {OK: "ok", MISMATCH: "MISMATCH", WARNING: "warning", SKIPPED: "skipped"}
STATUS_STYLES = {OK: "green", MISMATCH: "bold red", WARNING: "yellow", SKIPPED: "dim"}


def heliostat_summary(checks) -> dict:
    """Heliostat rows by status: ``{"read": n, "ok": .., "mismatch": .., "warning": ..}``."""
    rows = [c for c in checks if c.section == "heliostats" and c.status != SKIPPED]
    out = {"read": len(rows)}
    out.update({s: sum(1 for c in rows if c.status == s) for s in (OK, MISMATCH, WARNING)})
    return out


def shown_checks(checks, show_all: bool = False) -> list[Check]:
    """The rows to show: every check, with a big field's ``ok`` heliostat rows replaced by one
    count line (where the first heliostat row stood)."""
    helio = [c for c in checks if c.section == "heliostats" and c.status != SKIPPED]
    if show_all or len(helio) <= COLLAPSE_ABOVE:
        return list(checks)
    counts = heliostat_summary(checks)
    line = Check("heliostats", "heliostats read", f"{counts['read']} rows (--all shows each)",
                 f"{counts[OK]} ok, {counts[MISMATCH]} mismatch, {counts[WARNING]} warning",
                 OK, {k: counts[k] for k in counts})
    collapsed = {id(c) for c in helio if c.status == OK}
    out, placed = [], False
    for c in checks:
        if id(c) in collapsed:
            if not placed:
                out.append(line)
                placed = True
            continue
        out.append(c)
    return out if placed else [line, *out]


def summary(result) -> dict:
    """Counts by status, the heliostats' counts, and the verdict with its exit status."""
    out = {s: result.count(s) for s in STATUSES}
    out.update(checks=len(result.checks), heliostats=heliostat_summary(result.checks),
               passed=result.passed, exit_status=result.exit_status)
    return out


def summary_line(result) -> str:
    s = summary(result)
    verdict = "every check passed" if result.passed else f"{s[MISMATCH]} MISMATCH"
    return (f"probe: {s['checks']} checks: {s[OK]} ok, {s[MISMATCH]} mismatch, {s[WARNING]} warning, "
            f"{s[SKIPPED]} skipped: {verdict} (exit status {result.exit_status})")


def as_json(result, show_all: bool = False) -> dict:
    """The JSON document of ``--json``."""
    return {"field": result.field, "plant": result.plant,
            "checks": [{"section": c.section, "name": c.name, "status": c.status, "expected": c.expected,
                        "found": c.found, "values": _plain(c.values)} for c in shown_checks(result.checks, show_all)],
            "summary": summary(result)}


def print_json(result, show_all: bool = False, stream=None) -> None:
    out = sys.stdout if stream is None else stream
    print(json.dumps(as_json(result, show_all), allow_nan=False), file=out)


def _plain(value):
    """``value`` with every non-finite number as its text (``"nan"``): strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def print_table(result, show_all: bool = False, stream=None) -> None:
    """The table, then one plain line per failure and per warning, then the summary line."""
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    out = sys.stdout if stream is None else stream
    console = Console(file=out, highlight=False)
    if not console.is_terminal:
        console = Console(file=out, highlight=False, width=PLAIN_WIDTH)
    table = Table(title=f"helicalib probe · {result.plant}", title_justify="left")
    for name in ("section", "check", "expected", "found", "status"):
        table.add_column(name, overflow="fold")
    for c in shown_checks(result.checks, show_all):
        table.add_row(Text(c.section), Text(c.name), Text(c.expected), Text(c.found),
                      Text(STATUS_WORDS[c.status], style=STATUS_STYLES[c.status]))
    console.print(table)
    for c in result.checks:
        if c.status in (MISMATCH, WARNING):
            print(f"{STATUS_WORDS[c.status]}: {c.section}: {c.name}: {c.found}", file=out)
    print(summary_line(result), file=out)
