"""The live terminal view (and the plain log lines) of a run, drawn by rich into a recording
console from snapshots and events built here, as the runner builds them."""

from __future__ import annotations

import collections
import datetime as dt
import io
import json
import math
import re

import pytest

from helicalib.app.terminal import LineLog, TerminalView
from helicalib.campaign.events import BoardState, RunEvent, Snapshot

T0 = 1_795_010_000.0  # 2026-11-18 13:53:20 UTC
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


class _SlowPlant:
    """The in-process plant, each request taking 12 plant seconds (a 50 ms Modbus round trip at 240x)."""

    def __init__(self, plant, clock_of):
        self._plant, self._clock_of = plant, clock_of

    def __getattr__(self, name):
        attr = getattr(self._plant, name)
        clock = self._clock_of()
        if not callable(attr) or clock is None:
            return attr

        def call(*args, **kwargs):
            out = attr(*args, **kwargs)
            clock.advance_to(clock.now_s() + 12.0)
            return out
        return call


@pytest.fixture(scope="module")
def late_stamped(demo_field_path, tmp_path_factory):
    """Events of a short campaign whose plant answers slowly: they reach the views out of plant-time
    order (a step's visit_end carries the time the step began, its tracking_written a later one)."""
    from campaign_helpers import inprocess_campaign
    from helicalib.config import load_field_config

    cfg = load_field_config(demo_field_path)
    box = {}
    runner, sim, store, _cid, _c = inprocess_campaign(cfg, tmp_path_factory.mktemp("late"), 9, 3,
                                                      ["H0001", "H0021", "H0002"],
                                                      plant=lambda s: _SlowPlant(s, lambda: box.get("clock")))
    box["clock"] = runner.devices.clock
    events = []
    runner.journal.listeners.append(events.append)
    runner.run_until(sim.t_s + 1500)
    store.close()
    assert any(b.time_s < a.time_s for a, b in zip(events, events[1:]))  # as on the independent plant
    return events


def _event_times(text: str) -> list[str]:
    panel = text[text.index("events in plant-time order"):]
    return re.findall(r"^\W*(\d\d:\d\d:\d\d)\s", panel, flags=re.M)


def test_the_terminal_shows_events_in_plant_time_order(late_stamped):
    view = terminal(width=220)
    view.events = collections.deque(maxlen=len(late_stamped))  # every event, to see them all
    for ev in late_stamped:
        view.on_event(ev)
    view.on_snapshot(snapshot(time_s=late_stamped[-1].time_s))
    times = _event_times(draw(view))
    assert len(times) > 10 and times == sorted(times)
    shown = [ev for _s, ev in view.shown_events()]
    assert len(times) == len(shown)
    assert [ev.time_s for ev in shown] == sorted(ev.time_s for ev in shown)


def test_log_lines_label_a_line_stamped_before_the_line_above(late_stamped):
    stream = io.StringIO()
    log = LineLog(UTC, stream=stream)
    for ev in late_stamped:
        log.on_event(ev)
    lines = stream.getvalue().splitlines()
    assert len(lines) == len(late_stamped)
    newest = -math.inf
    for ev, line in zip(late_stamped, lines):
        assert ("out of order:" in line) == (ev.time_s < newest), line
        newest = max(newest, ev.time_s)
    assert any("out of order:" in line for line in lines)


def test_a_plant_clock_set_back_starts_a_new_run_of_lines():
    view, stream = terminal(), io.StringIO()
    log = LineLog(UTC, stream=stream)
    day_before = T0 - 86400.0
    for ev in (RunEvent(T0, "visit", "H0001 onto T1"), RunEvent(T0 + 60, "visit_end", "H0001 off T1"),
               RunEvent(day_before, "fault", "plant time went backwards"), RunEvent(day_before + 30, "visit", "H0002 onto T1")):
        view.on_event(ev)
        log.on_event(ev)
    view.on_snapshot(snapshot(time_s=day_before + 30))
    text = draw(view)
    assert text.index("H0001 off T1") < text.index("stamped 24.0 h before those above") < text.index("H0002 onto T1")
    lines = stream.getvalue().splitlines()
    assert "stamped 24.0 h before those above" in lines[2] and "out of order" not in lines[3]


def test_a_plant_that_stopped_answering_is_shown_first_and_the_readings_with_their_age():
    lost = snapshot(time_s=T0 + 600, plant_unreachable_since_s=T0 + 300, weather_time_s=T0 + 270)
    view = terminal()
    view.on_event(RunEvent(T0 + 240, "measurement", "H0001 on T1, placement 0: 1.25 mrad", "H0001", "T1",
                           {"valid": True}))
    view.on_snapshot(lost)
    text = draw(view)
    head = text[:text.index("progress")]
    assert "UNREACHABLE  plant unreachable since 2026-11-18 13:58:20 UTC" in head and "(5.0 min)" in head
    assert head.index("plant unreachable since") < head.index("plant time") < head.index("gate")
    assert "(the controller’s estimate)" in head
    gate = next(line for line in text.splitlines() if " gate " in line)
    assert "unknown, plant unreachable (last known: open: calibration allowed)" in gate
    assert "weather read 5.5 min ago" in gate
    assert "last error [mrad]" in text and "1.25 (6.0 min ago)" in text  # the board's last error and its age
    lines, js = io.StringIO(), io.StringIO()
    LineLog(UTC, stream=lines).on_snapshot(lost)
    from helicalib.app.terminal import JsonLines

    JsonLines(UTC, stream=js).on_snapshot(lost)
    assert "status           plant unreachable since 2026-11-18T13:58:20Z (5.0 min)" in lines.getvalue()
    assert "weather read 5.5 min ago" in lines.getvalue() and "last known: open" in lines.getvalue()
    status = json.loads(js.getvalue())
    assert status["plant_unreachable_for_s"] == 300.0 and status["weather_age_s"] == 330.0


def test_while_the_plant_answers_the_gate_is_shown_with_the_age_of_its_reading():
    view = terminal()
    view.on_snapshot(snapshot())
    text = draw(view)
    assert "unreachable" not in text.lower() and "unknown" not in text
    gate = next(line for line in text.splitlines() if " gate " in line)
    assert "open: calibration allowed" in gate and "weather read 30 s ago" in gate


def test_a_gate_not_judged_yet_says_so_once():
    """Before the first weather reading (at night too) the line says what is known, not the same words twice."""
    lines = []
    for snap in (snapshot(gate_open=None, gate_reason="", wind_ms=None, dni_wm2=None, weather_time_s=None),
                 snapshot(gate_open=None, gate_reason="sun at -12.0°, below the low band", night=True,
                          wind_ms=None, dni_wm2=None, weather_time_s=None, time_s=T0 + 3600)):
        out = io.StringIO()  # a log of its own each: status lines come at most once a minute
        LineLog(UTC, out).on_snapshot(snap)
        lines += out.getvalue().splitlines()
    assert lines and all(line.count("no weather reading yet") <= 1 for line in lines), lines
    assert any("not judged yet (no weather reading yet)" in line for line in lines), lines
    assert any("night: sun at -12.0°, below the low band (no weather reading yet)" in line for line in lines), lines
