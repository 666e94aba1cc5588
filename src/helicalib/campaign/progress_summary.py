"""A campaign's progress summed up for a crew at field scale (pure): per board, who needs attention,
the worst errors.

At 10⁴ heliostats nobody reads 10⁴ table rows: ``helicalib status`` prints these figures instead
(the full table with ``--all``, or by itself for a field of at most :data:`FULL_TABLE_MAX`
heliostats), ``--json`` adds them beside the per-heliostat rows, and the crew console pages,
sorts and filters the same rows (:func:`row_state`, :func:`first_missing`).

The rows are :meth:`helicalib.store.sqlite.Store.progress`'s dicts.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

FULL_TABLE_MAX = 200
"""Fields of at most this many heliostats get the full per-heliostat table by default."""
ATTENTION_SHOWN = 20
"""Heliostats listed under "needing attention" (the tally by first missing item counts them all)."""
WORST_SHOWN = 10
"""Heliostats listed under "worst last errors"."""
QUANTILES = (0.5, 0.9)


def row_state(row: dict, out_of_service=frozenset()) -> str:
    """``accepted``, ``out of service`` (the crew took it out), ``not accepted`` (a verdict said no)
    or ``no verdict`` (none yet)."""
    if row["heliostat_id"] in out_of_service:
        return "out of service"
    if row["accepted"] is None:
        return "no verdict"
    return "accepted" if row["accepted"] else "not accepted"


def first_missing(row: dict) -> str:
    """What a heliostat still lacks, in a few words: the verdict's first reason."""
    if row["accepted"]:
        return ""
    if row["accepted"] is None:
        return "no verdict yet" if row["valid"] else ("no valid point yet" if row["visits"] else "not visited yet")
    return (list(row["reasons"]) or ["not accepted"])[0]


@dataclass
class BoardSummary:
    """One board's heliostats: counts by state and the spread of their last valid errors [mrad]."""

    target_id: str
    heliostats: int = 0
    accepted: int = 0
    pending: int = 0
    out_of_service: int = 0
    visits: int = 0
    error_p50_mrad: float | None = None
    error_p90_mrad: float | None = None
    error_max_mrad: float | None = None
    rms_p50_mrad: float | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Summary:
    """The whole campaign's summary (:func:`summarise`)."""

    heliostats: int
    accepted: int
    boards: list[BoardSummary]
    attention: list[dict]
    """Rows not accepted and in service, block order, each with ``state`` and ``missing``."""
    missing_tally: list[tuple[str, int]]
    """First missing item → how many heliostats, most first."""
    worst: list[dict] = field(default_factory=list)
    """The :data:`WORST_SHOWN` largest last valid errors, largest first."""


def _quantile(values: list[float], q: float) -> float | None:
    return None if not values else float(np.quantile(np.asarray(values, dtype=float), q))


def summarise(rows: list[dict], out_of_service=frozenset(), worst_n: int = WORST_SHOWN) -> Summary:
    """Per board counts and error quantiles, the heliostats needing attention, the worst errors."""
    boards: dict[str, BoardSummary] = {}
    errors: dict[str, list[float]] = {}
    rms: dict[str, list[float]] = {}
    attention = []
    for r in rows:
        b = boards.setdefault(r["target_id"], BoardSummary(r["target_id"]))
        state = row_state(r, out_of_service)
        b.heliostats += 1
        b.visits += r["visits"]
        if state == "accepted":
            b.accepted += 1
        elif state == "out of service":
            b.out_of_service += 1
        else:
            b.pending += 1
            attention.append({**r, "state": state, "missing": first_missing(r)})
        if r["last_error_mrad"] is not None:
            errors.setdefault(r["target_id"], []).append(float(r["last_error_mrad"]))
        if r["rms_mrad"] is not None:
            rms.setdefault(r["target_id"], []).append(float(r["rms_mrad"]))
    for tid, b in boards.items():
        e = errors.get(tid, [])
        b.error_p50_mrad, b.error_p90_mrad = (_quantile(e, q) for q in QUANTILES)
        b.error_max_mrad = max(e) if e else None
        b.rms_p50_mrad = _quantile(rms.get(tid, []), 0.5)
    with_error = [r for r in rows if r["last_error_mrad"] is not None]
    worst = sorted(with_error, key=lambda r: -float(r["last_error_mrad"]))[:worst_n]
    tally = Counter(a["missing"] for a in attention).most_common()
    return Summary(heliostats=len(rows), accepted=sum(b.accepted for b in boards.values()),
                   boards=sorted(boards.values(), key=lambda b: b.target_id), attention=attention,
                   missing_tally=tally, worst=[{**r, "state": row_state(r, out_of_service)} for r in worst])


def summary_json(s: Summary) -> dict:
    """The summary's JSON (``status --json``'s ``summary``)."""
    return {"boards": [b.as_dict() for b in s.boards], "needing_attention": len(s.attention),
            "missing": [{"item": k, "heliostats": n} for k, n in s.missing_tally],
            "worst": [{"heliostat_id": r["heliostat_id"], "target_id": r["target_id"],
                       "last_error_mrad": r["last_error_mrad"], "state": r["state"]} for r in s.worst]}
