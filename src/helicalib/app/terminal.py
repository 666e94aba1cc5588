"""What a live run shows its crew: a rich terminal view, plain log lines, or JSON lines.

Three outputs of the same :class:`~helicalib.campaign.events.RunEvent` stream and
:class:`~helicalib.campaign.events.Snapshot` s (``helicalib run`` / ``check`` pick one):

* :class:`TerminalView`: a rich ``Live`` panel on a terminal: plant time and rate, the gate
  (wind, DNI, stowed and why), each board with the heliostat on it, its placement and last
  error, the accepted / in-progress / waiting counts with the next low band, and the newest
  events with their reasons;
* :class:`LineLog`: one line per event (a log file, systemd's journal, a CI log), and a status
  line every :attr:`LineLog.status_every_s` real seconds;
* :class:`JsonLines`: ``--json``: one JSON object per line on stdout for each event, a
  ``status`` line every :attr:`JsonLines.status_every_s` real seconds, and a final ``summary``.

Events arrive from the scheduler's thread, snapshots from the main thread; every method is
cheap and never raises into the campaign.
"""

from __future__ import annotations

import collections
import datetime as dt
import json
import math
import sys
import threading
import time
from typing import Any

from helicalib.campaign.events import RunEvent, Snapshot, iso_utc
from helicalib.campaign.words import clock_text, duration, gate_text, unreachable_text, weather_age_text
from helicalib.geometry.sitetime import site_time


def site_timezone(cfg) -> dt.tzinfo:
    """The site's clock beside UTC, as the report shows it (:func:`helicalib.geometry.sitetime.site_time`:
    the field config's zone if it gives one, else local mean solar time)."""
    return site_time(cfg).zone


def _fmt(x: float | None, unit: str = "", nd: int = 1) -> str:
    return "—" if x is None else f"{x:.{nd}f}{unit}"


CLOCK_JUMP_S = 1800.0
"""An event stamped this much [plant s] before the newest one shown starts a new run of lines (the
plant's clock went back, or a step ran that late) instead of being sorted in among the old ones."""


class PlantOrder:
    """The plant times of the lines shown so far, to place (or label) a line stamped earlier.

    Events reach a view in the order they happen in the controller, not in plant-time order: a
    measurement carries its frame's capture time, and a step's closing events (``visit_end``,
    ``verdict``) the plant time the step began, while events made during the step (a
    ``tracking_written`` after the track command) read the clock afresh; at 240x a step of two
    real seconds is eight plant minutes. :meth:`place` says how far behind the newest line a new one
    is, or that it starts a new run of lines after a jump back of more than :data:`CLOCK_JUMP_S`."""

    def __init__(self):
        self.newest_s: float | None = None
        self.run = 0

    def place(self, t_s: float) -> tuple[float, str | None]:
        """(seconds ``t_s`` lies before the newest line so far (0 if not), a sentence when it starts a new run)."""
        if self.newest_s is None or t_s >= self.newest_s:
            self.newest_s = t_s
            return 0.0, None
        behind = self.newest_s - t_s
        if behind <= CLOCK_JUMP_S:
            return behind, None
        self.run += 1
        self.newest_s = t_s
        return 0.0, (f"the lines below are stamped {duration(behind)} before those above (the plant's clock went "
                     "back, or a step ran that late)")


class _Lines:
    """Lines on a stream, written whole under a lock, never raising (a closed pipe, ``| tee`` killed
    by the same Ctrl-C, must not stop the campaign), with a status line at most every
    :attr:`status_every_s` real seconds."""

    status_every_s = 60.0

    def __init__(self, tz: dt.tzinfo, stream, monotonic=time.monotonic):
        self.tz, self.stream, self._mono = tz, stream, monotonic
        self._last_status = -float("inf")
        self._lock = threading.Lock()

    def _write(self, text: str) -> None:
        with self._lock:
            try:
                self.stream.write(text + "\n")
                self.stream.flush()
            except (OSError, ValueError):
                pass

    def _status_due(self) -> bool:
        if self._mono() - self._last_status < self.status_every_s:
            return False
        self._last_status = self._mono()
        return True

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass


class LineLog(_Lines):
    """One line per event on ``stream`` (stderr by default): for logs, journals and CI.

    Lines go out as the events happen; a line stamped before the newest line above it says so
    (``out of order: 4.0 min before the newest line above``), and a jump back of more than
    :data:`CLOCK_JUMP_S` gets a line of its own (:class:`PlantOrder`)."""

    def __init__(self, tz: dt.tzinfo, stream=None, monotonic=time.monotonic):
        super().__init__(tz, stream or sys.stderr, monotonic)
        self._order = PlantOrder()

    def message(self, text: str) -> None:
        self._write(text)

    def _stamped(self, t_s: float, kind: str, text: str, controller: bool = False) -> None:
        stamp = iso_utc(t_s).replace("+00:00", "Z")
        with self._lock:
            behind, jump = self._order.place(t_s)
        if jump is not None:
            self._write(f"{stamp} {'clock':<16} {jump}")
        late = f" (out of order: {duration(behind)} before the newest line above)" if behind > 0 else ""
        self._write(f"{stamp}{' (controller clock)' if controller else ''} {kind:<16} {text}{late}")

    def on_event(self, ev: RunEvent) -> None:
        self._stamped(ev.time_s, ev.kind, ev.reason, ev.clock != "plant")

    def on_snapshot(self, s: Snapshot) -> None:
        if not self._status_due():
            return
        boards = ", ".join(f"{b.target_id}: {'+'.join((b.heliostat_id, *b.others)) if b.heliostat_id else 'free'}"
                           for b in s.boards)
        lost = unreachable_text(s)
        self._stamped(s.time_s, "status", ("" if lost is None else f"{lost}; ")
                      + f"{s.accepted}/{s.heliostats} accepted, {s.in_progress} in progress, {s.waiting} waiting; "
                        f"{s.visits} visits; {gate_text(s)} ({weather_age_text(s)}); {boards}; {s.next_band}")


class JsonLines(_Lines):
    """``--json``: one JSON object per line on stdout (events, periodic status, the final summary)."""

    status_every_s = 5.0

    def __init__(self, tz: dt.tzinfo, stream=None, monotonic=time.monotonic):
        super().__init__(tz, stream or sys.stdout, monotonic)

    def emit(self, obj: dict[str, Any]) -> None:
        self._write(json.dumps(obj, default=str))

    def message(self, text: str) -> None:
        self.emit({"event": "message", "reason": text})

    def on_event(self, ev: RunEvent) -> None:
        self.emit(ev.to_json(self.tz))

    def on_snapshot(self, s: Snapshot) -> None:
        if self._status_due():
            obj = s.to_json(self.tz)
            obj["weather_age_s"] = None if s.weather_time_s is None else round(s.time_s - s.weather_time_s, 1)
            obj["plant_unreachable_for_s"] = (None if s.plant_unreachable_since_s is None
                                              else round(s.time_s - s.plant_unreachable_since_s, 1))
            self.emit(obj)


class TerminalView:
    """A rich ``Live`` view of the campaign on a terminal, refreshed from the newest snapshot."""

    def __init__(self, tz: dt.tzinfo, title: str, console=None, events_shown: int = 12):
        from rich.console import Console

        self.tz, self.title = tz, title
        self.console = console or Console(stderr=True)
        # the newest events as they arrived, each with its place in plant-time order (PlantOrder)
        self.events: collections.deque[tuple[tuple, str, RunEvent]] = collections.deque(maxlen=events_shown)
        self._order = PlantOrder()
        self._seq = 0
        self._events_lock = threading.Lock()
        self._measured: dict[str, float] = {}  # board -> plant time of its newest measurement
        self.snap: Snapshot | None = None
        self.note = ""
        self._live = None
        self._real0 = time.monotonic()
        self._plant0: float | None = None

    def start(self) -> None:
        from rich.live import Live

        self._live = Live(self._render(), console=self.console, refresh_per_second=4, transient=False,
                          get_renderable=self._render)
        self._live.start()

    def stop(self) -> None:
        if self._live is not None:
            self._live.stop()
            self._live = None

    def message(self, text: str) -> None:
        self.note = text
        if self._live is None:
            self.console.print(text, markup=False, highlight=False)  # names and paths from outside: text

    def on_event(self, ev: RunEvent) -> None:
        if ev.kind == "measurement" and ev.target_id is not None:
            self._measured[ev.target_id] = ev.time_s  # the age of the board's last error
        if ev.kind == "measurement" and ev.data.get("valid", True):
            return
        with self._events_lock:
            self._seq += 1
            _behind, jump = self._order.place(ev.time_s)
            if jump is not None:  # first in its run of lines, whatever the plant times in it
                self.events.append(((self._order.run, -math.inf, self._seq), "bold yellow",
                                    RunEvent(ev.time_s, "clock", jump)))
            self.events.append(((self._order.run, ev.time_s, self._seq), _style(ev), ev))

    def shown_events(self) -> list[tuple[str, RunEvent]]:
        """The events the view shows, in plant-time order (style, event)."""
        with self._events_lock:
            return [(style, ev) for _key, style, ev in sorted(self.events, key=lambda row: row[0])]

    def on_snapshot(self, s: Snapshot) -> None:
        if self._plant0 is None:
            self._plant0, self._real0 = s.time_s, time.monotonic()
        self.snap = s

    def _render(self):
        from rich.console import Group
        from rich.panel import Panel
        from rich.table import Table
        from rich.text import Text

        # every string from outside (ids, the site's name, reasons, paths) is a Text, never markup:
        # "[/]" would raise MarkupError (and blank the live view), "[link=...]" would become a link
        title = Text(self.title)
        s = self.snap
        if s is None:
            return Panel(Text("connecting to the plant …"), title=title)
        head = Table.grid(padding=(0, 2))
        head.add_column(style="bold")
        head.add_column()
        elapsed = max(time.monotonic() - self._real0, 1e-6)
        rate = (s.time_s - (self._plant0 or s.time_s)) / elapsed
        lost = unreachable_text(s, self.tz)
        if lost is not None:  # first, and loud: everything below is as of when the plant last answered
            head.add_row(Text("UNREACHABLE", style="bold white on red"), Text(lost, style="bold red"))
        head.add_row("plant time", f"{clock_text(s.time_s, self.tz)}"
                                   f"{'' if lost is None else ' (the controller’s estimate)'}   rate {s.rate:g}x "
                                   f"(seen {rate:.0f}x)   sun {s.sun_elevation_deg:.1f}°")
        head.add_row("mode", Text("ARMED", style="green") + Text(": calibrating") if s.armed else
                     Text("not armed", style="yellow") + Text(": reading and planning only, nothing written to "
                                                              "the plant"))
        style = "dim" if lost is not None else ("red" if s.stowed else ("green" if s.gate_open else "yellow"))
        weather = "" if "wind" in s.gate_reason else (f"   wind {_fmt(s.wind_ms, ' m/s')}   "
                                                      f"DNI {_fmt(s.dni_wm2, ' W/m²', 0)}")
        head.add_row("gate", Text(gate_text(s), style=style) + Text(weather) + Text(f"   ({weather_age_text(s)})"))
        head.add_row("progress", Text(str(s.accepted), style="bold") + Text(
            f"/{s.heliostats} accepted · {s.in_progress} on boards · {s.waiting} waiting · {s.visits} visits "
            f"({s.valid_visits} valid) · {s.next_band}"))
        if s.off_tracking:
            head.add_row(Text("off tracking", style="red"), Text(", ".join(s.off_tracking), style="red")
                         + Text(" (retrying until the plant confirms state 1)"))
        boards = Table(box=None, expand=False, header_style="bold")
        for col in ("board", "heliostat", "placement", "last error [mrad]", "on board for"):
            boards.add_column(Text(col))  # a str header is markup: "[mrad]" would vanish
        for b in s.boards:
            since = "" if b.since_s is None else f"{(s.time_s - b.since_s) / 60.0:.1f} min"
            who = Text(" + ".join((b.heliostat_id, *b.others))) if b.heliostat_id else Text("free", style="dim")
            error = _fmt(b.last_error_mrad, "", 2)
            if b.last_error_mrad is not None and b.target_id in self._measured:
                error += f" ({duration(s.time_s - self._measured[b.target_id])} ago)"
            boards.add_row(Text(b.target_id), who, "—" if b.iteration is None else str(b.iteration + 1), error, since)
        log = Table(box=None, show_header=False, expand=True)
        log.add_column(no_wrap=True, style="dim", width=9)
        log.add_column(no_wrap=True, width=16)
        log.add_column(overflow="fold", ratio=1)
        for style_, ev in self.shown_events():
            t = dt.datetime.fromtimestamp(ev.time_s, tz=self.tz).strftime("%H:%M:%S")
            # reasons carry text from outside (an operator's name, a device's message): never markup
            log.add_row(t + ("*" if ev.clock != "plant" else ""), Text(ev.kind, style=style_), Text(ev.reason))
        parts = [head, Text(""), boards, Text(""), Panel(log, title="events in plant-time order (site time; * controller clock)")]
        if self.note:
            parts.append(Text(self.note, style="bold yellow"))
        return Panel(Group(*parts), title=title)


def _style(ev: RunEvent) -> str:
    return {"fault": "red", "off_tracking": "red", "stow": "red", "gated": "yellow", "note": "yellow",
            "verdict": "green", "back_to_tracking": "green", "ungated": "green",
            "measurement": "yellow"}.get(ev.kind, "cyan")


def make_output(kind: str, tz: dt.tzinfo, title: str):
    """``"json"``, ``"lines"`` or ``"terminal"``."""
    if kind == "json":
        return JsonLines(tz)
    if kind == "lines":
        return LineLog(tz)
    return TerminalView(tz, title)


__all__ = ["JsonLines", "LineLog", "PlantOrder", "TerminalView", "make_output", "site_timezone"]
