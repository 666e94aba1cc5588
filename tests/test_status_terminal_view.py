"""The live terminal view (and the plain log lines) of a run, drawn by rich into a recording
console from snapshots and events built here, as the runner builds them."""

from __future__ import annotations

import datetime as dt
import io

from helicalib.campaign.console import LineLog, TerminalView
from helicalib.campaign.events import BoardState, RunEvent, Snapshot

T0 = 1_795_010_000.0  # 2026-11-18 ~12:33 UTC
UTC = dt.timezone.utc
LINK = "[link=http://evil.example]H3[/link]"


def snapshot(**kw) -> Snapshot:
    base = dict(time_s=T0, campaign_id=1, armed=True, rate=1.0,
                boards=(BoardState("T1", "H0001", 0, 1.25, T0 - 120), BoardState("T2")),
                wind_ms=3.2, dni_wm2=810.0, stowed=False, gate_open=True, gate_reason="calibration allowed",
                night=False, sun_elevation_deg=35.0, heliostats=4, accepted=1, in_progress=1, waiting=2, visits=3,
                valid_visits=2, next_band="setting band in 3.2 h", weather_time_s=T0 - 30)
    base.update(kw)
    return Snapshot(**base)


def draw(view: TerminalView) -> str:
    view.console.print(view._render())
    return view.console.export_text()


def terminal(title: str = "helicalib run · demo", width: int = 200) -> TerminalView:
    from rich.console import Console

    console = Console(file=io.StringIO(), width=width, record=True, force_terminal=True)
    return TerminalView(UTC, title, console=console)


def test_hostile_ids_names_and_reasons_are_shown_as_text():
    site = "[link=http://evil.example]Plant[/link] [/]"
    view = terminal(title=f"helicalib run · {site}")
    view.message(f"campaign 1 (armed, new): 4 heliostats; database /srv/[/]{LINK}.db")  # before the view starts
    snap = snapshot(boards=(BoardState("[/]T1", LINK, 0, 1.0, T0 - 60, others=("[/]",)), BoardState("[bold]T2")),
                    gate_reason="paused: [/] DNI low", gate_open=False, off_tracking=(LINK, "[/]"))
    view.on_snapshot(snap)
    view.on_event(RunEvent(T0, "visit", f"{LINK} onto [/]T1", LINK, "[/]T1"))
    text = draw(view)
    out = view.console.file.getvalue()
    assert "\x1b]8;" not in out  # no clickable link
    for literal in (site, LINK, "[/]T1", "[bold]T2", "paused: [/] DNI low", f"{LINK} onto [/]T1",
                    f"database /srv/[/]{LINK}.db"):
        assert literal in text, literal
