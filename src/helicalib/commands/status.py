"""``helicalib status DB``: a campaign's progress, as a summary at field scale or as a table."""

from __future__ import annotations

import argparse
import json

from helicalib.commands._args import add_database
from helicalib.campaign.progress_summary import ATTENTION_SHOWN, FULL_TABLE_MAX, first_missing, summarise, summary_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("status", help="print a campaign's progress: a summary, or the table of every heliostat",
                       description="Progress of a campaign in a helicalib database. A field of at most "
                                   f"{FULL_TABLE_MAX} heliostats: per heliostat visits, valid points, last error and "
                                   "the acceptance verdict with its first missing item. A larger one: per board "
                                   "accepted / pending / out of service and error quantiles, the heliostats needing "
                                   "attention with their first missing item, and the worst errors (--all: the "
                                   "full table).")
    add_database(p)
    p.add_argument("--campaign", type=int, default=None,
                   help="campaign id (default: the one the process holding the database runs, else the newest "
                        "marked running, else the newest)")
    p.add_argument("--all", action="store_true",
                   help=f"print the table of every heliostat also for a field of more than {FULL_TABLE_MAX}")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table (every heliostat, and the "
                                                       "summary)")
    p.set_defaults(func=run)


STATUS_EVENT_KINDS = ("plant_lost", "plant_back", "gated", "ungated", "stow", "resume", "off_tracking",
                      "back_to_tracking")
"""The events ``status`` reads (the plant's state, the gate, stows, heliostats left off tracking)."""


def run(args) -> int:

    from rich.console import Console
    from rich.text import Text

    from helicalib.store.history import replay
    from helicalib.store.records import off_tracking
    from helicalib.store.sqlite import Store, existing_database

    store = Store.open(existing_database(args.db), readonly=True)  # a reader: never creates, migrates, writes or deletes anything
    try:
        campaigns = store.campaigns()
        if not campaigns:
            print(f"{args.db}: no campaign yet")
            return 0
        owner = store.owner()
        camp, why = shown_campaign(store, campaigns, owner, args.campaign)
        rows = store.progress(camp.id)
        events = store.events(camp.id, kinds=STATUS_EVENT_KINDS)
        out_of_service = replay(store.actions(camp.id)).out_of_service
        newest_obs = max(store.latest_by_target(camp.id).values(), key=lambda o: o.id, default=None)
        last_event = store.last_event(camp.id)
    finally:
        store.close()
    accepted = sum(1 for r in rows if r["accepted"])
    state = shown_status(camp.status, owner)
    plant = plant_state(events, newest_obs, last_event)
    if args.json:
        print(json.dumps({"campaign": camp.id, "shown_because": why, "name": camp.name, "mode": camp.mode, "status": state,
                          "owner": owner, **plant, "accepted": accepted, "heliostats": rows,
                          "stows": sum(e.kind == "stow" for e in events),
                          "off_tracking": off_tracking(events), "out_of_service": sorted(out_of_service),
                          "summary": summary_json(summarise(rows, out_of_service))}, indent=2, default=list))
        return 0
    # every string below that a user or a device gave (ids, names, reasons, the owner's line) is
    # printed as rich Text, never parsed as markup: "[/]" must not crash, "[link=...]" not become a link
    console = Console()
    console.print(Text(f"campaign {camp.id}: {why}"))
    for text, style in plant_lines(plant, running=owner is not None):
        console.print(Text(text, style=style))
    title = Text(f"campaign {camp.id}: {camp.name} ({state}) — {accepted}/{len(rows)} accepted")
    if args.all or len(rows) <= FULL_TABLE_MAX:
        console.print(heliostat_table(title, rows))
    else:
        for part in summary_view(title, summarise(rows, out_of_service)):
            console.print(part)
    stranded = off_tracking(events)
    if stranded:
        console.print(Text("not confirmed back to tracking", style="red")
                      + Text(f": {', '.join(stranded)} (the next run retries them)"))
    stows = [e for e in events if e.kind == "stow"]
    if stows:
        console.print(Text(f"{len(stows)} wind stow(s); last: {stows[-1].reason}"))
    return 0


def _mrad(x) -> str:
    return "—" if x is None else f"{x:.2f}"


def heliostat_table(title, rows, columns=("heliostat", "target", "visits", "valid", "last error mrad", "RMS mrad",
                                          "verdict")):
    """The table of every heliostat in ``rows`` (``status`` on a small field, ``--all``)."""
    from rich.table import Table
    from rich.text import Text

    table = Table(title=title)
    for col in columns:
        table.add_column(col, justify="right" if col not in ("heliostat", "target", "verdict") else "left")
    for r in rows:
        verdict = "—" if r["accepted"] is None else (first_missing(r) or "accepted")
        table.add_row(Text(r["heliostat_id"]), Text(r["target_id"]), str(r["visits"]), str(r["valid"]),
                      _mrad(r["last_error_mrad"]), _mrad(r["rms_mrad"]), Text(verdict))
    return table


def summary_view(title, summary) -> list:
    """``status`` on a large field: the per-board table, the heliostats needing attention (the tally
    by first missing item, the first :data:`ATTENTION_SHOWN` of them), the worst last errors."""
    from rich.table import Table
    from rich.text import Text

    from rich import box

    boards = Table(title=title, box=box.SIMPLE_HEAD, pad_edge=False, show_edge=False, collapse_padding=True, caption="total: heliostats on the board; out: out of service (the crew's); err: each "
                   "heliostat's last valid error; RMS: the median of their verdicts' RMS; mrad")
    for col in ("board", "total", "accepted", "pending", "out", "visits", "err p50", "p90", "max", "RMS"):
        boards.add_column(col, justify="left" if col == "board" else "right", no_wrap=True)
    for b in summary.boards:
        boards.add_row(Text(b.target_id), str(b.heliostats), str(b.accepted), str(b.pending), str(b.out_of_service),
                       str(b.visits), *(_mrad(x) for x in (b.error_p50_mrad, b.error_p90_mrad, b.error_max_mrad,
                                                           b.rms_p50_mrad)))
    parts: list = [boards]
    n = len(summary.attention)
    if n:
        parts.append(Text(f"{n} heliostat(s) need attention (not accepted, in service); first missing item:"))
        for item, count in summary.missing_tally:
            parts.append(Text(f"  {count:6d}  ") + Text(item))
        shown = summary.attention[:ATTENTION_SHOWN]
        parts.append(heliostat_table(Text(f"needing attention: the first {len(shown)} of {n} in block order"
                                          + (" (--all: every heliostat)" if n > len(shown) else "")), shown))
    else:
        parts.append(Text("no heliostat needs attention: every one in service is accepted"))
    if summary.worst:
        parts.append(heliostat_table(Text(f"worst last errors (the {len(summary.worst)} largest)"), summary.worst))
    return parts


def _utc(t_s: float | None) -> str | None:
    from helicalib.campaign.events import iso_utc

    return None if t_s is None else iso_utc(t_s).replace("T", " ").replace("+00:00", " UTC")


def plant_state(events, newest_obs, last_event=None) -> dict:
    """What the database says of the plant: unreachable since when (the newest ``plant_lost`` /
    ``plant_back`` event, in the order recorded), the gate's last change (``gated``, ``ungated``,
    ``stow``, ``resume``), the weather of the newest measurement, each with its plant time, and the
    plant time of the newest record (events and measurements) that their ages are counted to.

    ``events`` may be only those kinds; ``last_event`` is then the campaign's event recorded last
    (of any kind: its plant time is the newest record's), else the last of ``events`` is."""
    by_row = sorted(events, key=lambda e: e.id)  # recorded order: a plant clock set back stamps earlier
    if last_event is not None and (not by_row or last_event.id > by_row[-1].id):
        by_row.append(last_event)
    lost = [e for e in by_row if e.kind in ("plant_lost", "plant_back")]
    since = lost[-1].time_s if lost and lost[-1].kind == "plant_lost" else None
    gates = [e for e in by_row if e.kind in ("gated", "ungated", "stow", "resume")]
    gate = None if not gates else {"kind": gates[-1].kind, "reason": gates[-1].reason, "since": _utc(gates[-1].time_s),
                                   "since_s": gates[-1].time_s}
    weather = None if newest_obs is None or (newest_obs.wind_ms is None and newest_obs.dni_wm2 is None) else {
        "wind_ms": newest_obs.wind_ms, "dni_wm2": newest_obs.dni_wm2, "as_of": _utc(newest_obs.capture_time_s),
        "as_of_s": newest_obs.capture_time_s}
    newest = [t for t in (by_row[-1].time_s if by_row else None,
                          None if newest_obs is None else newest_obs.capture_time_s) if t is not None]
    return {"plant_unreachable_since": _utc(since), "plant_unreachable_since_s": since, "gate": gate,
            "weather": weather, "newest_record": _utc(max(newest, default=None)),
            "newest_record_s": max(newest, default=None)}


def plant_lines(plant: dict, running: bool) -> list[tuple[str, str]]:
    """``status``'s lines on the plant (text, rich style): unreachable first, then the gate and the
    weather, each with its plant time and its age before the newest record."""
    from helicalib.campaign.words import duration

    newest = plant["newest_record_s"]
    age = lambda t: "" if newest is None else f", {duration(newest - t)} before the newest record"  # noqa: E731
    lines = []
    since = plant["plant_unreachable_since_s"]
    if since is not None:
        lines.append((f"plant unreachable since {plant['plant_unreachable_since']}"
                      + (" (the newest record" if newest is None else f" ({duration(newest - since)} before the "
                         f"newest record, {plant['newest_record']}") + ")"
                      + ("" if running else "; so it was when the campaign's process stopped")
                      + ": the gate and weather below are as of before", "bold red"))
    if plant["gate"] is not None:
        g = plant["gate"]
        what = {"gated": "paused", "ungated": "open", "stow": "STOWED for wind", "resume": "tracking again after a stow"}
        lines.append((f"gate{' (last known)' if since is not None else ''}: {what[g['kind']]}: {g['reason']} "
                      f"(since {g['since']}{age(g['since_s'])})", "dim" if since is not None else ""))
    if plant["weather"] is not None:
        w = plant["weather"]
        wind = "—" if w["wind_ms"] is None else f"{w['wind_ms']:.1f} m/s"
        dni = "—" if w["dni_wm2"] is None else f"{w['dni_wm2']:.0f} W/m²"
        lines.append((f"weather of the newest measurement: wind {wind}, DNI {dni} (as of {w['as_of']}"
                      f"{age(w['as_of_s'])})", "dim" if since is not None else ""))
    return lines


SQLITE_MAX_ID = 2**63 - 1
"""The largest row id SQLite stores."""

OWNER_MODES = {"run": ("live", "dry-run"), "operate": ("live",), "check": ("check",), "simulate": ("simulate",)}
"""Campaign modes each campaign command runs (the word after the pid in the owner's lock line)."""


def shown_campaign(store, campaigns, owner: str | None, requested: int | None):
    """The campaign to show and why, in a few words (``status``, the crew console).

    ``requested`` (``--campaign``) if given; else the campaign the process holding the database runs
    (of the campaigns marked ``running`` and of its command's modes, the one whose process opened it
    last: each opening records a ``campaign`` event); else the newest marked ``running`` (no process
    runs it: interrupted); else the newest.

    Raises
    ------
    ConfigError
        ``requested`` is not a campaign of the database (one line naming the ids it has).
    """
    from helicalib.errors import ConfigError

    if requested is not None:
        found = [c for c in campaigns if c.id == requested] if 0 < requested <= SQLITE_MAX_ID else []
        if not found:
            ids = (", ".join(str(c.id) for c in campaigns) if len(campaigns) <= 10
                   else f"{campaigns[0].id} to {campaigns[-1].id}, {len(campaigns)} in all")
            raise ConfigError(f"--campaign {requested}: {store.path} has no such campaign (its campaign ids: {ids})")
        return found[0], "asked for with --campaign"
    running = [c for c in campaigns if c.status == "running"]
    if owner is not None:
        command = owner.split(":", 1)[-1].split()[0] if owner.split(":", 1)[-1].split() else ""
        theirs = [c for c in running if c.mode in OWNER_MODES.get(command, ())]
        if theirs:
            opened = {e.campaign_id: e.id for e in store.events(kind="campaign")}
            camp = max(theirs, key=lambda c: (opened.get(c.id, 0), c.id))
            return camp, f"the campaign the process holding the database runs ({owner})"
    if running:
        return running[-1], ("the newest campaign marked running" if owner is None else
                             f"the newest campaign marked running (the database is held by {owner})")
    return campaigns[-1], "the newest campaign (none is running)"


def shown_status(status: str, owner: str | None) -> str:
    """A campaign's status as the crew should read it: ``running`` only while a process runs it."""
    if status == "running" and owner is None:
        return "interrupted: no process runs it (killed?); run it again to resume"
    if owner is not None:
        return f"running ({owner})" if status == "running" else f"{status}; database in use by {owner}"
    return status

