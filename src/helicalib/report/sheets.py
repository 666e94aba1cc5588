"""The per-heliostat figures of the report (pure): observations, corrections, fit, verdict.

:func:`acceptance_spans` turns the campaign's solar days into the spans the sheets shade (the
rising and setting 5–15° bands and the high-elevation windows of paper 2.4); :func:`heliostat_sheet`
gathers one heliostat's numbers. Both return plain dictionaries that go into ``report.json``.
"""

from __future__ import annotations

import pandas as pd

from helicalib.report.data import CampaignData
from helicalib.report.figures import DEFAULT_CLEANLINESS_PREFERRED, heliostat_status, iso, num


def acceptance_spans(data: CampaignData) -> dict:
    """The acceptance rules and, per solar day, the band and window spans [UTC s] (empty without a config)."""
    if data.cfg is None:
        return {"available": False, "note": data.config_note, "days": []}
    from helicalib.calibration.acceptance import evaluation_day
    from helicalib.calibration.sun_days import n_high_windows

    acc = data.cfg.acceptance
    ref = evaluation_day(data.days, data.end_s)
    n_win = n_high_windows(ref.high_span_s, acc.high_window_h) if ref is not None else 0
    days = []
    for d in data.days:
        windows = [d.high_window(k, n_win) for k in range(n_win)] if d.high_start_s is not None else []
        days.append({"noon_s": num(d.noon_s, 1), "noon_elevation_deg": num(d.noon_elevation_deg, 3),
                     "rising_band_s": [num(d.rise_band_start_s, 1), num(d.rise_band_end_s, 1)],
                     "setting_band_s": [num(d.set_band_start_s, 1), num(d.set_band_end_s, 1)],
                     "high_windows_s": [[num(a, 1), num(b, 1)] for a, b in windows if a is not None]})
    return {"available": True, "low_band_deg": list(acc.low_band_deg), "high_elevation_deg": acc.high_elevation_deg,
            "high_window_h": acc.high_window_h, "min_points": acc.min_points, "max_rms_mrad": acc.max_rms_mrad,
            "n_windows": n_win, "days": days}


def fit_table(fit) -> dict | None:
    """A fit's named parameters with their 1-sigma and units (``geometry.error_model.PARAMETERS``)."""
    if fit is None:
        return None
    from helicalib.geometry.error_model import PARAMETERS

    units = {p.name: (p.unit, p.description) for p in PARAMETERS}
    names = list(fit.params)
    ordered = [p.name for p in PARAMETERS if p.name in fit.params] + [n for n in names if n not in units]
    rows = [{"name": n, "value": num(fit.params.get(n), 6), "sigma": num(fit.sigma.get(n), 6),
             "unit": units.get(n, ("", ""))[0], "description": units.get(n, ("", ""))[1]} for n in ordered]
    return {"model": fit.model, "time_utc": iso(fit.time_s), "n_points": fit.n_points,
            "rms_mrad": num(fit.rms_mrad), "parameters": rows}


def corrections(obs: pd.DataFrame, visits_by_id: dict) -> list[dict]:
    """Per visit: the valid errors in loop order (first placement, then after each correction)."""
    out = []
    if not len(obs):
        return out
    o = obs[obs["visit_id"].notna()].sort_values("id")
    vid = o["visit_id"].to_numpy(dtype=float).astype(int)
    ok = (o["valid"].to_numpy(dtype=bool) & o["error_mrad"].notna().to_numpy())
    it = o["iteration"].to_numpy(dtype=int)
    err = o["error_mrad"].to_numpy(dtype=float)
    reason = o["reason"].to_numpy(dtype=object)
    for v_id in sorted(set(vid.tolist())):
        sel = vid == v_id
        good = sel & ok
        v = visits_by_id.get(v_id)
        out.append({"visit_id": v_id, "started_utc": iso(v.started_s) if v else None,
                    "outcome": v.outcome if v else None, "reason": v.reason if v else None,
                    "iterations": it[good].tolist(), "errors_mrad": [num(x) for x in err[good]],
                    "invalid_reasons": [str(r) for r in reason[sel & ~ok]]})
    return out


def observation_rows(obs: pd.DataFrame) -> list[dict]:
    """Every observation of a heliostat, valid or not, with its reason (the sheet's table and plots)."""
    cols = {"id": 0, "visit_id": 0, "iteration": 0, "capture_time_s": 1, "sun_elevation_deg": 3,
            "sun_azimuth_deg": 3, "sun_rising": None, "wind_ms": 2, "dni_wm2": 1, "cleanliness": 3,
            "cleanliness_measured": 4,
            "valid": None, "reason": None, "error_mrad": 4, "offset_u_m": 4, "offset_v_m": 4}
    rows = []
    o = obs.sort_values("id")
    columns = {c: o[c].tolist() for c in cols}  # column lists: itertuples is slow on a heliostat's group
    for i, t in enumerate(columns["capture_time_s"]):
        d = {}
        for c, nd in cols.items():
            x = columns[c][i]
            if nd is None:
                d[c] = None if x is None or (isinstance(x, float) and x != x) else (bool(x) if c != "reason" else str(x))
            elif nd == 0:
                d[c] = None if x is None or x != x else int(x)
            else:
                d[c] = num(x, nd)
        d["time_utc"] = iso(t)
        rows.append(d)
    return rows


def latest_frame_observation(obs: pd.DataFrame) -> dict | None:
    """The newest observation of the newest visit that saved a before and an after frame."""
    if not len(obs):
        return None
    import json

    have = obs[obs["before_frame_path"].notna() & (obs["after_frame_paths_json"] != "[]")]
    if not len(have):
        return None
    r = have.sort_values("id").iloc[-1]
    return {"id": int(r["id"]), "visit_id": None if pd.isna(r["visit_id"]) else int(r["visit_id"]),
            "iteration": int(r["iteration"]), "time_utc": iso(r["capture_time_s"]), "target_id": r["target_id"],
            "before": r["before_frame_path"], "after": json.loads(r["after_frame_paths_json"]),
            "valid": bool(r["valid"]), "reason": r["reason"], "message": _clause(r["message"]),
            "spot_px": None if pd.isna(r["spot_x_px"]) else [float(r["spot_x_px"]), float(r["spot_y_px"])],
            "error_mrad": num(r["error_mrad"])}


def _clause(message):
    """A stored message as a clause the page ends with its own full stop (the vision's messages
    are sentences that end with one already)."""
    return message.rstrip().rstrip(".") if isinstance(message, str) else message


def cleanliness_history(obs: pd.DataFrame, limit: float | None) -> dict:
    """The heliostat's measured cleanliness over time (oldest first), its present value and whether
    it is below the washing threshold ``limit`` (``gating.cleanliness_preferred``)."""
    rows = []
    if len(obs) and "cleanliness_measured" in obs:
        have = obs[obs["cleanliness_measured"].notna()].sort_values(["capture_time_s", "id"])
        for i, vid, t, c, plant in zip(*(have[k].tolist() for k in ("id", "visit_id", "capture_time_s",
                                                                    "cleanliness_measured", "cleanliness"))):
            rows.append({"id": int(i), "visit_id": None if pd.isna(vid) else int(vid),
                         "time_s": num(t, 1), "time_utc": iso(t),
                         "cleanliness_measured": num(c), "plant_cleanliness": num(plant)})
    plant = obs[obs["cleanliness"].notna()].sort_values(["capture_time_s", "id"]) if len(obs) else obs
    present, source = None, None
    if rows:
        present, source = rows[-1]["cleanliness_measured"], "measured"
    elif len(plant):
        present, source = num(plant["cleanliness"].iloc[-1]), "plant"
    return {"measured": rows, "present": present, "source": source, "threshold": limit,
            "needs_washing": None if present is None or limit is None else bool(present < limit)}


def coverage_complete(reasons) -> bool:
    """Whether a verdict found the bands and windows covered (its only reasons, if any, are about the RMS).

    The campaign judges the acceptance error out of sample (leave-one-visit-out) only then; before,
    its RMS is over the points' stored placement errors (``campaign.verdict``)."""
    return all(str(r).startswith("RMS") for r in reasons)


def verdict_history(verdicts) -> list[dict]:
    """A heliostat's verdicts, oldest first: time, accepted, acceptance error and whether it was provisional."""
    return [{"time_s": num(v.time_s, 1), "time_utc": iso(v.time_s), "accepted": v.accepted, "n_points": v.n_points,
             "rms_mrad": num(v.rms_mrad), "coverage_complete": coverage_complete(v.reasons)} for v in verdicts]


def heliostat_sheet(data: CampaignData, hid: str, target_id: str, obs: pd.DataFrame, present_error: float | None,
                    tracking: dict | None, visits_by_id: dict, history=()) -> dict:
    """One heliostat's sheet: status, verdict with reasons, fit, corrections, observations, frames.

    ``history``: the heliostat's verdicts, oldest first (its acceptance error over the campaign)."""
    v = data.verdicts.get(hid)
    valid = obs[obs["valid"] & obs["error_mrad"].notna()] if len(obs) else obs
    n_visits = sum(1 for x in visits_by_id.values() if x.heliostat_id == hid)  # visits_by_id: this heliostat's
    return {
        "id": hid, "target": target_id, "status": heliostat_status(data, hid),
        "verdict": None if v is None else {"accepted": v.accepted, "time_utc": iso(v.time_s), "n_points": v.n_points,
                                           "rms_mrad": num(v.rms_mrad), "reasons": list(v.reasons),
                                           "details": v.details, "coverage_complete": coverage_complete(v.reasons)},
        "verdict_history": verdict_history(history),
        "visits": n_visits, "observations": int(len(obs)), "valid_observations": int(len(valid)),
        "present_error_mrad": num(present_error),
        "valid_rms_mrad": num(float((valid["error_mrad"] ** 2).mean() ** 0.5)) if len(valid) else None,
        "tracking_test": tracking,
        "fit": fit_table(data.fits.get(hid)),
        "corrections": corrections(obs, visits_by_id),
        "latest_frames": latest_frame_observation(obs),
        "cleanliness": cleanliness_history(obs, float(data.cfg.gating.cleanliness_preferred)
                                          if data.cfg is not None else DEFAULT_CLEANLINESS_PREFERRED),
        "observation_rows": observation_rows(obs),
    }
