"""Matplotlib drawings of the report's figure dictionaries (Agg backend, labelled axes with units).

Each ``figure_*`` function takes a dictionary from :mod:`helicalib.report.figures` or
:mod:`helicalib.report.grlm` and returns the drawn matplotlib Figure (tests inspect its lines and
labels); the ``plot_*`` function of the same name saves it as a PNG and closes it. The per-heliostat
sheets use :class:`SheetPlotter` (:mod:`helicalib.report.sheet_plots`), which reuses one figure
for the whole field.

Readable at the size the page shows them: figures are at most :data:`MAX_WIDTH_IN` wide at
:data:`DPI` (the page's 1200 px column shows them 1:1) and every text is at least
:data:`MIN_FONT_PT` (:data:`STYLE`). Error axes are named by :mod:`helicalib.report.measures`; each
limit is drawn only over its own measure. Time axes are UTC below and the site's clock
(:mod:`helicalib.geometry.sitetime`) above.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.dates as mdates  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from helicalib.report.measures import label as measure_label  # noqa: E402
from helicalib.report.measures import name as measure_name  # noqa: E402

DPI = 100
"""Pixels per inch of every PNG: one point of text is 1.39 px, as on a 100 % browser page (1.33 px)."""
MAX_WIDTH_IN = 12.0
"""Widest figure [in]: 1200 px, the page's column, so no figure is shown scaled down."""
MIN_FONT_PT = 10.0
"""Smallest text of any figure [pt]."""
STYLE = {"font.size": 11.0, "axes.titlesize": 12.0, "axes.labelsize": 11.0, "xtick.labelsize": 10.5,
         "ytick.labelsize": 10.5, "legend.fontsize": 10.0, "legend.title_fontsize": 10.0, "figure.titlesize": 12.0}
"""Font sizes [pt] of every report figure (none below :data:`MIN_FONT_PT`)."""
SMALL_PT = MIN_FONT_PT
"""Size of the per-bar count labels and notes [pt]."""
STATUS_COLOURS = {"accepted": "#2a9d3a", "not accepted": "#d1495b", "no verdict": "#9a9a9a"}
LIMIT_COLOURS = {"acceptance": "#2a9d3a", "loop": "#d1495b"}
"""Colour of the acceptance limit and of the loop threshold lines."""


def new_figure(nrows: int = 1, ncols: int = 1, **kw):
    """``plt.subplots`` with :data:`STYLE` (the sizes are fixed on the artists as they are made)."""
    with matplotlib.rc_context(STYLE):
        return plt.subplots(nrows, ncols, dpi=DPI, **kw)


def finish(fig) -> None:
    """Fix every axis' tick label size (ticks are made lazily, after the style context is gone)."""
    for ax in fig.axes:
        ax.tick_params(labelsize=STYLE["xtick.labelsize"])


def to_dates(times_s) -> np.ndarray:
    """UTC seconds → matplotlib date numbers."""
    t = np.asarray([np.nan if x is None else x for x in times_s], dtype=float)
    return t / 86400.0 + mdates.date2num(np.datetime64("1970-01-01T00:00:00"))


def time_axis(ax, site=None, t_ref_s: float | None = None, top: bool = True) -> None:
    """A UTC date axis below; with ``site`` (:class:`~helicalib.geometry.sitetime.SiteTime`) and ``top``,
    the same instants on the site's clock above (its offset at ``t_ref_s``)."""
    loc = mdates.AutoDateLocator(minticks=3, maxticks=7)
    ax.xaxis.set_major_locator(loc)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc))
    ax.set_xlabel("time (UTC)")
    if site is None or not top:
        return
    shift = site.offset_h(t_ref_s if t_ref_s is not None else 0.0) / 24.0
    sec = ax.secondary_xaxis("top", functions=(lambda x: x + shift, lambda x: x - shift))
    loc2 = mdates.AutoDateLocator(minticks=3, maxticks=7)
    sec.xaxis.set_major_locator(loc2)
    sec.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc2, show_offset=False))
    sec.set_xlabel(site.axis_label(t_ref_s if t_ref_s is not None else 0.0), fontsize=STYLE["axes.labelsize"])
    sec.tick_params(labelsize=STYLE["xtick.labelsize"])


def save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _empty(ax, text: str) -> None:
    import textwrap

    ax.text(0.5, 0.5, "\n".join(textwrap.wrap(text, 48)), ha="center", va="center", transform=ax.transAxes,
            color="#666", fontsize=STYLE["font.size"])


def figure_field_map(fm: dict):
    """Two maps of the field, east vs north [m]: acceptance status, and acceptance error [mrad]
    (the colour bar marks the acceptance limit)."""
    fig, (a1, a2) = new_figure(1, 2, figsize=(MAX_WIDTH_IN, 5.4), layout="constrained")
    rows = [r for r in fm["heliostats"] if r["east_m"] is not None]
    for ax in (a1, a2):
        ax.set_xlabel("east [m]")
        ax.set_ylabel("north [m]")
        if rows:
            ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        if fm.get("tower"):
            ax.plot(fm["tower"]["tower_east_m"], fm["tower"]["tower_north_m"], "k^", ms=10, label="tower")
    if not rows:
        for ax in (a1, a2):
            _empty(ax, "no heliostat positions (" + (fm.get("note") or "none enrolled") + ")")
        finish(fig)
        return fig
    e = np.array([r["east_m"] for r in rows])
    n = np.array([r["north_m"] for r in rows])
    size = 60 if len(rows) <= 100 else max(6, 6000 / len(rows))
    for status, colour in STATUS_COLOURS.items():
        sel = np.array([r["status"] == status for r in rows])
        if sel.any():
            a1.scatter(e[sel], n[sel], s=size, c=colour, edgecolors="k", linewidths=0.3,
                       label=f"{status} ({int(sel.sum())})")
    a1.set_title("acceptance status (paper 2.4)")
    a1.legend(loc="best")
    acc = np.array([np.nan if r.get("acceptance_error_mrad") is None else r["acceptance_error_mrad"] for r in rows])
    known = np.isfinite(acc)
    limit = fm.get("acceptance_limit_mrad")
    if (~known).any():
        a2.scatter(e[~known], n[~known], s=size, facecolors="none", edgecolors="#999", label="no verdict")
    if known.any():
        top = max(float(np.nanmax(acc[known])), 1.5 * limit if limit else 1.0)
        sc = a2.scatter(e[known], n[known], s=size, c=acc[known], cmap="viridis_r", edgecolors="k", linewidths=0.3,
                        vmin=0.0, vmax=top)
        bar = fig.colorbar(sc, ax=a2, label=measure_label("acceptance_error")
                           + (f"\n(line: acceptance limit {limit:g} mrad)" if limit else ""))
        if limit:
            bar.ax.axhline(limit, color="#d1495b", lw=3)
    a2.set_title(f"{measure_name('acceptance_error')} (newest verdict)")
    a2.legend(loc="best")
    finish(fig)
    return fig


def plot_field_map(fm: dict, path: Path) -> Path:
    return save(figure_field_map(fm), path)


def figure_progress(pr: dict, site=None):
    """Campaign progress over time: accepted heliostats, visits, gated and stowed hours (cumulative)."""
    fig, axes = new_figure(3, 1, figsize=(10, 8.4), sharex=True, layout="constrained")
    if not pr["times_s"]:
        for ax in axes:
            _empty(ax, "no campaign")
        finish(fig)
        return fig
    t = to_dates(pr["times_s"])
    axes[0].step(t, pr["accepted"], where="post", color=STATUS_COLOURS["accepted"])
    axes[0].set_ylabel("accepted\nheliostats [-]")
    axes[1].step(t, pr["visits"], where="post", label="visits")
    axes[1].step(t, pr["valid_visits"], where="post", label="visits with a valid point")
    axes[1].set_ylabel("visits,\ncumulative [-]")
    axes[1].legend(loc="upper left")
    axes[2].plot(t, pr["gated_hours"], label="gated (weather)")
    axes[2].plot(t, pr["stowed_hours"], label="stowed (wind)")
    axes[2].set_ylabel("hours,\ncumulative [h]")
    axes[2].legend(loc="upper left")
    for a, b in pr["stowed_spans_s"]:
        for ax in axes:
            ax.axvspan(*to_dates([a, b]), color="#4c72b0", alpha=0.12, lw=0)
    for ax in axes:
        ax.grid(alpha=0.3)
    time_axis(axes[2])
    if site is not None:
        time_axis(axes[0], site, pr["times_s"][0])
        axes[0].set_xlabel("")
    axes[0].set_title("campaign progress (shaded: field stowed)")
    finish(fig)
    return fig


def plot_progress(pr: dict, path: Path, site=None) -> Path:
    return save(figure_progress(pr, site), path)


def figure_pass_rate(fig_data: dict, number: int, threshold_mrad: float | None = None):
    """Correction pass rate [%] against one condition, as the paper's figure ``number`` (6, 7 or 8)."""
    fig, ax = new_figure(figsize=(10, 5.2), layout="constrained")
    edges = np.asarray(fig_data["edges"], dtype=float)
    mid = (edges[:-1] + edges[1:]) / 2
    width = np.diff(edges)
    rate_all = np.array([np.nan if r is None else 100 * r for r in fig_data["all"]["rate"]])
    rate_good = np.array([np.nan if r is None else 100 * r for r in fig_data["good_other"]["rate"]])
    ax.bar(mid, np.nan_to_num(rate_all), width=0.85 * width, color="#8fb3d9", label="all visits")
    if np.isfinite(rate_good).any():
        ax.plot(mid, rate_good, "o-", color="#c0392b", label=f"other conditions good ({fig_data['good_other']['condition']})")
    ax.axhline(100 * fig_data["paper_rate"], color="k", ls="--", lw=1, label="paper: 60 % in good conditions")
    ax.set_ylim(0, 118)
    ax.set_xlim(edges[0], edges[-1])
    ax.set_xlabel(f"{fig_data['label']} [{fig_data['unit']}]")
    thr = f" below {threshold_mrad:g} mrad" if threshold_mrad is not None else ""
    ax.set_ylabel(f"visits converged [%]\n(a {measure_name('placement_error')}{thr})")
    ax.set_title(f"correction pass rate against {fig_data['label']} (cf. paper fig. {number}; "
                 "labels: passed/visits)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    ax.grid(alpha=0.3)
    if not any(fig_data["all"]["n"]):
        _empty(ax, f"no visit with a recorded {fig_data['label']}")
    finish(fig)
    count_labels(fig, ax, [(x, f"{k}/{n}") for x, n, k in zip(mid, fig_data["all"]["n"], fig_data["all"]["passed"]) if n])
    return fig


def plot_pass_rate(fig_data: dict, path: Path, number: int, threshold_mrad: float | None = None) -> Path:
    return save(figure_pass_rate(fig_data, number, threshold_mrad), path)


def figure_3(tt: dict):
    """T/GRLM figure 3: share of first-placement errors within the threshold per wind bin, with the clause
    8.2 minima (green met, red not met, grey: no data at that wind)."""
    f3, field, spec = tt["figure_3"], tt["field"], tt["spec"]
    fig, ax = new_figure(figsize=(10, 5.4), layout="constrained")
    edges = np.asarray(f3["edges_ms"], dtype=float)
    mid = (edges[:-1] + edges[1:]) / 2
    frac = np.array([np.nan if f is None else 100 * f for f in f3["fraction"]])
    ax.bar(mid, np.nan_to_num(frac), width=0.85 * np.diff(edges), color="#7fa7c9", label="measured")
    for b in field["bins"]:
        colour = {True: "#2a9d3a", False: "#d1495b", None: "#999"}[b["pass"]]
        ax.hlines(100 * b["required"], b["low_ms"], b["high_ms"], colors=colour, lw=3)
        if b["fraction"] is not None:
            ax.plot(b["wind_ms"], 100 * b["fraction"], "D", color=colour, ms=7)
        else:
            ax.text(b["wind_ms"], 100 * b["required"] - 3, "no data\n(not a failure)", ha="center", va="top",
                    fontsize=SMALL_PT, color="#555")
    ax.plot([], [], color="#555", lw=3, label="clause 8.2 minimum (bin ± half width)")
    ax.plot([], [], "D", color="#555", label="share in the clause 8.2 bin")
    ax.set_xlim(edges[0], edges[-1])
    ax.set_ylim(0, 118)
    ax.set_xlabel("wind speed [m/s]")
    ax.set_ylabel(f"{measure_name('first_placement_error')}s\nwithin {spec['threshold_mrad']:g} mrad [%]")
    verdict = {"pass": "PASS", "fail": "FAIL", "incomplete": "not judged yet (wind bins without data)"}.get(
        field["verdict"], field["verdict"])
    ax.set_title(f"T/GRLM 02-2014 fig. 3 — clause 8.2: {verdict}\n({field['n']} first placements; "
                 "labels: within/points per 1 m/s)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3)
    ax.grid(alpha=0.3)
    if not field["n"]:
        _empty(ax, "no valid first placement with a recorded wind")
    finish(fig)
    count_labels(fig, ax, [(x, f"{k}/{n}") for x, n, k in zip(mid, f3["n"], f3["within"]) if n])
    return fig


LABEL_GAP_PX = 3.0
"""Least gap [px] between two neighbouring count labels above the bars."""


def count_labels(fig, ax, labels: list[tuple[float, str]], y: float = 101.0) -> list:
    """Write each ``(x, text)`` count label above its bar of a percent axis, level when no two
    neighbours touch (closer than :data:`LABEL_GAP_PX`, measured on the drawn figure), else all
    turned upright; the axis then grows upward until the tallest label fits inside it. Returns the
    text artists."""
    texts = [ax.text(x, y, t, ha="center", va="bottom", fontsize=SMALL_PT, color="#444") for x, t in labels]
    if not texts:
        return texts
    fig.draw_without_rendering()  # the final layout, so the extents are the PNG's
    boxes = sorted((t.get_window_extent() for t in texts), key=lambda b: b.x0)
    if any(b.x0 - a.x1 < LABEL_GAP_PX for a, b in zip(boxes, boxes[1:])):
        for t in texts:
            t.set_rotation(90)
        fig.draw_without_rendering()
    box = ax.get_window_extent()
    tall = max(t.get_window_extent().height for t in texts)
    lo, hi = ax.get_ylim()
    # the labels' foot sits (y − lo)/(hi − lo) of the axis' height up; their tops must stay inside it
    need = lo + (y - lo) * box.height / max(box.height - tall - LABEL_GAP_PX, 1.0)
    if need > hi:
        ax.set_ylim(lo, need)
        fig.draw_without_rendering()
    return texts


def plot_figure_3(tt: dict, path: Path) -> Path:
    return save(figure_3(tt), path)
