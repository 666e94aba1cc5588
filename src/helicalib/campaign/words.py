"""A campaign's state in the words its views show: the gate, a lost plant, the weather's age.

The terminal view (:mod:`helicalib.app.terminal`) and the web console (:mod:`helicalib.console`)
describe a :class:`~.events.Snapshot` (or anything with its gate fields) in the same sentences;
both take them from here.
"""

from __future__ import annotations

import datetime as dt

from helicalib.campaign.events import Snapshot, iso_utc


def duration(seconds: float) -> str:
    """A span of time in a few characters: ``"45 s"``, ``"4.0 min"``, ``"3.1 h"``, ``"2.0 d"``."""
    seconds = max(0.0, float(seconds))
    if seconds < 90.0:
        return f"{seconds:.0f} s"
    if seconds < 5400.0:
        return f"{seconds / 60.0:.1f} min"
    if seconds < 2 * 86400.0:
        return f"{seconds / 3600.0:.1f} h"
    return f"{seconds / 86400.0:.1f} d"


def clock_text(t_s: float, tz: dt.tzinfo) -> str:
    """Plant time ``t_s`` [UTC s] as UTC and the site's clock: ``2026-11-28 10:00:00 UTC (11:00 site, UTC+0100)``."""
    utc = dt.datetime.fromtimestamp(t_s, tz=dt.timezone.utc)
    local = dt.datetime.fromtimestamp(t_s, tz=tz)
    return f"{utc:%Y-%m-%d %H:%M:%S} UTC ({local:%H:%M} site, UTC{local:%z})"


def gate_text(s: Snapshot) -> str:
    """The gate in words: why calibration runs or waits (only "last known" while the plant is unreachable)."""
    if s.stowed:
        text = f"STOWED for wind ({s.gate_reason or 'wind above the stow limit'})"
    elif s.gate_open is None:
        text = f"night: {s.gate_reason}" if s.night and s.gate_reason else "not judged yet"
    elif s.night:
        text = f"night: {s.gate_reason}"
    else:
        text = ("open: " if s.gate_open else "paused: ") + s.gate_reason
    if s.plant_unreachable_since_s is None:
        return text
    return f"unknown, plant unreachable (last known: {text})"


def unreachable_text(s: Snapshot, tz: dt.tzinfo | None = None) -> str | None:
    """``plant unreachable since <time> (<how long>)…`` while the plant does not answer, else None."""
    since = s.plant_unreachable_since_s
    if since is None:
        return None
    when = clock_text(since, tz) if tz is not None else iso_utc(since).replace("+00:00", "Z")
    return (f"plant unreachable since {when} ({duration(s.time_s - since)}): no visit starts; the readings "
            "shown are as of when it last answered")


def weather_age_text(s: Snapshot) -> str:
    """How old the weather reading behind wind, DNI and the gate is."""
    if s.weather_time_s is None:
        return "no weather reading yet" if s.wind_ms is None and s.dni_wm2 is None else "weather reading of unknown age"
    return f"weather read {duration(s.time_s - s.weather_time_s)} ago"
