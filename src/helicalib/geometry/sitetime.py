"""The site's local time beside UTC: which clock the report shows, and how it formats an instant.

The program keeps UTC; a crew reads the plant's clock. :func:`site_time` picks the site's zone:

1. the zone given to the report (``build_report(timezone=...)``, ``helicalib report --timezone``):
   an IANA name (``Asia/Shanghai``, daylight saving included) or a fixed offset (``+08:00``, ``UTC+8``);
2. a zone the field config's ``site`` gives (``timezone``: IANA name, or ``utc_offset_h``), when
   the config schema has one;
3. otherwise the site's **local mean solar time**, UTC + longitude / 15 h (the field config
   always has the longitude). It is not the civil clock (Dunhuang's solar time is UTC+06:18, its
   clock UTC+08:00), and every label says "solar time" so it cannot be mistaken for it.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from dataclasses import dataclass

UTC_FORMAT = "%Y-%m-%d %H:%M:%S UTC"
"""How ``report.json`` writes instants (``…_utc`` keys)."""


def _offset_text(minutes: int) -> str:
    sign = "+" if minutes >= 0 else "−"
    return f"UTC{sign}{abs(minutes) // 60:02d}:{abs(minutes) % 60:02d}"


@dataclass(frozen=True)
class SiteTime:
    """The site's clock.

    Attributes
    ----------
    zone : datetime.tzinfo
    name : str
        Short name for table cells and axis labels (``'solar time'``, ``'Asia/Shanghai'``, ``'UTC+08:00'``).
    description : str
        One sentence: which clock and where it comes from.
    source : str
        ``'report option'``, ``'field config'`` or ``'site longitude'``.
    """

    zone: _dt.tzinfo
    name: str
    description: str
    source: str

    def local(self, t_s: float | None, fmt: str = "%H:%M") -> str | None:
        """``t_s`` [UTC s] on the site's clock (default ``HH:MM``); None for None/NaN."""
        if t_s is None or not math.isfinite(float(t_s)):
            return None
        return _dt.datetime.fromtimestamp(float(t_s), tz=self.zone).strftime(fmt)

    def offset_h(self, t_s: float) -> float:
        """The site clock's offset from UTC at ``t_s`` [h]."""
        when = _dt.datetime.fromtimestamp(float(t_s), tz=_dt.timezone.utc)
        return when.astimezone(self.zone).utcoffset().total_seconds() / 3600.0

    def axis_label(self, t_s: float) -> str:
        """The label of a time axis in site time (its offset at ``t_s``)."""
        minutes = int(round(self.offset_h(t_s) * 60))
        return f"{self.name} ({_offset_text(minutes)})" if self.source != "site longitude" else \
            f"local solar time ({_offset_text(minutes)})"

    def to_json(self) -> dict:
        return {"name": self.name, "description": self.description, "source": self.source}


def parse_zone(text: str) -> tuple[_dt.tzinfo, str]:
    """(tzinfo, name) of an IANA zone name or a fixed offset (``+08:00``, ``UTC+8``, ``-3:30``).

    Raises
    ------
    ConfigError
        Neither a known zone nor an offset.
    """
    from helicalib.errors import ConfigError

    t = str(text).strip()
    m = re.fullmatch(r"(?:UTC|GMT)?\s*([+-−])\s*(\d{1,2})(?::?(\d{2}))?", t, flags=re.IGNORECASE)
    if m:
        minutes = int(m.group(2)) * 60 + int(m.group(3) or 0)
        if minutes > 14 * 60:
            raise ConfigError(f"time zone {text!r}: offset beyond ±14 h")
        minutes = -minutes if m.group(1) in "-−" else minutes
        return _dt.timezone(_dt.timedelta(minutes=minutes)), _offset_text(minutes)
    if t.upper() in ("UTC", "Z", "GMT"):
        return _dt.timezone.utc, "UTC"
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        return ZoneInfo(t), t
    except (ZoneInfoNotFoundError, ValueError) as err:
        raise ConfigError(f"time zone {text!r}: not an IANA zone name (e.g. Asia/Shanghai) "
                          "nor an offset (e.g. +08:00)") from err


def site_time(cfg=None, override: str | None = None) -> SiteTime:
    """The site's clock shown beside UTC in reports and live views (module docstring: option, field config, solar time)."""
    if override:
        zone, nm = parse_zone(override)
        return SiteTime(zone, nm, f"site time {nm} (given to the report)", "report option")
    site = getattr(cfg, "site", None)
    for key in ("timezone", "time_zone", "utc_offset_h"):
        value = getattr(site, key, None)
        if value is None:
            continue
        if key == "utc_offset_h":
            minutes = int(round(float(value) * 60))
            value = f"{'+' if minutes >= 0 else '-'}{abs(minutes) // 60}:{abs(minutes) % 60:02d}"
        zone, nm = parse_zone(str(value))
        return SiteTime(zone, nm, f"site time {nm} (field config site.{key})", "field config")
    lon = float(getattr(site, "longitude_deg", 0.0) or 0.0)
    minutes = int(round(lon * 4.0))
    zone = _dt.timezone(_dt.timedelta(minutes=minutes))
    where = f"longitude {lon:g}°" if site is not None else "no field config: longitude 0°"
    return SiteTime(zone, "solar time",
                    f"local mean solar time, {_offset_text(minutes)} from the site's {where} (the field config "
                    "gives no time zone; pass --timezone for the plant's clock)", "site longitude")


def utc_seconds(value) -> float | None:
    """UTC seconds of a number or of a ``report.json`` UTC string (:data:`UTC_FORMAT`); None otherwise."""
    if value is None:
        return None
    if isinstance(value, (int, float)):
        return float(value) if math.isfinite(float(value)) else None
    try:
        when = _dt.datetime.strptime(str(value), UTC_FORMAT).replace(tzinfo=_dt.timezone.utc)
    except ValueError:
        return None
    return when.timestamp()
