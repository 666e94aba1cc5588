"""Matplotlib drawings of the report's figure dictionaries (Agg backend, labelled axes with units).

Each function takes a dictionary from :mod:`helicalib.report.figures` or :mod:`helicalib.report.grlm`
and a PNG path, draws, saves and closes. The per-heliostat sheets use :class:`SheetPlotter`
(:mod:`helicalib.report.sheet_plots`), which reuses one figure for the whole field.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.dates as mdates  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

DPI = 90
STATUS_COLOURS = {"accepted": "#2a9d3a", "not accepted": "#d1495b", "no verdict": "#9a9a9a"}


def to_dates(times_s) -> np.ndarray:
    """UTC seconds → matplotlib date numbers."""
    t = np.asarray([np.nan if x is None else x for x in times_s], dtype=float)
    return t / 86400.0 + mdates.date2num(np.datetime64("1970-01-01T00:00:00"))


def time_axis(ax) -> None:
    loc = mdates.AutoDateLocator(minticks=3, maxticks=8)
    ax.xaxis.set_major_locator(loc)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc))
    ax.set_xlabel("time (UTC)")


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _empty(ax, text: str) -> None:
    import textwrap

    ax.text(0.5, 0.5, "\n".join(textwrap.wrap(text, 48)), ha="center", va="center", transform=ax.transAxes,
            color="#666", fontsize=9)


def plot_field_map(fm: dict, path: Path) -> Path:
    """Two maps of the field, east vs north [m]: acceptance status, and present tracking error [mrad]."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 5.2), layout="constrained")
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
        return _save(fig, path)
    e = np.array([r["east_m"] for r in rows])
    n = np.array([r["north_m"] for r in rows])
    size = 60 if len(rows) <= 100 else max(6, 6000 / len(rows))
    for status, colour in STATUS_COLOURS.items():
        sel = np.array([r["status"] == status for r in rows])
        if sel.any():
            a1.scatter(e[sel], n[sel], s=size, c=colour, edgecolors="k", linewidths=0.3,
                       label=f"{status} ({int(sel.sum())})")
    a1.set_title("acceptance status (paper 2.4)")
    a1.legend(loc="best", fontsize=8)
    err = np.array([np.nan if r["present_error_mrad"] is None else r["present_error_mrad"] for r in rows])
    known = np.isfinite(err)
    if (~known).any():
        a2.scatter(e[~known], n[~known], s=size, facecolors="none", edgecolors="#999", label="no valid point")
    if known.any():
        sc = a2.scatter(e[known], n[known], s=size, c=err[known], cmap="viridis_r", edgecolors="k", linewidths=0.3,
                        vmin=0.0, vmax=max(float(np.nanpercentile(err[known], 95)), 1.0))
        fig.colorbar(sc, ax=a2, label="present tracking error [mrad]")
    a2.set_title("present tracking error (newest valid observation)")
    a2.legend(loc="best", fontsize=8)
    return _save(fig, path)


def plot_progress(pr: dict, path: Path) -> Path:
    """Campaign progress over time: accepted heliostats, visits, gated and stowed hours (cumulative)."""
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True, layout="constrained")
    if not pr["times_s"]:
        for ax in axes:
            _empty(ax, "no campaign")
        return _save(fig, path)
    t = to_dates(pr["times_s"])
    axes[0].step(t, pr["accepted"], where="post", color=STATUS_COLOURS["accepted"])
    axes[0].set_ylabel("accepted heliostats [-]")
    axes[1].step(t, pr["visits"], where="post", label="visits")
    axes[1].step(t, pr["valid_visits"], where="post", label="visits with a valid point")
    axes[1].set_ylabel("visits, cumulative [-]")
    axes[1].legend(fontsize=8, loc="upper left")
    axes[2].plot(t, pr["gated_hours"], label="gated (weather)")
    axes[2].plot(t, pr["stowed_hours"], label="stowed (wind)")
    axes[2].set_ylabel("hours, cumulative [h]")
    axes[2].legend(fontsize=8, loc="upper left")
    for a, b in pr["stowed_spans_s"]:
        for ax in axes:
            ax.axvspan(*to_dates([a, b]), color="#4c72b0", alpha=0.12, lw=0)
    for ax in axes:
        ax.grid(alpha=0.3)
    time_axis(axes[2])
    axes[0].set_title("campaign progress (shaded: field stowed)")
    return _save(fig, path)


def plot_pass_rate(fig_data: dict, path: Path, number: int) -> Path:
    """Correction pass rate [%] against one condition, as the paper's figure ``number`` (6, 7 or 8)."""
    fig, ax = plt.subplots(figsize=(7, 4.6), layout="constrained")
    edges = np.asarray(fig_data["edges"], dtype=float)
    mid = (edges[:-1] + edges[1:]) / 2
    width = np.diff(edges)
    rate_all = np.array([np.nan if r is None else 100 * r for r in fig_data["all"]["rate"]])
    rate_good = np.array([np.nan if r is None else 100 * r for r in fig_data["good_other"]["rate"]])
    ax.bar(mid, np.nan_to_num(rate_all), width=0.85 * width, color="#8fb3d9", label="all visits")
    if np.isfinite(rate_good).any():
        ax.plot(mid, rate_good, "o-", color="#c0392b", label=f"other conditions good ({fig_data['good_other']['condition']})")
    ax.axhline(100 * fig_data["paper_rate"], color="k", ls="--", lw=1, label="paper: 60 % in good conditions")
    for x, n, k in zip(mid, fig_data["all"]["n"], fig_data["all"]["passed"]):
        if n:
            ax.text(x, 101, f"{k}/{n}", ha="center", va="bottom", fontsize=7, color="#555")
    ax.set_ylim(0, 112)
    ax.set_xlim(edges[0], edges[-1])
    ax.set_xlabel(f"{fig_data['label']} [{fig_data['unit']}]")
    ax.set_ylabel("correction pass rate [%]")
    ax.set_title(f"pass rate against {fig_data['label']} (cf. paper fig. {number}; passed/visits per bin)", fontsize=10)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    ax.grid(alpha=0.3)
    if not any(fig_data["all"]["n"]):
        _empty(ax, f"no visit with a recorded {fig_data['label']}")
    return _save(fig, path)


def plot_figure_3(tt: dict, path: Path) -> Path:
    """T/GRLM figure 3: fraction of tracking errors within 3.5 mrad per wind bin, with the clause 8.2 limits."""
    f3, field, spec = tt["figure_3"], tt["field"], tt["spec"]
    fig, ax = plt.subplots(figsize=(7.5, 4.8), layout="constrained")
    edges = np.asarray(f3["edges_ms"], dtype=float)
    mid = (edges[:-1] + edges[1:]) / 2
    frac = np.array([np.nan if f is None else 100 * f for f in f3["fraction"]])
    ax.bar(mid, np.nan_to_num(frac), width=0.85 * np.diff(edges), color="#7fa7c9", label="measured")
    for x, n, k in zip(mid, f3["n"], f3["within"]):
        if n:
            ax.text(x, 101, f"{k}/{n}", ha="center", va="bottom", fontsize=7, color="#555")
    for b in field["bins"]:
        colour = {True: "#2a9d3a", False: "#d1495b", None: "#999"}[b["pass"]]
        ax.hlines(100 * b["required"], b["low_ms"], b["high_ms"], colors=colour, lw=3)
        if b["fraction"] is not None:
            ax.plot(b["wind_ms"], 100 * b["fraction"], "D", color=colour, ms=7)
    ax.plot([], [], color="#555", lw=3, label="clause 8.2 minimum (bin ± half width)")
    ax.plot([], [], "D", color="#555", label="fraction in the clause 8.2 bin")
    ax.set_xlim(edges[0], edges[-1])
    ax.set_ylim(0, 112)
    ax.set_xlabel("wind speed [m/s]")
    ax.set_ylabel(f"errors within {spec['threshold_mrad']:g} mrad [%]")
    ax.set_title(f"T/GRLM 02-2014 fig. 3 — clause 8.2: {field['verdict'].upper()} ({field['n']} first placements; "
                 "within/points per bin)", fontsize=10)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3)
    ax.grid(alpha=0.3)
    if not field["n"]:
        _empty(ax, "no valid first placement with a recorded wind")
    return _save(fig, path)
