"""One summary from the summaries of a split simulation's groups (:mod:`helicalib.app.split`).

Each group's summary (:func:`~helicalib.app.sim_figures.summarise`) covers its own heliostats
against the same simulated plant, weather and clock; :func:`combine_summaries` makes the whole
field's figures of them, key by key:

* counts add up (heliostats, accepted, visits, checks, drifted ...; ``outcomes`` per outcome),
  lists of events and drift days are joined, ``acceptance_rate`` is recomputed;
* ``visits_per_target_hour`` and ``board_time_share_after_commissioning`` add up (each group's
  figure is already over all the field's boards);
* the per-board peak, the gated and stowed hours and the days (one weather, one clock) are the
  largest group's;
* RMS figures combine in quadrature, weighted by the heliostats they cover (``..._accepted_...``
  by the accepted ones, first shots by the valid visits); per-month lists likewise, month by month;
* other numbers (95th percentiles, medians, shares, coverages, mean iterations) are the weighted
  mean of the groups' figures: close to, not exactly, the unsplit figure (docs/simulator.md);
* ``drift_median_days_to_fix`` is the median of the joined days to fix; ``commissioned_day`` is
  read again from the merged database by the caller.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from typing import Any

SUMS = ("heliostats", "accepted", "visits", "valid_visits", "shared_visits", "drifted", "checks", "drift_detected",
        "drift_false_alarms", "predicted_heliostats", "visits_per_target_hour", "board_time_share_after_commissioning")
LARGEST = ("peak_visits_on_a_board", "gated_hours", "stowed_hours", "days", "wall_s")
JOINED = ("drift_events", "drift_days_to_fix")
SAME = ("fidelity", "spots_per_board")


def _weight(key: str, s: dict) -> float:
    """How many a group's figure ``key`` covers."""
    if "accepted" in key:
        return float(s.get("accepted") or 0)
    if key.startswith("first_shot") or key == "mean_iterations":
        return float(s.get("valid_visits") or 0)
    if key.startswith("predicted_") or key == "true_exceed_share":
        return float(s.get("predicted_heliostats") or 0)
    return float(s.get("heliostats") or 0)


def _mean(values: list[tuple[float, float]], quadrature: bool) -> float | None:
    """Weighted mean of (value, weight) pairs (in quadrature for RMS figures); None if nothing counts."""
    pairs = [(v, w) for v, w in values if v is not None and isinstance(v, (int, float)) and math.isfinite(v) and w > 0]
    total = sum(w for _v, w in pairs)
    if not total:
        return None
    if quadrature:
        return round(math.sqrt(sum(w * v * v for v, w in pairs) / total), 3)
    return round(sum(w * v for v, w in pairs) / total, 4)


def _rounded(x: float) -> float:
    return round(x, 4) if isinstance(x, float) else x


def combine_summaries(summaries: Sequence[dict]) -> dict[str, Any]:
    """The whole field's summary from its groups' (module docstring); ``{}`` when there are none."""
    if not summaries:
        return {}
    keys: list[str] = []
    for s in summaries:
        keys.extend(k for k in s if k not in keys)
    out: dict[str, Any] = {}
    for key in keys:
        values = [s.get(key) for s in summaries]
        present = [v for v in values if v is not None]
        if key in SUMS:
            out[key] = _rounded(sum(present)) if present else None
        elif key in LARGEST:
            out[key] = max(present) if present else None
        elif key in JOINED:
            out[key] = [x for v in present for x in v]
        elif key == "outcomes":
            merged: dict[str, int] = {}
            for v in present:
                for name, n in v.items():
                    merged[name] = merged.get(name, 0) + n
            out[key] = merged
        elif key in SAME or not present or not all(isinstance(v, (int, float, list)) for v in present):
            out[key] = present[0] if present else None
        elif all(isinstance(v, list) for v in present):  # per month
            months = max(len(v) for v in present)
            out[key] = [_mean([(v[m] if m < len(v) else None, _weight(key, s)) for v, s in zip(values, summaries)
                               if v is not None], "rms" in key) for m in range(months)]
        else:
            out[key] = _mean([(v, _weight(key, s)) for v, s in zip(values, summaries)], "rms" in key)
    if out.get("heliostats"):
        out["acceptance_rate"] = round(out["accepted"] / out["heliostats"], 4)
    if "drift_days_to_fix" in out and out.get("drifted"):
        days = [math.inf if d is None else d for d in out["drift_days_to_fix"]]
        median = statistics.median(days) if days else None
        out["drift_median_days_to_fix"] = None if median is None or not math.isfinite(median) else round(median, 2)
    return out
