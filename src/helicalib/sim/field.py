"""``sim-field``: generate a field config (radial-staggered layout) whose strokes are feasible all year.

Heliostats stand in staggered rings on the pole side of the tower (north for a northern site,
south for a southern one) within ±75° of it. Ring spacing and in-ring spacing follow the mirror
diagonal; a new zone with a denser ring starts each time the in-ring gap doubles. Every candidate
is checked with :meth:`HeliostatModel.strokes_for_aim` for its calibration target AND the receiver
over a year of sun positions ≥ 5°; candidates whose strokes leave the range are dropped and more
rings are laid until ``n`` heliostats remain.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from helicalib.config import write_field_config
from helicalib.geometry.drives import DriveArrays
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.sim.evaluate import year_sun_times

DRIVE_NAME = "tr20"
MIRROR_M = (4.5, 4.5)
BOARD_M = 12.0
STROKE_MARGIN_MM = 25.0
"""Room left at both ends of each stroke range for corrections and between the sampled sun positions."""


def _drive(south_field: bool) -> dict:
    """The demo's tilt-roll drive; a south field tilts the other way (actuator 1 sign −1)."""
    return {
        "kind": "tilt-roll", "mirror_offset_m": 0.25, "mirror_size_m": list(MIRROR_M),
        "actuators": [
            {"arm_fixed_m": 1.6, "arm_moving_m": 1.1, "gamma0_deg": 60, "sign": -1 if south_field else 1,
             "length_at_zero_stroke_m": 0.80, "stroke_range_mm": [0, 1850]},
            {"arm_fixed_m": 1.2, "arm_moving_m": 0.9, "gamma0_deg": 90, "sign": 1,
             "length_at_zero_stroke_m": 0.50, "stroke_range_mm": [0, 1590]},
        ],
    }


def radial_staggered(count: int, r0_m: float, spacing_m: float, half_width_deg: float = 75.0,
                     pole_azimuth_deg: float = 0.0) -> np.ndarray:
    """At least ``count`` positions (k, 2) east/north [m] in staggered rings from radius ``r0_m``."""
    out: list[np.ndarray] = []
    r = r0_m
    dr = 0.866 * spacing_m
    zone_r = r0_m
    ring = 0
    total = 0
    while total < count:
        daz = spacing_m / zone_r                       # angular gap fixed within a zone
        if r * daz > 2.0 * spacing_m:                  # gap doubled: new, denser zone
            zone_r = r
            daz = spacing_m / zone_r
        half = math.radians(half_width_deg)
        k = int(half // daz)
        az = (np.arange(-k, k + 1) + (0.5 if ring % 2 else 0.0)) * daz
        az = az[np.abs(az) <= half] + math.radians(pole_azimuth_deg)
        pts = np.stack([r * np.sin(az), r * np.cos(az)], axis=1)
        out.append(pts)
        total += len(pts)
        r += dr
        ring += 1
    return np.concatenate(out)


def feasible_all_year(model: HeliostatModel, aims: list[np.ndarray], sun_enu: np.ndarray,
                      margin_mm: float = STROKE_MARGIN_MM, progress=None) -> np.ndarray:
    """(N,) bool: strokes at least ``margin_mm`` inside the range for every aim (N, 3) and sun (T, 3).

    ``progress(done, total)``, if given, is called after each (aim, sun position) check, with
    ``total = len(aims) · T``.
    """
    ok = np.ones(len(model), dtype=bool)
    lo = model.drives.stroke_min_mm + margin_mm
    hi = model.drives.stroke_max_mm - margin_mm
    total = len(aims) * len(sun_enu)
    done = 0
    for aim in aims:
        for s in sun_enu:
            st = model.strokes_for_aim(s, aim).strokes_mm
            with np.errstate(invalid="ignore"):
                ok &= np.all((st >= lo) & (st <= hi), axis=-1)
            done += 1
            if progress is not None:
                progress(done, total)
    return ok


def generate_field(n: int, latitude_deg: float, longitude_deg: float, altitude_m: float = 0.0,
                   targets: int = 4, name: str | None = None, step_days: float = 7.0,
                   step_min: float = 30.0, progress=None) -> tuple[dict, list[dict]]:
    """Field config mapping (without ``heliostats_csv``) and heliostat rows of a feasible field.

    ``progress(done, total, candidates)``, if given, is called as the year's feasibility checks go:
    ``done`` of ``total`` checks (one per aim and sun position, for all candidates at once) over every
    round so far, ``candidates`` the positions checked in this round. ``done`` only grows; a round of
    extra candidates (when too few were feasible) adds its checks to ``total``.
    """
    south = latitude_deg < 0
    pole = 180.0 if south else 0.0
    sgn = -1.0 if south else 1.0
    tower_h = float(np.clip(40.0 + 2.5 * math.sqrt(n), 60.0, 250.0))
    board_h = round(0.6 * tower_h, 1)
    spacing = 1.35 * math.hypot(*MIRROR_M)
    r0 = max(0.6 * tower_h, 40.0)
    target_list = []
    for k in range(targets):
        x = (k - (targets - 1) / 2) * (BOARD_M + 4.0)
        target_list.append({
            "id": f"T{k + 1}", "center_enu_m": [round(x, 2), sgn * 8.0, board_h], "normal_enu": [0.0, sgn, 0.0],
            "size_m": [BOARD_M, BOARD_M], "standby_offset_m": [0.0, BOARD_M + 3.0],  # above the board: clear of its neighbours
            "marks": {"vertices_m": [[-5.5, 5.5], [5.5, 5.5], [5.5, -5.5], [-5.5, -5.5]], "arm_m": 1.4,
                      "thickness_m": 0.35},
        })
    site = {"name": name or f"Simulated field ({n} heliostats)", "latitude_deg": latitude_deg,
            "longitude_deg": longitude_deg, "altitude_m": altitude_m}
    drive = _drive(south)
    data = {
        "site": site, "tower": {"receiver_aim_enu_m": [0.0, 0.0, round(tower_h, 1)]},
        "targets": target_list,
        "cameras": [{"id": f"C{k + 1}", "target": t["id"], "url": f"http://127.0.0.1:8081/{t['id']}.png",
                     "position_enu_m": [t["center_enu_m"][0], sgn * (r0 * 0.8), 2.0], "resolution_px": [1280, 1024]}
                    for k, t in enumerate(target_list)],
        "drives": {DRIVE_NAME: drive},
        "plant": {"scs": {"host": "127.0.0.1", "port": 5020, "unit": 1, "timeout_s": 2.0}, "clock": "plant"},
        "calibration": {"loop_threshold_mrad": 3.5, "max_iterations": 5},
        "gating": {"wind_max_ms": 10.0, "wind_preferred_ms": 5.0, "stow_wind_ms": 15.0, "dni_min_wm2": 300,
                   "dni_preferred_wm2": 800, "cleanliness_min": 0.55, "cleanliness_preferred": 0.7},
        "acceptance": {"low_band_deg": [5, 15], "high_elevation_deg": 15, "high_window_h": 2, "min_points": 5,
                       "max_rms_mrad": 1.2},
        "tracking_test": {"threshold_mrad": 3.5, "wind_bins": [{"wind_ms": 4, "min_fraction": 0.99},
                                                               {"wind_ms": 8, "min_fraction": 0.62},
                                                               {"wind_ms": 11, "min_fraction": 0.33}],
                          "bin_half_width_ms": 1.0},
        "storage": {"database": "sqlite:///helicalib.db", "images_dir": "images"},
    }
    from helicalib.config import Site

    _, sun = year_sun_times(Site(**site), 2026, step_days=step_days, step_min=step_min, min_elevation_deg=5.0)
    from helicalib.config import Drive

    drive_obj = Drive(**drive)
    rows: list[dict] = []
    want = int(n)
    extra = 1.15
    checked = 0                                         # checks of the rounds before this one
    while len(rows) < want:
        pts = radial_staggered(int(want * extra) + 10, r0, spacing, pole_azimuth_deg=pole)
        pivots = np.column_stack([pts, np.full(len(pts), 4.3)])
        drives = DriveArrays.from_drives([drive_obj] * len(pts))
        model = HeliostatModel([f"c{i}" for i in range(len(pts))], pivots, drives)
        # each candidate uses the target nearest its azimuth sector
        frac = (np.degrees(np.arctan2(pts[:, 0], sgn * pts[:, 1])) + 75.0) / 150.0
        tk = np.clip((frac * targets).astype(int), 0, targets - 1)
        aim_t = np.array([target_list[k]["center_enu_m"] for k in tk], dtype=float)
        aim_r = np.broadcast_to(data["tower"]["receiver_aim_enu_m"], (len(pts), 3))
        step = None
        if progress is not None:
            def step(done, total, before=checked, k=len(pts)):
                progress(before + done, before + total, k)
        ok = feasible_all_year(model, [aim_t, np.asarray(aim_r, float)], sun, progress=step)
        checked += 2 * len(sun)
        good = np.flatnonzero(ok)
        if len(good) >= want:
            good = good[:want]
            rows = [{"id": f"H{j + 1:05d}", "e_m": round(float(pts[g, 0]), 2), "n_m": round(float(pts[g, 1]), 2),
                     "u_m": 4.3, "drive": DRIVE_NAME, "target": target_list[tk[g]]["id"]}
                    for j, g in enumerate(good)]
        else:
            extra *= 1.5 * want / max(len(good), 1)
            if extra > 50:
                raise RuntimeError(f"only {len(good)} of {want} candidate positions are feasible all year")
    return data, rows


def write_field(data: dict, rows: list[dict], out_path: str | Path):
    """Write ``FIELD.yaml`` + ``FIELD.csv`` beside it; returns the loaded (validated) config."""
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    csv_path = out.with_suffix(".csv")
    with csv_path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["id", "e_m", "n_m", "u_m", "drive", "target"])
        w.writeheader()
        w.writerows(rows)
    return write_field_config({**data, "heliostats_csv": csv_path.name}, out)
