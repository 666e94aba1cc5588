"""HTML pages of the report, rendered from the Jinja2 templates in ``report/templates`` (autoescaped).

The pages are self-contained (inline CSS and a few lines of inline JavaScript to sort the
heliostat table; no network resource), the PNG plots sit beside them. :func:`index_page` is the
campaign page, :func:`sheet_page` one heliostat's page. The templates (``base.html``,
``macros.html``, ``index.html``, ``sheet.html``) take plain ``report.json`` dictionaries, so a
live console can render the same pages from the same figures.

Filters the templates use: ``v`` (a value: ``—`` for None, floats to 4 significant digits),
``pct`` (a fraction as a percentage), ``arrows`` (errors by placement), ``utc`` and ``local``
(an instant, given as UTC seconds or a ``report.json`` UTC string, in UTC and on the site's
clock, :mod:`helicalib.geometry.sitetime`).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

from helicalib.report.figures import ROUTINE_EVENTS
from helicalib.report.measures import MEASURES
from helicalib.geometry.sitetime import SiteTime, site_time, utc_seconds

TEMPLATES = Path(__file__).with_name("templates")


def v(value: Any) -> str:
    """Text of a value; '—' for None, floats to 4 significant digits."""
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def pct(value: float | None) -> str:
    return "—" if value is None else f"{100 * value:.1f} %"


def arrows(errors) -> str:
    return " → ".join(f"{x:.2f}" for x in errors or [] if x is not None)


def utc(value) -> str:
    """An instant (UTC seconds or a ``report.json`` UTC string) as ``report.json`` writes it."""
    from helicalib.report.figures import iso

    t = utc_seconds(value)
    return "—" if t is None else iso(t)


def local(site: SiteTime, value) -> str:
    """The same instant on the site's clock: ``'11:18 solar time'`` (with the date when it differs from UTC's)."""
    t = utc_seconds(value)
    if t is None:
        return "—"
    same_day = site.local(t, "%Y-%m-%d") == utc(t)[:10]
    return f"{site.local(t, '%H:%M' if same_day else '%m-%d %H:%M')} {site.name}"


@lru_cache(maxsize=4)
def environment(*extra_dirs: str):
    """The Jinja2 environment of the report's templates (autoescape on; undefined values are errors).

    ``extra_dirs``: folders searched first (the crew console's templates extend and import the
    report's: the same pieces live and after the fact)."""
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader([*extra_dirs, str(TEMPLATES)]), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters.update(v=v, pct=pct, arrows=arrows, utc=utc,
                       local=jinja2.pass_context(lambda ctx, value: local(ctx["site"], value)))
    return env


def render(name: str, site: SiteTime | None = None, *, extra_dirs: tuple[str, ...] = (), **context) -> str:
    """Render template ``name`` with ``context``, the site's clock and the error measures' names
    (``extra_dirs``: template folders searched before the report's, see :func:`environment`)."""
    return environment(*extra_dirs).get_template(name).render(site=site or site_time(None),
                                                              names={k: m.name for k, m in MEASURES.items()},
                                                              **context)


def script_json(value) -> str:
    """JSON to embed in a ``<script type="application/json">`` block: no ``<``, ``>`` or ``&`` left that
    could end the block or start markup (they are written as ``\\u003c``... inside the strings)."""
    import json

    from markupsafe import Markup

    text = json.dumps(value, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
    return Markup(text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))


def index_page(rep: dict, images: dict, sheets: list[dict], site: SiteTime | None = None,
               static_table: bool = True) -> str:
    """The campaign page: banner, summary, glossary, field overview (map, boards, bands, searchable table),
    maps, progress, pass rates, T/GRLM, heliostat table (``static_table``: every row in the HTML, for
    small fields), events."""
    c = rep["campaign"]
    ov = rep.get("overview")
    return render("index.html", site, title=f"helicalib report — {c.get('name') if c else 'empty'}", sortable=True,
                  rep=rep, images=images, sheets=sheets, hrefs={h["id"]: h["href"] for h in sheets},
                  routine=ROUTINE_EVENTS, static_table=static_table,
                  ov_json=script_json({"columns": ov["columns"], "rows": ov["rows"]}) if ov else None)


def coverage_text(details: dict) -> str:
    """The paper-2.4 coverage the verdict recorded (bands and windows with their point counts), if any."""
    parts = []
    for key, label in (("rising_ok", "rising band"), ("setting_ok", "setting band")):
        if key in details:
            parts.append(f"{label} {'✓' if details[key] else '✗'}")
    counts = details.get("window_counts")
    if isinstance(counts, list) and counts:
        parts.append("high windows: " + " ".join(f"{k + 1}:{'✓' if c else '✗'}({c})" for k, c in enumerate(counts)))
    return "; ".join(parts)


def cleanliness_svg(points: list[tuple[float, float]], limit: float | None, width: int = 640,
                    height: int = 190) -> dict | None:
    """Coordinates of the sheet's small chart of (time [s], cleanliness) points, the washing threshold dashed."""
    if not points:
        return None
    t = [p[0] for p in points]
    t0, t1 = min(t), max(t)
    span = (t1 - t0) or 1.0
    lo = min([0.0] + [p[1] for p in points])
    hi = max([1.0] + [p[1] for p in points])
    pad = 30

    def xy(tt, c):
        return (round(pad + (tt - t0) / span * (width - 2 * pad), 1),
                round(height - pad - (c - lo) / (hi - lo) * (height - 2 * pad), 1))

    dots = [xy(a, b) for a, b in points]
    return {"width": width, "height": height, "pad": pad, "lo": f"{lo:g}", "hi": f"{hi:g}",
            "points": " ".join(f"{x:.1f},{y:.1f}" for x, y in dots), "dots": dots,
            "limit": None if limit is None else f"{limit:g}", "limit_y": None if limit is None else xy(t0, limit)[1]}


def error_svg(rows: list[dict], threshold_mrad: float, band_deg=(5.0, 15.0), width: int = 640, height: int = 220,
              y_min_mrad: float = 0.1, y_max_mrad: float | None = None) -> dict | None:
    """Coordinates of the sheet's small chart of placement errors against sun elevation (0–90°, log
    error axis), when the page has no drawn plot: rising and setting points, invalid observations as
    crosses along the bottom, the low band shaded and the loop threshold dashed."""
    import math

    if not rows:
        return None
    valid = [r for r in rows if r["valid"] and r["error_mrad"] is not None]
    top = max([y_max_mrad or 0.0, 2.0 * threshold_mrad] + [r["error_mrad"] for r in valid])
    lo_log, hi_log, pad = math.log10(y_min_mrad), math.log10(top), 34

    def x(el):
        return round(pad + max(0.0, min(90.0, float(el or 0.0))) / 90.0 * (width - 2 * pad), 1)

    def y(e):
        e = min(max(float(e), y_min_mrad), top)
        return round(height - pad - (math.log10(e) - lo_log) / (hi_log - lo_log) * (height - 2 * pad), 1)

    return {"width": width, "height": height, "pad": pad, "top": f"{top:.3g}", "bottom": f"{y_min_mrad:g}",
            "band": [x(band_deg[0]), x(band_deg[1])], "threshold_y": y(threshold_mrad), "threshold": f"{threshold_mrad:g}",
            "rising": [(x(r["sun_elevation_deg"]), y(r["error_mrad"])) for r in valid if r["sun_rising"]],
            "setting": [(x(r["sun_elevation_deg"]), y(r["error_mrad"])) for r in valid if not r["sun_rising"]],
            "invalid": [x(r["sun_elevation_deg"]) for r in rows if not (r["valid"] and r["error_mrad"] is not None)]}


def sheet_page(sh: dict, plot_src: str | None, frames: dict | None, json_src: str, site: SiteTime | None = None,
               limits: dict | None = None, plot_note: str = "") -> str:
    """One heliostat's page: verdict with reasons, clause 8.2 by wind bin, plots, frames, fit, visits, observations."""
    cl = sh.get("cleanliness")
    svg = cleanliness_svg([(r["time_s"], r["cleanliness_measured"]) for r in cl["measured"]], cl["threshold"]) \
        if cl and cl.get("measured") else None
    lim = limits or {}
    errors = None if plot_src else error_svg(sh["observation_rows"], float(lim.get("loop_threshold_mrad", 3.5)),
                                             tuple(lim.get("low_band_deg", (5.0, 15.0))))
    return render("sheet.html", site, title=f"helicalib — heliostat {sh['id']}", sortable=True, sh=sh,
                  plot_src=plot_src, frames=frames, json_src=json_src, svg=svg, errors=errors, plot_note=plot_note,
                  coverage=coverage_text((sh["verdict"] or {}).get("details") or {}), limits=limits or {})
