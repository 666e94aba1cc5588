"""The inverse model of Wu et al. 2022, section 2.2: observed spot → observed normal → stroke correction.

A heliostat held strokes ``s``; at the capture time (sun ``s_c``) its spot was seen at X on a
target. The beam left the mirror centre M = P + offset·n toward X, so the observed normal is the
fixed point ``n_obs = unit(s_c + unit(X − M(n_obs)))`` (same as aiming at X). The model's normal
for the held strokes is ``n_cmd``; their angle is the normal error.

The error is carried to the next aim (sun ``s_n``, aim point T) in push-rod stroke space, as the
paper corrects the main and secondary push rods: the strokes the model would need to produce
``n_obs`` differ from the held ones by Δ; the new command is the model's strokes for T at ``s_n``
minus Δ. This is exact when the heliostat's error is a stroke offset (at any sun position) and first
order otherwise; the closed loop repeats it until the tracking error is below the threshold.
``mode="angle"`` carries Δ in axis-angle space instead, ``mode="rotation"`` as the smallest ENU
rotation from ``n_cmd`` to ``n_obs``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helicalib.geometry import optics
from helicalib.geometry.drives import angles_to_strokes, rotate, strokes_in_range


@dataclass(frozen=True)
class Correction:
    """Result of :func:`stroke_correction` for N heliostats.

    Attributes
    ----------
    strokes_mm : (N, 2) new commanded strokes [mm] (NaN where no solution)
    delta_mm : (N, 2) new minus held strokes [mm]
    normal_error_mrad : (N,) angle between the observed and the model's normal [mrad]
    in_range : (N,) bool, new strokes finite and inside the stroke ranges
    observed_normal_enu : (N, 3)
    model_normal_enu : (N, 3) the model's normal for the held strokes
    stroke_error_mm : (N, 2) Δ: strokes the model needs for the observed normal minus the held ones [mm]
    """

    strokes_mm: np.ndarray
    delta_mm: np.ndarray
    normal_error_mrad: np.ndarray
    in_range: np.ndarray
    observed_normal_enu: np.ndarray
    model_normal_enu: np.ndarray
    stroke_error_mm: np.ndarray


def observed_normal(pivot_enu: np.ndarray, sun_enu: np.ndarray, spot_enu: np.ndarray, mirror_offset_m) -> np.ndarray:
    """Mirror normal (..., 3) that sends the sun's ray from the mirror centre to the observed spot.

    Parameters
    ----------
    pivot_enu : (..., 3) [m]
    sun_enu : (..., 3) unit sun vector at the capture time
    spot_enu : (..., 3) observed spot centre [m, ENU]
    mirror_offset_m : (...) [m]
    """
    return optics.aim_normal(pivot_enu, sun_enu, spot_enu, mirror_offset_m)


def _rows(v, n: int) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return np.broadcast_to(a, (n, 3)) if a.ndim == 1 else a


def stroke_correction(model, strokes_mm: np.ndarray, sun_at_capture_enu: np.ndarray, spot_enu: np.ndarray,
                      aim_enu: np.ndarray, sun_at_next_enu: np.ndarray, mode: str = "stroke") -> Correction:
    """Stroke corrections (main, secondary push rod) that put the beam on ``aim_enu`` at the next time.

    Parameters
    ----------
    model : HeliostatModel of N heliostats (its error parameters are used as they are)
    strokes_mm : (N, 2) strokes held at the capture [mm]
    sun_at_capture_enu : (3,) or (N, 3) unit sun vector when the spot was captured
    spot_enu : (N, 3) observed spot centres [m, ENU] (on whatever target plane)
    aim_enu : (3,) or (N, 3) desired aim points [m]
    sun_at_next_enu : (3,) or (N, 3) unit sun vector at the time the new strokes will be held
    mode : "stroke" (default; the paper's push-rod correction), "angle" or "rotation"
    """
    n = len(model)
    strokes = np.asarray(strokes_mm, dtype=float).reshape(n, 2)
    s_c = optics.unit(_rows(sun_at_capture_enu, n))
    s_n = optics.unit(_rows(sun_at_next_enu, n))
    spot = _rows(spot_enu, n)
    aim = _rows(aim_enu, n)
    n_cmd = model.normal(strokes)
    n_obs = observed_normal(model.pivots_eff_enu, s_c, spot, model.mirror_offset_m)
    err_mrad = 1000.0 * optics.angle_between_rad(n_cmd, n_obs)
    s_obs, ang_obs, _ = model.normal_to_strokes(n_obs)
    stroke_err = s_obs - strokes
    if mode == "stroke":
        nxt = model.strokes_for_aim(s_n, aim)
        new = nxt.strokes_mm - stroke_err
    elif mode == "angle":
        nxt = model.strokes_for_aim(s_n, aim)
        ang_err = ang_obs - model.angles(strokes)
        new = angles_to_strokes(model.drives_eff, nxt.angles_rad - ang_err)
    elif mode == "rotation":
        n_des = optics.aim_normal(model.pivots_eff_enu, s_n, aim, model.mirror_offset_m)
        axis = np.cross(n_obs, n_cmd)
        norm = np.linalg.norm(axis, axis=-1, keepdims=True)
        axis = np.where(norm > 1e-15, axis / np.where(norm > 1e-15, norm, 1.0), np.array([1.0, 0.0, 0.0]))
        n_command = rotate(axis, err_mrad / 1000.0, n_des)  # undo the observed error: n_obs → n_cmd
        new = model.normal_to_strokes(n_command)[0]
    else:
        raise ValueError(f"mode must be 'stroke', 'angle' or 'rotation', not {mode!r}")
    in_range = np.all(strokes_in_range(model.drives, new), axis=-1)
    return Correction(strokes_mm=new, delta_mm=new - strokes, normal_error_mrad=err_mrad, in_range=in_range,
                      observed_normal_enu=n_obs, model_normal_enu=n_cmd, stroke_error_mm=stroke_err)
