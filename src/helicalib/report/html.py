"""HTML pages of the report: plain string templates, every value through :func:`html.escape`.

The pages are self-contained (inline CSS and a few lines of inline JavaScript to sort the
heliostat table; no network resource), the PNG plots sit beside them. :func:`index_page` is the
campaign page, :func:`sheet_page` one heliostat's page.
"""

from __future__ import annotations

from html import escape
from typing import Any

from helicalib.report.figures import ROUTINE_EVENTS as F_ROUTINE

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em auto;max-width:1250px;
 color:#222;padding:0 1em}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0}
th,td{border:1px solid #ddd;padding:3px 7px;text-align:left}th{background:#f3f3f3}
table.sortable th{cursor:pointer}table.sortable th:after{content:" \\2195";color:#aaa}
td.num{text-align:right;font-variant-numeric:tabular-nums}
.banner{padding:.7em 1em;border-radius:6px;margin:1em 0}
.banner.ok{background:#e6f4ea;border:1px solid #2a9d3a}
.banner.partly_failed{background:#fff4e0;border:1px solid #e59f00}
.banner.empty{background:#fde8ea;border:1px solid #d1495b}
.accepted{color:#2a9d3a;font-weight:600}.not-accepted{color:#d1495b;font-weight:600}.no-verdict{color:#777}
.pass{color:#2a9d3a;font-weight:600}.fail{color:#d1495b;font-weight:600}.incomplete{color:#b07d00;font-weight:600}
img{max-width:100%;border:1px solid #eee}.grid3{display:grid;grid-template-columns:repeat(auto-fit,minmax(380px,1fr));gap:8px}
.small{font-size:.85em;color:#555}
"""

SORT_JS = """
document.querySelectorAll('table.sortable').forEach(function(t){
 t.querySelectorAll('th').forEach(function(th,i){th.addEventListener('click',function(){
  var b=t.tBodies[0],rows=Array.from(b.rows),asc=th.dataset.dir!=='asc';th.dataset.dir=asc?'asc':'desc';
  rows.sort(function(x,y){var a=x.cells[i].dataset.v||x.cells[i].textContent,c=y.cells[i].dataset.v||y.cells[i].textContent;
   var p=parseFloat(a),q=parseFloat(c);var r=(!isNaN(p)&&!isNaN(q))?p-q:a.localeCompare(c);return asc?r:-r;});
  rows.forEach(function(r){b.appendChild(r);});});});});
"""


def e(value: Any) -> str:
    """Escaped text of a value; '—' for None."""
    if value is None:
        return "—"
    if isinstance(value, float):
        return escape(f"{value:.4g}")
    return escape(str(value))


def page(title: str, body: str, *, sortable: bool = False) -> str:
    script = f"<script>{SORT_JS}</script>" if sortable else ""
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{escape(title)}</title>"
            f"<style>{CSS}</style></head><body>\n{body}\n{script}</body></html>\n")


def table(headers, rows, *, sortable=False, numeric=()) -> str:
    """A table; ``rows`` hold already-escaped cell HTML, ``numeric`` the column indices aligned right."""
    cls = ' class="sortable"' if sortable else ""
    head = "".join(f"<th>{escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f'<td class="num">{c}</td>' if i in numeric else f"<td>{c}</td>"
                                    for i, c in enumerate(r)) + "</tr>\n" for r in rows)
    return f"<table{cls}><thead><tr>{head}</tr></thead><tbody>\n{body}</tbody></table>"


def status_span(status: str) -> str:
    return f'<span class="{status.replace(" ", "-")}">{escape(status)}</span>'


def verdict_span(verdict: str | None) -> str:
    return "—" if verdict is None else f'<span class="{escape(verdict)}">{escape(verdict)}</span>'


def banner_html(b: dict) -> str:
    head = {"ok": "No failure recorded.", "partly_failed": "Partly failed campaign.",
            "empty": "Empty campaign."}[b["level"]]
    items = "".join(f"<li>{escape(m)}</li>" for m in b["messages"])
    return f'<div class="banner {b["level"]}"><strong>{escape(head)}</strong><ul>{items}</ul></div>'


def img(src: str | None, alt: str) -> str:
    return f'<img src="{escape(src)}" alt="{escape(alt)}">' if src else f'<p class="small">({escape(alt)}: not drawn)</p>'


def index_page(rep: dict, images: dict, sheets: list[dict]) -> str:
    """The campaign page: banner, summary, maps, progress, pass rates, T/GRLM, heliostat table, events."""
    c, s = rep["campaign"], rep["summary"]
    out = [f"<h1>Calibration campaign report — {e(c.get('name') if c else 'no campaign')}</h1>",
           banner_html(rep["status"])]
    if c:
        out.append(table(["campaign", "mode", "status", "started", "ended", "field config", "database"],
                         [[e(c["id"]), e(c["mode"]), e(c["status"]), e(c["started_utc"]), e(c["ended_utc"]),
                           e(c["field_config"]), e(rep["database"])]]))
    out.append("<h2>Summary</h2>")
    pr = "—" if s.get("pass_rate") is None else f"{100 * s['pass_rate']:.1f} %"
    ar = "—" if s.get("acceptance_rate") is None else f"{100 * s['acceptance_rate']:.1f} %"
    out.append(table(["heliostats", "accepted", "visits", "valid visits", "pass rate", "observations", "valid obs.",
                      "gated [h]", "stowed [h]"],
                     [[e(s["heliostats"]), f"{e(s['accepted'])} ({ar})", e(s["visits"]), e(s["valid_visits"]), pr,
                       e(s["observations"]), e(s["valid_observations"]), e(s["gated_hours"]), e(s["stowed_hours"])]],
                     numeric=range(9)))
    if s["visits_by_outcome"]:
        out.append('<p class="small">visit outcomes: ' + ", ".join(f"{e(k)} {e(v)}" for k, v in s["visits_by_outcome"].items())
                   + (("; invalid observations: " + ", ".join(f"{e(k)} {e(v)}" for k, v in s["invalid_by_reason"].items()))
                      if s["invalid_by_reason"] else "") + "</p>")
    out.append('<p class="small">All figures as JSON: <a href="report.json">report.json</a>.</p>')
    out += ["<h2>Field map</h2>", img(images.get("field_map"), "field map")]
    out += ["<h2>Campaign progress</h2>", img(images.get("progress"), "campaign progress")]
    p = rep["pass_rate"]
    out += ["<h2>Correction pass rate (paper figures 6–8)</h2>",
            f'<p class="small">{e(p["definition"])} ({e(p["threshold_mrad"])} mrad). Conditions of a visit: those of '
            "its first observation that recorded them.</p>",
            '<div class="grid3">' + "".join(img(images.get(f"pass_{k}"), f"pass rate against {k}")
                                            for k in ("wind", "dni", "cleanliness")) + "</div>"]
    t = rep["tracking_test"]["field"]
    out += ["<h2>Tracking accuracy, T/GRLM 02-2014 (figure 3, clause 8.2)</h2>",
            f"<p>Clause 8.2 verdict of the field's pooled first placements: {verdict_span(t['verdict'])} — "
            f"{escape(t['message'])}</p>",
            f'<p class="small">Points: {e(rep["tracking_test"]["points"])}.</p>',
            img(images.get("figure_3"), "T/GRLM figure 3")]
    out.append(f"<h2>Heliostats ({len(sheets)})</h2><p class=\"small\">Click a column to sort; a heliostat's id "
               "opens its sheet.</p>")
    rows = []
    for h in sheets:
        v = h["verdict"] or {}
        tt = h["tracking_test"]["verdict"] if h.get("tracking_test") else None
        rows.append([f'<a href="{escape(h["href"])}">{e(h["id"])}</a>', e(h["target"]), status_span(h["status"]),
                     e(h["visits"]), e(h["valid_observations"]), e(h["observations"]), e(v.get("rms_mrad")),
                     e(h["present_error_mrad"]), verdict_span(tt), e("; ".join(v.get("reasons", [])))])
    out.append(table(["heliostat", "target", "status", "visits", "valid obs.", "obs.", "RMS [mrad]",
                      "present error [mrad]", "clause 8.2", "reasons"], rows, sortable=True, numeric=(3, 4, 5, 6, 7)))
    out.append(washing_html(rep.get("washing"), {h["id"]: h["href"] for h in sheets}))
    ev = rep["events"]["rows"]
    out.append(f"<h2>Event log ({len(ev)})</h2>")
    if rep["events"]["omitted_routine"] or rep["events"]["omitted_old"]:
        out.append(f'<p class="small">Not listed: {rep["events"]["omitted_routine"]} routine events '
                   f'({", ".join(escape(k) for k in F_ROUTINE)}), {rep["events"]["omitted_old"]} older events.</p>')
    out.append(table(["time", "kind", "heliostat", "reason"],
                     [[e(x["time_utc"]), e(x["kind"]), e(x["heliostat"]), e(x["reason"])] for x in ev])
               if ev else "<p>No event recorded.</p>")
    out.append(f'<p class="small">Generated {e(rep["generated_utc"])} by helicalib {e(rep["helicalib"])}.</p>')
    return page(f"helicalib report — {c.get('name') if c else 'empty'}", "\n".join(out), sortable=True)


def washing_html(w: dict | None, hrefs: dict) -> str:
    """The campaign page's list of mirrors that need washing (``report.json`` ``washing``)."""
    if w is None:
        return ""
    rows = w["rows"]
    out = [f"<h2>Mirrors to wash ({len(rows)})</h2>",
           f'<p class="small">Present cleanliness below {e(w["threshold"])} ({e(w["threshold_source"])}): the newest '
           "value measured from the spot's power (measured against expected power), else the plant's register; "
           f"dirtiest first. {e(w['heliostats_with_value'])} heliostats have a value, "
           f"{e(w['heliostats_measured'])} of them measured.</p>"]
    if not rows:
        out.append("<p>No mirror needs washing.</p>")
        return "\n".join(out)
    cells = []
    for r in rows:
        link = hrefs.get(r["heliostat"])
        name = f'<a href="{escape(link)}">{e(r["heliostat"])}</a>' if link else e(r["heliostat"])
        cells.append([name, e(r["target"]), f'<span data-v="{e(r["cleanliness"])}">{e(r["cleanliness"])}</span>',
                      e(r["source"]), e(r["time_utc"]), e(r["plant_cleanliness"]), e(r["n_measured"])])
    out.append(table(["heliostat", "target", "cleanliness", "source", "date", "plant's value", "measurements"],
                     cells, sortable=True, numeric=(2, 5, 6)))
    return "\n".join(out)


def cleanliness_svg(points: list[tuple[float, float]], limit: float | None, width: int = 640, height: int = 180) -> str:
    """A small inline SVG of (time [s], cleanliness) points, the washing threshold dashed."""
    if not points:
        return ""
    t = [p[0] for p in points]
    t0, t1 = min(t), max(t)
    span = (t1 - t0) or 1.0
    lo = min([0.0] + [p[1] for p in points])
    hi = max([1.0] + [p[1] for p in points])
    pad = 30

    def xy(tt, c):
        return (pad + (tt - t0) / span * (width - 2 * pad), height - pad - (c - lo) / (hi - lo) * (height - 2 * pad))

    pts = " ".join(f"{x:.1f},{y:.1f}" for x, y in (xy(a, b) for a, b in points))
    dots = "".join(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="3" fill="#1d3557"/>' for x, y in (xy(a, b) for a, b in points))
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" role="img" '
           'aria-label="measured cleanliness over time" style="border:1px solid #eee">',
           f'<text x="4" y="14" font-size="11" fill="#555">cleanliness {lo:g}–{hi:g}; time →</text>',
           f'<polyline points="{pts}" fill="none" stroke="#1d3557" stroke-width="1.5"/>', dots]
    if limit is not None:
        y = xy(t0, limit)[1]
        out.append(f'<line x1="{pad}" x2="{width - pad}" y1="{y:.1f}" y2="{y:.1f}" stroke="#d1495b" '
                   f'stroke-dasharray="5,4"/><text x="{width - pad}" y="{y - 3:.1f}" font-size="11" fill="#d1495b" '
                   f'text-anchor="end">wash below {limit:g}</text>')
    out.append("</svg>")
    return "".join(out)


def cleanliness_html(c: dict | None) -> str:
    """A sheet's cleanliness section: present value, washing verdict, measured values over time."""
    if c is None:
        return ""
    out = ["<h2>Mirror cleanliness</h2>"]
    if c["present"] is None:
        out.append("<p>No cleanliness recorded (neither measured nor from the plant).</p>")
        return "\n".join(out)
    wash = {True: '<span class="fail">needs washing</span>', False: '<span class="pass">clean enough</span>',
            None: "—"}[c["needs_washing"]]
    out.append(f"<p>Present cleanliness {e(c['present'])} ({e(c['source'])}): {wash} "
               f"(threshold {e(c['threshold'])}).</p>")
    m = c["measured"]
    if not m:
        out.append("<p class=\"small\">No cleanliness was measured from the spot (the value is the plant's).</p>")
        return "\n".join(out)
    out.append(cleanliness_svg([(r["time_s"], r["cleanliness_measured"]) for r in m], c["threshold"]))
    out.append(table(["observation", "visit", "time", "measured", "plant's value"],
                     [[e(r["id"]), e(r["visit_id"]), e(r["time_utc"]), e(r["cleanliness_measured"]),
                       e(r["plant_cleanliness"])] for r in m], numeric=(0, 1, 3, 4)))
    return "\n".join(out)


def coverage_html(details: dict) -> str:
    """The paper-2.4 coverage the verdict recorded (bands and windows with their point counts), if any."""
    parts = []
    for key, label in (("rising_ok", "rising band"), ("setting_ok", "setting band")):
        if key in details:
            parts.append(f"{label} {'✓' if details[key] else '✗'}")
    counts = details.get("window_counts")
    if isinstance(counts, list) and counts:
        parts.append("high windows: " + " ".join(f"{k + 1}:{'✓' if c else '✗'}({c})" for k, c in enumerate(counts)))
    return f'<p class="small">Coverage: {escape("; ".join(parts))}</p>' if parts else ""


def sheet_page(sh: dict, plot_src: str | None, frames: dict | None, json_src: str) -> str:
    """One heliostat's page: verdict with reasons, plots, frames, fit, corrections, observations."""
    out = ['<p><a href="../index.html">← campaign report</a></p>',
           f"<h1>Heliostat {e(sh['id'])} (target {e(sh['target'])}): {status_span(sh['status'])}</h1>"]
    v = sh["verdict"]
    if v is None:
        out.append("<p>No acceptance verdict recorded yet.</p>")
    else:
        out.append(f"<p>Verdict of {e(v['time_utc'])}: {status_span('accepted' if v['accepted'] else 'not accepted')}, "
                   f"{e(v['n_points'])} valid points, RMS {e(v['rms_mrad'])} mrad.</p>")
        if v["reasons"]:
            out.append("<ul>" + "".join(f"<li>{escape(r)}</li>" for r in v["reasons"]) + "</ul>")
        out.append(coverage_html(v.get("details") or {}))
    tt = sh.get("tracking_test")
    out.append("<p>T/GRLM clause 8.2 on its first placements: " + (
        f"{verdict_span(tt['verdict'])} — {escape(tt['message'])}" if tt else "no point") + "</p>")
    out.append(table(["visits", "observations", "valid", "RMS of valid [mrad]", "present error [mrad]"],
                     [[e(sh["visits"]), e(sh["observations"]), e(sh["valid_observations"]), e(sh["valid_rms_mrad"]),
                       e(sh["present_error_mrad"])]], numeric=range(5)))
    out += ["<h2>Observations and corrections</h2>", img(plot_src, "observation plots")]
    out.append(cleanliness_html(sh.get("cleanliness")))
    out.append("<h2>Latest visit: before and after frames</h2>")
    lf = sh["latest_frames"]
    if lf is None:
        out.append("<p>No visit saved a before and an after frame.</p>")
    else:
        out.append(f'<p class="small">Observation {e(lf["id"])} at {e(lf["time_utc"])}: {e(lf["reason"])} — '
                   f'{e(lf["message"])}. Green: marks; cyan: board centre; yellow: annex A window; red: spot centre '
                   "measured again; magenta circle: stored spot centre.</p>")
        out.append(img(frames.get("src") if frames else None, "before/after frames"))
        if frames and frames.get("note"):
            out.append(f'<p class="small">{e(frames["note"])}</p>')
    out.append("<h2>Fitted error model</h2>")
    fit = sh["fit"]
    if fit is None:
        out.append("<p>No fit recorded.</p>")
    else:
        out.append(f'<p class="small">{e(fit["model"])}, {e(fit["n_points"])} points, residual RMS '
                   f'{e(fit["rms_mrad"])} mrad, {e(fit["time_utc"])}.</p>')
        out.append(table(["parameter", "value", "± 1σ", "unit", "meaning"],
                         [[e(p["name"]), e(p["value"]), e(p["sigma"]), e(p["unit"]), e(p["description"])]
                          for p in fit["parameters"]], numeric=(1, 2)))
    out.append("<h2>Visits</h2>")
    out.append(table(["visit", "started", "outcome", "reason", "errors by placement [mrad]", "invalid"],
                     [[e(c["visit_id"]), e(c["started_utc"]), e(c["outcome"]), e(c["reason"]),
                       e(" → ".join(f"{x:.2f}" for x in c["errors_mrad"])), e(", ".join(c["invalid_reasons"]))]
                      for c in sh["corrections"]]) if sh["corrections"] else "<p>No visit.</p>")
    out.append(f"<h2>Observations ({len(sh['observation_rows'])})</h2>")
    out.append(f'<p class="small">As JSON: <a href="{escape(json_src)}">{escape(json_src)}</a>.</p>')
    out.append(table(["id", "visit", "placement", "time", "elev. [deg]", "wind [m/s]", "DNI [W/m²]", "clean.",
                      "clean. measured", "valid", "reason", "error [mrad]"],
                     [[e(r["id"]), e(r["visit_id"]), e(r["iteration"]), e(r["time_utc"]), e(r["sun_elevation_deg"]),
                       e(r["wind_ms"]), e(r["dni_wm2"]), e(r["cleanliness"]), e(r.get("cleanliness_measured")),
                       e(r["valid"]), e(r["reason"]), e(r["error_mrad"])] for r in sh["observation_rows"]],
                     sortable=True, numeric=(0, 1, 2, 4, 5, 6, 7, 8, 11)))
    return page(f"helicalib — heliostat {sh['id']}", "\n".join(out), sortable=True)
