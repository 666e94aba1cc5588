"""What a live run shows: the terminal view, the log lines and the JSON lines of the same events.

The renderers get real events and snapshots from a runner on the in-process simulated plant;
the terminal view is drawn by rich into a recording console, the way a crew's terminal shows it.
"""

from __future__ import annotations

import io
import json

import pytest

from campaign_helpers import inprocess_campaign
from helicalib.app.terminal import JsonLines, LineLog, TerminalView, site_timezone
from helicalib.config import load_field_config


@pytest.fixture(scope="module")
def moving(demo_field_path, tmp_path_factory):
    """Events and a snapshot taken mid-visit of a short in-process campaign."""
    cfg = load_field_config(demo_field_path)
    tmp = tmp_path_factory.mktemp("console")
    runner, sim, store, _cid, _c = inprocess_campaign(cfg, tmp, 9, 3, ["H0001", "H0021", "H0002"])
    events = []
    runner.journal.listeners.append(events.append)
    runner.run_until(sim.t_s + 1200)
    while not runner.state.active:
        runner.run_until(sim.t_s + 10)
    snap = runner.snapshot(sim.t_s)
    store.close()
    return cfg, events, snap


def test_the_terminal_view_shows_boards_gate_counts_and_events(moving):
    from rich.console import Console

    cfg, events, snap = moving
    console = Console(file=io.StringIO(), width=140, record=True, force_terminal=True)
    view = TerminalView(site_timezone(cfg), "helicalib run · demo", console=console)
    for ev in events:
        view.on_event(ev)
    view.on_snapshot(snap)
    console.print(view._render())
    text = console.export_text()
    on_board = [b for b in snap.boards if b.heliostat_id]
    assert on_board and all(b.heliostat_id in text for b in on_board)
    assert f"{snap.accepted}/{snap.heliostats} accepted" in text and snap.next_band in text
    assert "open: calibration allowed" in text and "UTC" in text and "site, UTC+0618" in text
    visit_lines = [e.reason for e in events if e.kind == "visit_end"]
    assert visit_lines and visit_lines[-1][:40] in text  # the newest events scroll in, with their reasons


def test_text_from_outside_is_shown_as_text_not_markup(moving):
    """An operator's name (free text from the console) reaches event reasons: brackets in it must
    neither break the view (rich's MarkupError would stop the live refresh) nor restyle it."""
    import dataclasses

    from rich.console import Console

    cfg, events, snap = moving
    console = Console(file=io.StringIO(), width=160, record=True, force_terminal=True)
    view = TerminalView(site_timezone(cfg), "helicalib run · demo", console=console)
    evil = "pause asked by [/] [blink]crew[/blink] (127.0.0.1)"
    view.on_event(dataclasses.replace(events[-1], kind="operator", reason=evil))
    view.on_snapshot(snap)
    console.print(view._render())
    assert evil in console.export_text()


def test_log_lines_and_json_lines_carry_every_event(moving):
    cfg, events, snap = moving
    tz = site_timezone(cfg)
    lines, js = io.StringIO(), io.StringIO()
    log, jl = LineLog(tz, stream=lines), JsonLines(tz, stream=js)
    for ev in events:
        log.on_event(ev)
        jl.on_event(ev)
    jl.on_snapshot(snap)
    out = lines.getvalue().splitlines()
    objs = [json.loads(line) for line in js.getvalue().splitlines()]
    assert len(out) == len(events) and len(objs) == len(events) + 1
    assert [o["event"] for o in objs[:-1]] == [e.kind for e in events]
    assert {"visit", "measurement", "visit_end", "ungated"} <= {o["event"] for o in objs}
    assert objs[-1]["event"] == "status" and objs[-1]["accepted"] == snap.accepted
    assert all(o["time"].endswith("+00:00") for o in objs)
    assert all(e.reason in line for e, line in zip(events, out))
