"""The field overview of the report (pure): one compact row per heliostat, per-board and per-band views.

A 10⁴-heliostat field cannot be read as 10⁴ HTML rows or figures. The campaign page carries these
rows once, as JSON, and draws from them a field map (one canvas: every heliostat, coloured by
verdict or by error, a click opens its sheet) and a table with a search box, sorting, paging and
board/status filters. :func:`band_coverage` counts each heliostat's valid points in the rising and
setting 5–15° bands (paper rule 1) and above 15°; :func:`board_views` and :func:`band_view` sum the
rows by board and by band.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from helicalib.report.data import CampaignData

ROW_KEYS = ("id", "href", "board", "status", "visits", "valid_observations", "observations", "acceptance_error_mrad",
            "provisional", "present_error_mrad", "rising_points", "setting_points", "high_points", "reasons",
            "east_m", "north_m")
"""The overview row's fields, in the order the page's table script reads them (``report.json``'s
``overview.columns``)."""
_K = {name: i for i, name in enumerate(ROW_KEYS)}
"""Each field's index in an overview row."""


def _limits(data: CampaignData) -> tuple[float, float, float]:
    """The low band (paper: 5–15°) and the high-elevation limit of the campaign's field config."""
    if data.cfg is None:
        return 5.0, 15.0, 15.0
    lo, hi = map(float, data.cfg.acceptance.low_band_deg)
    return lo, hi, float(data.cfg.acceptance.high_elevation_deg)


def band_coverage(data: CampaignData) -> dict[str, tuple[int, int, int]]:
    """Per heliostat: valid points (an error recorded) in the rising and in the setting low band
    (the field config's ``acceptance.low_band_deg``, paper: 5–15°) and above ``high_elevation_deg``."""
    obs = data.observations
    if not len(obs):
        return {}
    lo, hi, high = _limits(data)
    ok = obs["valid"].to_numpy(dtype=bool) & obs["error_mrad"].notna().to_numpy()
    el = obs["sun_elevation_deg"].to_numpy(dtype=float)
    rising = obs["sun_rising"].to_numpy(dtype=float)  # 1 rising, 0 setting, NaN unknown
    band = ok & (el >= lo) & (el <= hi)
    frame = pd.DataFrame({"h": obs["heliostat_id"].astype(str).to_numpy(), "r": band & (rising == 1.0),
                          "s": band & (rising == 0.0), "u": ok & (el > high)})
    g = frame.groupby("h", sort=False)[["r", "s", "u"]].sum()
    return {str(h): (int(r), int(s), int(u)) for h, r, s, u in g.itertuples()}


def overview_rows(data: CampaignData, rep: dict, sheets: list[dict]) -> list[list]:
    """One list per heliostat, fields :data:`ROW_KEYS`, from the sheet summaries and the field map."""
    cover = band_coverage(data)
    where = {r["id"]: (r["east_m"], r["north_m"]) for r in rep["field_map"]["heliostats"]}
    rows = []
    for h in sheets:
        vd = h.get("verdict")
        east, north = where.get(h["id"], (None, None))
        r, s, u = cover.get(h["id"], (0, 0, 0))
        rows.append([h["id"], h["href"], h.get("target"), h["status"], h["visits"], h["valid_observations"],
                     h["observations"], vd["rms_mrad"] if vd else None,
                     bool(vd and not vd["coverage_complete"]), h["present_error_mrad"], r, s, u,
                     "; ".join(vd["reasons"]) if vd else "", east, north])
    return rows


def _median(values) -> float | None:
    x = np.array([v for v in values if v is not None], dtype=float)
    return None if not len(x) else round(float(np.median(x)), 4)


def board_views(rows: list[list]) -> list[dict]:
    """Per board: heliostats, accepted / not accepted / no verdict, band coverage and the median errors."""
    k = _K
    boards: dict[str, list[list]] = {}
    for r in rows:
        boards.setdefault(str(r[k["board"]]), []).append(r)
    out = []
    for board in sorted(boards):
        rs = boards[board]
        out.append({"board": board, "heliostats": len(rs),
                    "accepted": sum(r[k["status"]] == "accepted" for r in rs),
                    "not_accepted": sum(r[k["status"]] == "not accepted" for r in rs),
                    "no_verdict": sum(r[k["status"]] == "no verdict" for r in rs),
                    **_band_counts(rs, k),
                    "median_acceptance_error_mrad": _median(r[k["acceptance_error_mrad"]] for r in rs),
                    "median_present_error_mrad": _median(r[k["present_error_mrad"]] for r in rs)})
    return out


def _band_counts(rs: list[list], k: dict) -> dict:
    rising = [r[k["rising_points"]] > 0 for r in rs]
    setting = [r[k["setting_points"]] > 0 for r in rs]
    return {"rising_covered": sum(rising), "setting_covered": sum(setting),
            "both_bands": sum(a and b for a, b in zip(rising, setting)),
            "no_band": sum(not a and not b for a, b in zip(rising, setting)),
            "with_high_points": sum(r[k["high_points"]] > 0 for r in rs)}


def band_view(data: CampaignData, rows: list[list]) -> dict:
    """The field's band coverage: heliostats with a valid point in the rising band, the setting band,
    both, neither, and with points above the high-elevation limit; the limits used."""
    k = _K
    lo, hi, high = _limits(data)
    return {"low_band_deg": [lo, hi], "high_elevation_deg": high, "heliostats": len(rows), **_band_counts(rows, k)}


def overview(data: CampaignData, rep: dict, sheets: list[dict]) -> dict:
    """``report.json``'s ``overview``: the columns, one row per heliostat, the board and band views."""
    rows = overview_rows(data, rep, sheets)
    return {"columns": list(ROW_KEYS), "rows": rows, "boards": board_views(rows), "bands": band_view(data, rows)}
