"""Observation ↔ flat database row (and CSV) columns.

The flat columns are also the CSV export's header, so a script can read an export without
helicalib: one column per vector component, units in every name.
"""

from __future__ import annotations

import json
import math
import sqlite3
from pathlib import Path
from typing import Any

from helicalib.store.damage import loads
from helicalib.store.records import Observation

OBSERVATION_COLUMNS: tuple[str, ...] = (
    "id", "campaign_id", "heliostat_id", "target_id", "visit_id", "iteration", "capture_time_s",
    "stroke_cmd_1_mm", "stroke_cmd_2_mm", "stroke_read_1_mm", "stroke_read_2_mm", "approach_1", "approach_2",
    "sun_e", "sun_n", "sun_u", "sun_azimuth_deg", "sun_elevation_deg", "sun_rising",
    "wind_ms", "wind_direction_deg", "dni_wm2", "temperature_c", "cleanliness", "cleanliness_measured",
    "exposure_ms", "valid", "reason", "message", "offset_u_m", "offset_v_m",
    "spot_x_px", "spot_y_px", "spot_area_px", "threshold", "jitter_px",
    "spot_e_m", "spot_n_m", "spot_u_m", "error_mrad",
    "before_frame_path", "after_frame_paths_json",
)
"""Flat observation columns, in table and CSV order."""


def _f(value: Any) -> float | None:
    if value is None:
        return None
    x = float(value)
    return None if math.isnan(x) else x


def observation_to_row(obs: Observation, before_path: str | None, after_paths: tuple[str, ...]) -> dict[str, Any]:
    """The row to insert for ``obs`` (without ``id``), with the given frame paths."""
    read = obs.strokes_read_mm
    spot = obs.spot_enu_m
    return {
        "campaign_id": int(obs.campaign_id),
        "heliostat_id": str(obs.heliostat_id),
        "target_id": str(obs.target_id),
        "visit_id": None if obs.visit_id is None else int(obs.visit_id),
        "iteration": int(obs.iteration),
        "capture_time_s": float(obs.capture_time_s),
        "stroke_cmd_1_mm": _f(obs.strokes_cmd_mm[0]),
        "stroke_cmd_2_mm": _f(obs.strokes_cmd_mm[1]),
        "stroke_read_1_mm": None if read is None else _f(read[0]),
        "stroke_read_2_mm": None if read is None else _f(read[1]),
        "approach_1": None if obs.approach is None else int(obs.approach[0]),
        "approach_2": None if obs.approach is None else int(obs.approach[1]),
        "sun_e": float(obs.sun_enu[0]),
        "sun_n": float(obs.sun_enu[1]),
        "sun_u": float(obs.sun_enu[2]),
        "sun_azimuth_deg": float(obs.sun_azimuth_deg),
        "sun_elevation_deg": float(obs.sun_elevation_deg),
        "sun_rising": None if obs.sun_rising is None else int(bool(obs.sun_rising)),
        "wind_ms": _f(obs.wind_ms),
        "wind_direction_deg": _f(obs.wind_direction_deg),
        "dni_wm2": _f(obs.dni_wm2),
        "temperature_c": _f(obs.temperature_c),
        "cleanliness": _f(obs.cleanliness),
        "cleanliness_measured": _f(obs.cleanliness_measured),
        "exposure_ms": _f(obs.exposure_ms),
        "valid": int(bool(obs.valid)),
        "reason": str(obs.reason),
        "message": str(obs.message),
        "offset_u_m": _f(obs.offset_u_m),
        "offset_v_m": _f(obs.offset_v_m),
        "spot_x_px": _f(obs.spot_x_px),
        "spot_y_px": _f(obs.spot_y_px),
        "spot_area_px": _f(obs.spot_area_px),
        "threshold": _f(obs.threshold),
        "jitter_px": _f(obs.jitter_px),
        "spot_e_m": None if spot is None else _f(spot[0]),
        "spot_n_m": None if spot is None else _f(spot[1]),
        "spot_u_m": None if spot is None else _f(spot[2]),
        "error_mrad": _f(obs.error_mrad),
        "before_frame_path": before_path,
        "after_frame_paths_json": json.dumps(list(after_paths)),
    }


def observation_from_row(r: sqlite3.Row, db: str | Path = "database") -> Observation:
    """An :class:`Observation` (with ``id`` and frame paths) from a database row of ``db`` (its
    values checked by the store's reader; a frame path list that is not JSON is named here)."""
    read = None if r["stroke_read_1_mm"] is None else (r["stroke_read_1_mm"], r["stroke_read_2_mm"])
    spot = None if r["spot_e_m"] is None else (r["spot_e_m"], r["spot_n_m"], r["spot_u_m"])
    return Observation(
        id=r["id"], campaign_id=r["campaign_id"], heliostat_id=r["heliostat_id"], target_id=r["target_id"],
        visit_id=r["visit_id"], iteration=r["iteration"], capture_time_s=r["capture_time_s"],
        strokes_cmd_mm=tuple(float("nan") if x is None else x for x in (r["stroke_cmd_1_mm"], r["stroke_cmd_2_mm"])),
        strokes_read_mm=read,
        approach=None if r["approach_1"] is None else (int(r["approach_1"]), int(r["approach_2"])),
        sun_enu=(r["sun_e"], r["sun_n"], r["sun_u"]), sun_azimuth_deg=r["sun_azimuth_deg"],
        sun_elevation_deg=r["sun_elevation_deg"],
        sun_rising=None if r["sun_rising"] is None else bool(r["sun_rising"]),
        wind_ms=r["wind_ms"], wind_direction_deg=r["wind_direction_deg"], dni_wm2=r["dni_wm2"],
        temperature_c=r["temperature_c"], cleanliness=r["cleanliness"],
        cleanliness_measured=r["cleanliness_measured"],
        exposure_ms=r["exposure_ms"],
        valid=bool(r["valid"]), reason=r["reason"], message=r["message"],
        offset_u_m=r["offset_u_m"], offset_v_m=r["offset_v_m"], spot_x_px=r["spot_x_px"], spot_y_px=r["spot_y_px"],
        spot_area_px=r["spot_area_px"], threshold=r["threshold"], jitter_px=r["jitter_px"], spot_enu_m=spot,
        error_mrad=r["error_mrad"], before_frame_path=r["before_frame_path"],
        after_frame_paths=tuple(loads(db, "observations", r, "after_frame_paths_json")),
    )
