"""``helicalib status DB``: a campaign's progress as a table."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("status", help="print a campaign's progress as a table",
                       description="Progress of a campaign in a helicalib database: per heliostat visits, valid "
                                   "points, last error and the acceptance verdict with its first missing item.")
    p.add_argument("db", help="helicalib SQLite database (file path or sqlite:/// URL)")
    p.add_argument("--campaign", type=int, default=None, help="campaign id (default the newest)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=run)


def run(args) -> int:

    from rich.console import Console
    from rich.table import Table

    from helicalib.store.records import off_tracking
    from helicalib.store.sqlite import Store, existing_database

    store = Store.open(existing_database(args.db), readonly=True)  # a reader: never creates, migrates, writes or deletes anything
    try:
        campaigns = store.campaigns()
        if not campaigns:
            print(f"{args.db}: no campaign yet")
            return 0
        camp = store.campaign(args.campaign) if args.campaign is not None else campaigns[-1]
        rows = store.progress(camp.id)
        events = store.events(camp.id)
        owner = store.owner()
    finally:
        store.close()
    accepted = sum(1 for r in rows if r["accepted"])
    state = shown_status(camp.status, owner)
    if args.json:
        print(json.dumps({"campaign": camp.id, "name": camp.name, "mode": camp.mode, "status": state,
                          "owner": owner, "accepted": accepted, "heliostats": rows,
                          "stows": sum(e.kind == "stow" for e in events),
                          "off_tracking": off_tracking(events)}, indent=2, default=list))
        return 0
    console = Console()
    table = Table(title=f"campaign {camp.id}: {camp.name} ({state}) — {accepted}/{len(rows)} accepted")
    for col in ("heliostat", "target", "visits", "valid", "last error mrad", "RMS mrad", "verdict"):
        table.add_column(col, justify="right" if col not in ("heliostat", "target", "verdict") else "left")
    for r in rows:
        verdict = "accepted" if r["accepted"] else ("—" if r["accepted"] is None else (r["reasons"] or ["not accepted"])[0])
        fmt = lambda x: "—" if x is None else f"{x:.2f}"  # noqa: E731
        table.add_row(r["heliostat_id"], r["target_id"], str(r["visits"]), str(r["valid"]), fmt(r["last_error_mrad"]),
                      fmt(r["rms_mrad"]), verdict)
    console.print(table)
    stranded = off_tracking(events)
    if stranded:
        console.print(f"[red]not confirmed back to tracking[/]: {', '.join(stranded)} (the next run retries them)")
    stows = [e for e in events if e.kind == "stow"]
    if stows:
        console.print(f"{len(stows)} wind stow(s); last: {stows[-1].reason}")
    return 0


def shown_status(status: str, owner: str | None) -> str:
    """A campaign's status as the crew should read it: ``running`` only while a process runs it."""
    if status == "running" and owner is None:
        return "interrupted: no process runs it (killed?); run it again to resume"
    if owner is not None:
        return f"running ({owner})" if status == "running" else f"{status}; database in use by {owner}"
    return status

