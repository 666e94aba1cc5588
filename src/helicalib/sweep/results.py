"""The sweep's table (one row per run, failed runs marked) and the per-cell statistics.

Per cell and figure: the number of runs with a value, their mean, standard deviation and a 95 %
interval for the mean over seeds that keeps the figure's scale (:data:`SCALES`, docs/sweep.md):

* a positive figure (an RMS, days, a visit rate): the t-interval on the logarithms, for the mean
  of a log-normal (modified Cox method): ``exp(ȳ + s²/2 ± t(0.975, n − 1) · √(s²/n + s⁴/(2(n − 1))))``
  with ``ȳ``, ``s`` the mean and standard deviation of ``ln x``: never below 0, wider above the
  mean than below as the spread of such figures is. A run with the value 0 makes it the t-interval
  ``mean ± t(0.975, n − 1) · s / √n`` cut at 0;
* a share (accepted share): the t-interval cut to [0, 1].

``scipy.stats.t``; no interval with fewer than 2 values. ``days_to_95`` only has a value in the
runs that reached 95 % accepted; ``reached_95`` says how many of the cell's finished runs that is.
A cell whose finished runs accepted no heliostat at all says so (``note``) instead of a figure of
the accepted heliostats.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

FIGURES = ("days_to_95", "acceptance_rate", "true_sky_rms_accepted_mrad", "true_sky_rms_mrad",
           "visits_per_board_hour")
"""The figures summarised per cell, in the order shown."""
SUMMARY_COLUMNS = ("heliostats", "accepted", "acceptance_rate", "visits", "valid_visits", "true_sky_rms_accepted_mrad",
                   "true_sky_rms_mrad", "first_shot_rms_mrad", "true_tracking_rms_mrad", "gated_hours", "stowed_hours")
SCALES = {"days_to_95": "positive", "acceptance_rate": "share", "true_sky_rms_accepted_mrad": "positive",
          "true_sky_rms_mrad": "positive", "visits_per_board_hour": "positive"}
"""What values each figure can take: its interval keeps to them (module docstring)."""
INTERVAL = ("95 % interval for the mean over seeds, n = runs with a value (scipy.stats.t): positive figures "
            "(RMS, days, visit rates) log-scale t-interval for a log-normal mean, "
            "exp(ȳ + s²/2 ± t(0.975, n-1)·√(s²/n + s⁴/(2(n-1)))) over y = ln x (with fewer than 3 values, a 0 among them or an "
            "overflow: mean ± t(0.975, n-1)·s/√n cut at 0); shares: mean ± t(0.975, n-1)·s/√n cut to [0, 1]")
MIN_LOG_T = 3
"""Fewest values for the log-scale interval of a positive figure: with two, the variance of the logs
has one degree of freedom and the interval spans orders of magnitude (e.g. 0.05 and 3.0 gave
[6e-34, 1e36]); two values get the t-interval cut at 0."""

NOTHING_ACCEPTED = "no heliostat accepted in any seed"
"""A cell's ``note`` when none of its finished runs accepted a heliostat."""


def row(run, record: dict | None = None, error: str | None = None) -> dict:
    """One table row: the run's settings, then its figures (``status`` ok) or its error (failed)."""
    out = {"cell": run.cell, "scenario": run.scenario, "planner": run.planner, "start": run.start,
           "start_s": run.start_s, "seed": run.seed, "sim_seed": run.sim_seed, "days": run.days,
           "status": "ok" if record is not None else "failed", "error": error or ""}
    summary = (record or {}).get("summary", {})
    for key in SUMMARY_COLUMNS:
        out[key] = summary.get(key)
    for key in ("days_to_95", "visits_per_board_hour", "boards_used", "wall_s"):
        out[key] = (record or {}).get(key)
    out["run_dir"] = run.run_dir
    return out


def mean_interval(values, scale: str | None = None) -> dict:
    """``{"n", "mean", "sd", "ci95", "interval"}`` of the finite values; ``scale`` ``"positive"``,
    ``"share"`` or None (the plain t-interval) chooses the interval (module docstring), ``interval``
    names the one used."""
    from scipy import stats

    x = np.array([float(v) for v in values if v is not None and math.isfinite(float(v))])
    if x.size == 0:
        return {"n": 0, "mean": None, "sd": None, "ci95": None, "interval": None}
    mean = float(np.mean(x))
    if x.size < 2:
        return {"n": 1, "mean": mean, "sd": None, "ci95": None, "interval": None}
    sd = float(np.std(x, ddof=1))
    t = float(stats.t.ppf(0.975, x.size - 1))
    if scale == "positive" and x.size >= MIN_LOG_T and np.all(x > 0):
        y = np.log(x)
        var = float(np.var(y, ddof=1))
        centre = float(np.mean(y)) + var / 2.0
        half = t * math.sqrt(var / x.size + var * var / (2.0 * (x.size - 1)))
        try:
            return {"n": int(x.size), "mean": mean, "sd": sd,
                    "ci95": [math.exp(centre - half), math.exp(centre + half)], "interval": "log-t"}
        except OverflowError:  # seeds orders of magnitude apart: the plain interval below, cut at 0
            pass
    half = t * sd / math.sqrt(x.size)
    low, high = mean - half, mean + half
    if scale == "positive":
        return {"n": int(x.size), "mean": mean, "sd": sd, "ci95": [max(low, 0.0), high], "interval": "t, cut at 0"}
    if scale == "share":
        return {"n": int(x.size), "mean": mean, "sd": sd, "ci95": [max(low, 0.0), min(high, 1.0)],
                "interval": "t, cut to [0, 1]"}
    return {"n": int(x.size), "mean": mean, "sd": sd, "ci95": [low, high], "interval": "t"}


def cell_statistics(rows: list[dict]) -> list[dict]:
    """Per cell (in the table's order): runs, failed runs, reached 95 %, and each figure's mean and interval."""
    cells: dict[str, list[dict]] = {}
    for r in rows:
        cells.setdefault(r["cell"], []).append(r)
    out = []
    for key, rs in cells.items():
        ok = [r for r in rs if r["status"] == "ok"]
        first = rs[0]
        none_accepted = bool(ok) and not any(r["accepted"] for r in ok)
        out.append({"cell": key, "scenario": first["scenario"], "planner": first["planner"], "start": first["start"],
                    "runs": len(rs), "finished": len(ok), "failed": len(rs) - len(ok),
                    "reached_95": sum(r["days_to_95"] is not None for r in ok),
                    "note": NOTHING_ACCEPTED if none_accepted else None,
                    "figures": {f: mean_interval((r[f] for r in ok), SCALES[f]) for f in FIGURES}})
    return out


def write_outputs(out_dir: Path, rows: list[dict], document: dict) -> list[Path]:
    """``results.csv`` (always), ``results.parquet`` (when pyarrow is installed), ``summary.json``;
    each written atomically. Returns the paths written."""
    import pandas as pd

    out_dir = Path(out_dir)
    table = pd.DataFrame(rows)
    written = [_atomic(out_dir / "results.csv", lambda p: table.to_csv(p, index=False))]
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        pass
    else:
        written.append(_atomic(out_dir / "results.parquet", lambda p: table.to_parquet(p, index=False)))
    written.append(_atomic(out_dir / "summary.json",
                           lambda p: p.write_text(json.dumps(document, indent=2), encoding="utf-8")))
    return written


def _atomic(path: Path, write) -> Path:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)
    return path


def format_cells(cells: list[dict]) -> list[str]:
    """The per-cell statistics as text lines: ``mean [low, high]`` per figure."""
    head = ["cell", "runs", "days to 95 %", "accepted share", "sky RMS accepted", "sky RMS all", "visits/board-h"]
    lines = [head]
    for c in cells:
        f = c["figures"]
        days = _fmt(f["days_to_95"]) + f" ({c['reached_95']}/{c['finished']} reached)"
        accepted = c.get("note") or _fmt(f["true_sky_rms_accepted_mrad"])
        lines.append([c["cell"], f"{c['finished']}/{c['runs']}" + (f", {c['failed']} failed" if c["failed"] else ""),
                      days, _fmt(f["acceptance_rate"]), accepted,
                      _fmt(f["true_sky_rms_mrad"]), _fmt(f["visits_per_board_hour"])])
    widths = [max(len(line[k]) for line in lines) for k in range(len(head))]
    return ["  ".join(cell.ljust(w) for cell, w in zip(line, widths)).rstrip() for line in lines]


def _fmt(stat: dict) -> str:
    if stat["mean"] is None:
        return "-"
    text = f"{stat['mean']:.3f}"
    if stat["ci95"] is not None:
        text += f" [{stat['ci95'][0]:.3f}, {stat['ci95'][1]:.3f}]"
    return text
