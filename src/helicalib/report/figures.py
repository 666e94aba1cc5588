"""The campaign-level figures of the report, as pure functions: :class:`CampaignData` in, plain dicts out.

Every dictionary here is written unchanged into ``report.json`` and drawn by
:mod:`helicalib.report.plots`; ``docs/report.md`` lists the keys. Definitions:

* a **visit passed** (the paper's "qualified correction", figures 6–8) when its loop converged:
  at least one VALID observation of the visit has ``error_mrad < loop_threshold_mrad``;
* a visit's **conditions** are the wind, DNI and cleanliness of its first observation that
  recorded them (failure records carry none; such visits are counted as ``n_unknown``);
* a heliostat's **latest placement error** (``present_error_mrad``) is the placement error of its newest
  valid observation (:mod:`helicalib.report.measures` names every error measure);
* **stowed** time runs from each ``stow`` event to the next ``resume``, **gated** time from each
  ``gated`` event to the next ``ungated``, in daylight only (sun above the low band's lower edge,
  as the runner gates); an interval still open ends at the campaign's end.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from collections import Counter
from typing import Any

import numpy as np
import pandas as pd

from helicalib.store.records import off_tracking
from helicalib.report.data import CampaignData

DEFAULT_LOOP_THRESHOLD_MRAD = 3.5
"""Used for the pass rate only when the campaign's field config cannot be read (the paper's value)."""

DEFAULT_MAX_RMS_MRAD = 1.2
"""The paper's acceptance limit, used only when the campaign's field config cannot be read."""

PAPER_PASS_RATE = 0.60
"""The paper's figure: about 60 % correction pass rate in good conditions."""

BINS = {
    "wind": dict(column="wind_ms", unit="m/s", label="wind speed", edges=np.arange(0.0, 16.0 + 1e-9, 1.0)),
    "dni": dict(column="dni_wm2", unit="W/m²", label="DNI", edges=np.arange(0.0, 1200.0 + 1e-9, 100.0)),
    "cleanliness": dict(column="cleanliness", unit="1", label="mirror cleanliness",
                        edges=np.round(np.arange(0.40, 1.0 + 1e-9, 0.05), 2)),
}
"""Bin edges of the pass-rate figures; values outside go to the first or last bin."""

GOOD = {"wind": ("wind_ms", "<=", 5.0), "dni": ("dni_wm2", ">=", 800.0), "cleanliness": ("cleanliness", ">", 0.7)}
"""The paper's good conditions (section 3): each figure holds the other two at these."""


def num(x: Any, nd: int = 4) -> float | None:
    """A float rounded for JSON, or None for None/NaN."""
    if x is None:
        return None
    try:
        f = float(x)
    except (TypeError, ValueError):
        return None
    return None if not math.isfinite(f) else round(f, nd)


def iso(t_s: float | None) -> str | None:
    """``'2026-06-01 03:14:15 UTC'`` (the second truncated); None for None/NaN."""
    if t_s is None or not math.isfinite(float(t_s)):
        return None
    return _dt.datetime.fromtimestamp(math.floor(float(t_s)), _dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def loop_threshold_mrad(data: CampaignData) -> float:
    return float(data.cfg.calibration.loop_threshold_mrad) if data.cfg is not None else DEFAULT_LOOP_THRESHOLD_MRAD


# ---------------------------------------------------------------------------------------- visits
def visit_table(data: CampaignData) -> pd.DataFrame:
    """One row per visit: id, heliostat, outcome, times, observations, valid ones, passed, conditions."""
    cols = ["visit_id", "heliostat_id", "outcome", "started_s", "ended_s", "n_obs", "n_valid", "passed",
            "first_error_mrad", "final_error_mrad", "wind_ms", "dni_wm2", "cleanliness"]
    if not data.visits:
        return pd.DataFrame(columns=cols)
    per_visit = _visit_aggregates(data.observations, loop_threshold_mrad(data))
    rows = []
    for v in data.visits:
        row = dict(visit_id=v.id, heliostat_id=v.heliostat_id, outcome=v.outcome, started_s=v.started_s,
                   ended_s=v.ended_s, n_obs=0, n_valid=0, passed=False, first_error_mrad=None, final_error_mrad=None,
                   wind_ms=None, dni_wm2=None, cleanliness=None)
        row.update(per_visit.get(v.id, {}))
        rows.append(row)
    return pd.DataFrame(rows, columns=cols)


def _visit_aggregates(obs: pd.DataFrame, threshold_mrad: float) -> dict[int, dict]:
    """Per visit id, in one grouped pass over the observations (recording order): observation and valid
    counts, passed (a valid error under ``threshold_mrad``), first and final valid error, and the first
    recorded wind, DNI and cleanliness. A visit's values are None where it has none."""
    if not len(obs):
        return {}
    o = obs[obs["visit_id"].notna()]
    if not len(o):
        return {}
    ok = o["valid"].to_numpy(dtype=bool) & o["error_mrad"].notna().to_numpy()
    frame = pd.DataFrame({"visit_id": o["visit_id"].to_numpy(dtype=float).astype(np.int64),
                          "ok": ok, "err": o["error_mrad"].where(ok).to_numpy(dtype=float),
                          "wind_ms": o["wind_ms"].to_numpy(dtype=float), "dni_wm2": o["dni_wm2"].to_numpy(dtype=float),
                          "cleanliness": o["cleanliness"].to_numpy(dtype=float)})
    frame["below"] = frame["err"] < threshold_mrad
    g = frame.groupby("visit_id", sort=False)
    agg = pd.DataFrame({"n_obs": g.size(), "n_valid": g["ok"].sum(), "passed": g["below"].any(),
                        "first_error_mrad": g["err"].first(), "final_error_mrad": g["err"].last(),
                        "wind_ms": g["wind_ms"].first(), "dni_wm2": g["dni_wm2"].first(),
                        "cleanliness": g["cleanliness"].first()})
    out = {}
    for vid, r in zip(agg.index.tolist(), agg.itertuples(index=False)):
        d = r._asdict()
        d.update(n_obs=int(d["n_obs"]), n_valid=int(d["n_valid"]), passed=bool(d["passed"]))
        for k in ("first_error_mrad", "final_error_mrad", "wind_ms", "dni_wm2", "cleanliness"):
            d[k] = None if d[k] != d[k] else float(d[k])
        out[int(vid)] = d
    return out


# ---------------------------------------------------------------------------------------- intervals
def intervals(events, start_kind: str, end_kind: str, end_s: float) -> list[tuple[float, float]]:
    """[start, end) spans from ``start_kind`` events to the next ``end_kind`` event (or ``end_s``)."""
    out, open_at = [], None
    for e in sorted(events, key=lambda e: (e.time_s, e.id)):
        if e.kind == start_kind and open_at is None:
            open_at = e.time_s
        elif e.kind == end_kind and open_at is not None:
            out.append((open_at, max(open_at, e.time_s)))
            open_at = None
    if open_at is not None:
        out.append((open_at, max(open_at, end_s)))
    return out


def clip_spans(spans, windows) -> list[tuple[float, float]]:
    """The parts of ``spans`` inside any of ``windows`` (both lists of (start, end) [s])."""
    out = []
    for a, b in spans:
        for wa, wb in windows:
            lo, hi = max(a, wa), min(b, wb)
            if hi > lo:
                out.append((lo, hi))
    return out


def stowed_spans(data: CampaignData, end_s: float) -> list[tuple[float, float]]:
    """From each ``stow`` event to the next ``resume`` (or ``end_s``)."""
    return intervals(data.events, "stow", "resume", end_s)


def gated_spans(data: CampaignData, end_s: float) -> list[tuple[float, float]]:
    """From each ``gated`` event to the next ``ungated`` (or ``end_s``), daytime only when the days are known.

    The runner gates by weather only while the sun is above the low band's lower edge (the night
    is not "gated"), so with the field config the spans are clipped to each day's daylight.
    """
    spans = intervals(data.events, "gated", "ungated", end_s)
    daylight = [d.daylight for d in data.days if d.daylight is not None]
    return clip_spans(spans, daylight) if data.days else spans


def _hours_until(spans, t: np.ndarray) -> np.ndarray:
    total = np.zeros_like(t, dtype=float)
    for a, b in spans:
        total += np.clip(t - a, 0.0, b - a)
    return total / 3600.0


# ---------------------------------------------------------------------------------------- status
def summary(data: CampaignData, visits: pd.DataFrame) -> dict:
    """Counts of the campaign: heliostats, accepted, visits by outcome, observations, events, hours."""
    obs = data.observations
    n_h = len(data.heliostats)
    accepted = sum(1 for h in data.heliostat_ids if (v := data.verdicts.get(h)) is not None and v.accepted)
    end = data.end_s
    stowed = stowed_spans(data, end)
    gated = gated_spans(data, end)
    attempted = visits[visits["n_obs"] > 0] if len(visits) else visits
    invalid = obs[~obs["valid"]] if len(obs) else obs
    return {
        "heliostats": n_h,
        "accepted": accepted,
        "acceptance_rate": num(accepted / n_h) if n_h else None,
        "visits": len(visits),
        "visits_by_outcome": dict(sorted(Counter(visits["outcome"]).items())) if len(visits) else {},
        "valid_visits": int((visits["n_valid"] > 0).sum()) if len(visits) else 0,
        "passed_visits": int(visits["passed"].sum()) if len(visits) else 0,
        "pass_rate": num(attempted["passed"].mean()) if len(attempted) else None,
        "observations": len(obs),
        "valid_observations": int(obs["valid"].sum()) if len(obs) else 0,
        "invalid_by_reason": dict(sorted(Counter(invalid["reason"]).items())) if len(invalid) else {},
        "events_by_kind": dict(sorted(Counter(e.kind for e in data.events).items())),
        "stowed_hours": num(sum(b - a for a, b in stowed) / 3600.0, 3),
        "gated_hours": num(sum(b - a for a, b in gated) / 3600.0, 3),
        "loop_threshold_mrad": loop_threshold_mrad(data),
    }


NO_RESULT_OUTCOMES = ("fault", "invalid", "aborted", "refused", "interrupted")
"""Visit outcomes without a usable result (the other outcomes: ``converged``, ``not_converged``, ``running``)."""



def _listed(ids: list[str], limit: int = 12) -> str:
    shown = ", ".join(ids[:limit])
    return shown + (f" and {len(ids) - limit} more" if len(ids) > limit else "")


def _event_heliostat(ev) -> str | None:
    """The heliostat an event concerns: its own column, else a leading ``H0007:`` in its reason."""
    if ev.heliostat_id:
        return ev.heliostat_id
    m = re.match(r"\s*([^\s:]+):", ev.reason or "")
    return m.group(1) if m else None


def banner(data: CampaignData, summ: dict, visits: pd.DataFrame | None = None) -> dict:
    """What the crew must act on, and what is only information.

    ``level`` is ``'empty'`` (nothing recorded), ``'action'`` (at least one item in ``actions``) or
    ``'ok'`` (nothing to act on). Actions: heliostats not accepted or without a verdict, fault
    events, heliostats that could not be sent back to tracking, a field still stowed at the end, an
    unfinished campaign, an unreadable field config. Information: invalid observations (and
    whether their visits recovered), visits without a usable result, stows, gated hours.
    ``messages`` is ``actions + information``; ``partly_failed`` is ``level == 'action'``.
    """
    if data.campaign is None:
        msg = "This database holds no campaign: nothing was recorded."
        return {"empty": True, "partly_failed": False, "level": "empty", "headline": "Empty database.",
                "actions": [msg], "information": [], "messages": [msg], "not_accepted": [], "no_verdict": [],
                "off_tracking": []}
    actions: list[str] = []
    info: list[str] = []
    empty = summ["visits"] == 0 and summ["observations"] == 0
    if empty:
        actions.append("This campaign recorded no visit and no observation: there is nothing to judge yet.")
    if data.campaign.status == "running":
        actions.append("The campaign is unfinished (status 'running': a process runs it, or was killed in it): the "
                       "figures are those recorded so far.")
    elif data.campaign.status == "stopped":
        info.append("The campaign was stopped before its end time (Ctrl-C or SIGTERM); running it again resumes it.")
    ids = data.heliostat_ids
    not_accepted = [h for h in ids if (v := data.verdicts.get(h)) is not None and not v.accepted]
    no_verdict = [h for h in ids if h not in data.verdicts]
    if not_accepted:
        first = [f"{h} ({data.verdicts[h].reasons[0]})" if data.verdicts[h].reasons else h for h in not_accepted]
        actions.append(f"{len(not_accepted)} of {len(ids)} heliostats not accepted: {_listed(first, 8)}.")
    if no_verdict and not empty:
        actions.append(f"{len(no_verdict)} of {len(ids)} heliostats have no verdict (no valid visit yet): "
                       f"{_listed(no_verdict)}.")
    faults = [ev for ev in data.events if ev.kind == "fault"]
    off = off_tracking(data.events)
    if off:
        actions.append(f"{len(off)} heliostat(s) not confirmed back to tracking when the record ends (the next run "
                       f"sends them back first); check them at the plant: {_listed(off)}.")
    if faults:
        concerned = sorted({h for ev in faults if (h := _event_heliostat(ev)) in set(ids)})
        actions.append(f"{len(faults)} fault event(s) were recorded" + (f" (heliostats {_listed(concerned)})"
                                                                        if concerned else "")
                       + "; see the event log.")
    kinds = [ev.kind for ev in sorted(data.events, key=lambda e: (e.time_s, e.id)) if ev.kind in ("stow", "resume")]
    if kinds and kinds[-1] == "stow":
        actions.append("The field was still stowed for wind when the campaign's record ends.")
    if data.cfg is None:
        actions.append(f"Field map, acceptance bands and thresholds are limited: {data.config_note} "
                       "(give the report the field config with --field).")
    n_obs, n_valid = summ["observations"], summ["valid_observations"]
    if summ["invalid_by_reason"]:
        reasons = ", ".join(f"{n} {k}" for k, n in summ["invalid_by_reason"].items())
        sentence = f"{n_obs - n_valid} of {n_obs} observations were invalid ({reasons})"
        obs = data.observations
        lost = []
        if visits is not None and len(visits) and len(obs):
            bad = set(obs.loc[~obs["valid"] & obs["visit_id"].notna(), "visit_id"].astype(int))
            lost = visits[visits["visit_id"].isin(bad) & (visits["n_valid"] == 0)]
        if len(lost) == 0:
            sentence += ": every visit they occurred in still gave a valid point (the loop measured again)."
        else:
            sentence += f": {len(lost)} of their visits gave no valid point (see below)."
        info.append(sentence)
    failed = {k: n for k, n in summ["visits_by_outcome"].items() if k in NO_RESULT_OUTCOMES}
    if failed:
        info.append("Visits without a usable result: " + ", ".join(f"{n} {k}" for k, n in failed.items())
                    + ".")
    ev = summ["events_by_kind"]
    if ev.get("stow"):
        info.append(f"The field was stowed for wind {ev['stow']} time(s), {summ['stowed_hours']:g} h in all.")
    if summ.get("gated_hours"):
        info.append(f"Calibration was gated by the weather for {summ['gated_hours']:g} daylight hours.")
    level = "empty" if empty else ("action" if actions else "ok")
    if level == "ok":
        accepted = summ["accepted"]
        headline = f"Nothing to act on: {accepted} of {len(ids)} heliostats accepted, no fault recorded."
    elif level == "action":
        headline = f"{len(actions)} thing{'s' if len(actions) != 1 else ''} to act on."
    else:
        headline = "Empty campaign."
    return {"empty": empty, "partly_failed": level == "action", "level": level, "headline": headline,
            "actions": actions, "information": info, "messages": actions + info, "not_accepted": not_accepted,
            "no_verdict": no_verdict, "off_tracking": off}


# ---------------------------------------------------------------------------------------- field map
def present_errors(data: CampaignData) -> dict[str, float]:
    """Each heliostat's latest placement error: its newest valid observation's error [mrad]."""
    obs = data.observations
    if not len(obs):
        return {}
    valid = obs[obs["valid"] & obs["error_mrad"].notna()].sort_values("id")
    last = valid.groupby("heliostat_id")["error_mrad"].last()
    return {str(k): float(v) for k, v in last.items()}


def heliostat_status(data: CampaignData, hid: str) -> str:
    """``'accepted'``, ``'not accepted'`` or ``'no verdict'``."""
    v = data.verdicts.get(hid)
    if v is None:
        return "no verdict"
    return "accepted" if v.accepted else "not accepted"


def field_map(data: CampaignData) -> dict:
    """Positions (east, north) [m], acceptance status, acceptance error and latest placement error of every
    enrolled heliostat."""
    errors = present_errors(data)
    rows = []
    positions = {}
    if data.cfg is not None and data.cfg.heliostats:
        positions = {h.id: h.position_enu_m for h in data.cfg.heliostats}
    for h in data.heliostats:
        p = positions.get(h.heliostat_id)
        rows.append({"id": h.heliostat_id, "target": h.target_id,
                     "east_m": num(p[0], 3) if p else None, "north_m": num(p[1], 3) if p else None,
                     "status": heliostat_status(data, h.heliostat_id),
                     "acceptance_error_mrad": num(v.rms_mrad) if (v := data.verdicts.get(h.heliostat_id)) else None,
                     "present_error_mrad": num(errors.get(h.heliostat_id))})
    towers = None
    if data.cfg is not None:
        towers = {"tower_east_m": num(data.cfg.tower.receiver_aim_enu_m[0], 3),
                  "tower_north_m": num(data.cfg.tower.receiver_aim_enu_m[1], 3)}
    limit = float(data.cfg.acceptance.max_rms_mrad) if data.cfg is not None else DEFAULT_MAX_RMS_MRAD
    return {"available": bool(positions), "note": "" if positions else data.config_note,
            "heliostats": rows, "tower": towers, "acceptance_limit_mrad": limit}


# ---------------------------------------------------------------------------------------- washing
DEFAULT_CLEANLINESS_PREFERRED = 0.7
"""Washing threshold when the campaign's field config cannot be read (the paper's good mirror: > 0.7)."""


def _latest(obs: pd.DataFrame, column: str) -> dict[str, tuple[float, float, int]]:
    """Per heliostat: (value, capture time, row id) of its newest observation with ``column`` recorded."""
    if not len(obs) or column not in obs:
        return {}
    have = obs[obs[column].notna()].sort_values(["capture_time_s", "id"])
    out = {}
    for hid, g in have.groupby("heliostat_id"):
        r = g.iloc[-1]
        out[str(hid)] = (float(r[column]), float(r["capture_time_s"]), int(r["id"]))
    return out


def present_cleanliness(data: CampaignData) -> dict[str, dict]:
    """Each heliostat's present cleanliness: its newest *measured* value (``cleanliness_measured``,
    from the spot's power), else the newest value of the plant's register (``cleanliness``).

    Returns heliostat id → ``{"cleanliness", "source" ("measured"|"plant"), "time_s", "observation_id",
    "plant_cleanliness", "n_measured"}``; heliostats with neither are absent.
    """
    obs = data.observations
    measured = _latest(obs, "cleanliness_measured")
    plant = _latest(obs, "cleanliness")
    counts = (obs[obs["cleanliness_measured"].notna()].groupby("heliostat_id").size().to_dict()
              if len(obs) and "cleanliness_measured" in obs else {})
    out = {}
    for hid in data.heliostat_ids:
        src = measured.get(hid)
        kind = "measured"
        if src is None:
            src, kind = plant.get(hid), "plant"
        if src is None:
            continue
        p = plant.get(hid)
        out[hid] = {"cleanliness": src[0], "source": kind, "time_s": src[1], "observation_id": src[2],
                    "plant_cleanliness": None if p is None else p[0], "n_measured": int(counts.get(hid, 0))}
    return out


def washing(data: CampaignData) -> dict:
    """Mirrors that need washing: present cleanliness (:func:`present_cleanliness`) below
    ``gating.cleanliness_preferred``, dirtiest first (ties by heliostat id)."""
    if data.cfg is not None:
        limit, source = float(data.cfg.gating.cleanliness_preferred), "gating.cleanliness_preferred"
    else:
        limit, source = DEFAULT_CLEANLINESS_PREFERRED, f"default ({data.config_note})"
    present = present_cleanliness(data)
    targets = {h.heliostat_id: h.target_id for h in data.heliostats}
    rows = [{"heliostat": hid, "target": targets.get(hid), "cleanliness": num(p["cleanliness"]),
             "source": p["source"], "time_s": num(p["time_s"], 1), "time_utc": iso(p["time_s"]),
             "plant_cleanliness": num(p["plant_cleanliness"]), "n_measured": p["n_measured"]}
            for hid, p in present.items() if p["cleanliness"] < limit]
    rows.sort(key=lambda r: (r["cleanliness"], r["heliostat"]))
    return {"threshold": limit, "threshold_source": source,
            "definition": "present cleanliness (newest measured from the spot's power, else the plant's register) "
                          "below the threshold",
            "heliostats_with_value": len(present),
            "heliostats_measured": sum(1 for p in present.values() if p["source"] == "measured"),
            "rows": rows}


# ---------------------------------------------------------------------------------------- progress
def progress(data: CampaignData, visits: pd.DataFrame, step_s: float = 3600.0) -> dict:
    """Cumulative accepted heliostats, visits, valid visits, gated and stowed hours on an hourly grid."""
    if data.campaign is None:
        return {"times_s": [], "accepted": [], "visits": [], "valid_visits": [], "gated_hours": [],
                "stowed_hours": [], "stowed_spans_s": [], "gated_spans_s": []}
    t0, t1 = float(data.campaign.started_s), float(max(data.end_s, data.campaign.started_s))
    t = np.append(np.arange(t0, t1, step_s), t1)
    accepted = np.zeros(t.size, dtype=int)
    by_h: dict[str, list] = {}
    for v in data.verdict_history:
        by_h.setdefault(v.heliostat_id, []).append((v.time_s, v.accepted))
    for hist in by_h.values():
        times = np.array([a for a, _ in hist])
        flags = np.array([b for _, b in hist], dtype=bool)
        idx = np.searchsorted(times, t, side="right") - 1  # newest verdict at or before t
        accepted += np.where(idx >= 0, flags[np.maximum(idx, 0)], False)
    started = np.sort(visits["started_s"].to_numpy(float)) if len(visits) else np.zeros(0)
    ok = visits[visits["n_valid"] > 0] if len(visits) else visits
    ok_t = np.sort(ok["ended_s"].fillna(ok["started_s"]).to_numpy(float)) if len(ok) else np.zeros(0)
    stowed = stowed_spans(data, t1)
    gated = gated_spans(data, t1)
    return {
        "times_s": [num(x, 1) for x in t],
        "accepted": accepted.tolist(),
        "visits": np.searchsorted(started, t, side="right").tolist(),
        "valid_visits": np.searchsorted(ok_t, t, side="right").tolist(),
        "gated_hours": [num(x, 3) for x in _hours_until(gated, t)],
        "stowed_hours": [num(x, 3) for x in _hours_until(stowed, t)],
        "stowed_spans_s": [[num(a, 1), num(b, 1)] for a, b in stowed],
        "gated_spans_s": [[num(a, 1), num(b, 1)] for a, b in gated],
    }


# ---------------------------------------------------------------------------------------- pass rate
def _compare(values: pd.Series, op: str, limit: float) -> pd.Series:
    return {"<=": values <= limit, ">=": values >= limit, ">": values > limit}[op]


def _binned(values: np.ndarray, passed: np.ndarray, edges: np.ndarray) -> dict:
    k = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)
    n = np.bincount(k, minlength=len(edges) - 1)
    p = np.bincount(k, weights=passed.astype(float), minlength=len(edges) - 1).astype(int)
    rate = [num(pi / ni) if ni else None for pi, ni in zip(p, n)]
    return {"n": n.tolist(), "passed": p.tolist(), "rate": rate}


def pass_rate_figure(visits: pd.DataFrame, which: str) -> dict:
    """Correction pass rate against one condition (paper figure 6 wind, 7 DNI, 8 cleanliness).

    ``all`` bins every attempted visit with a known value; ``good_other`` only those whose other two
    conditions were good (the paper's figures hold them there). Values outside the edges go to the
    first or last bin.
    """
    spec = BINS[which]
    col = spec["column"]
    attempted = visits[visits["n_obs"] > 0] if len(visits) else visits
    known = attempted[attempted[col].notna()] if len(attempted) else attempted
    good = known
    conds = []
    for other, (c, op, lim) in GOOD.items():
        if other == which or not len(good):
            continue
        good = good[good[c].notna() & _compare(good[c].astype(float), op, lim)]
    for other, (c, op, lim) in GOOD.items():
        if other != which:
            conds.append(f"{c} {op} {lim:g}")
    edges = spec["edges"]

    def series(frame):
        return _binned(frame[col].to_numpy(float), frame["passed"].to_numpy(bool), edges) if len(frame) else \
            {"n": [0] * (len(edges) - 1), "passed": [0] * (len(edges) - 1), "rate": [None] * (len(edges) - 1)}

    return {"condition": which, "column": col, "label": spec["label"], "unit": spec["unit"],
            "edges": [num(e) for e in edges], "n_unknown": int(len(attempted) - len(known)),
            "all": series(known), "good_other": {**series(good), "condition": " and ".join(conds)},
            "paper_rate": PAPER_PASS_RATE}


def pass_rates(data: CampaignData, visits: pd.DataFrame) -> dict:
    return {"threshold_mrad": loop_threshold_mrad(data),
            "definition": "share of visits whose loop converged: a valid observation below the loop threshold",
            **{k: pass_rate_figure(visits, k) for k in BINS}}


ROUTINE_EVENTS = ("tracking_written",)
"""Event kinds counted in the summary but left out of the event log (one per visit)."""


def events_log(data: CampaignData, limit: int = 500) -> dict:
    """The campaign's events but the routine ones, newest ``limit``, for the report's event log."""
    shown = [ev for ev in data.events if ev.kind not in ROUTINE_EVENTS]
    rows = [{"time_utc": iso(ev.time_s), "time_s": num(ev.time_s, 1), "kind": ev.kind, "heliostat": ev.heliostat_id,
             "reason": ev.reason} for ev in shown[-limit:]]
    return {"rows": rows, "omitted_routine": len(data.events) - len(shown), "omitted_old": max(0, len(shown) - limit)}
