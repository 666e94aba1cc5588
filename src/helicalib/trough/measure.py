"""Detect the tube's edges in each facet of a photo and estimate each facet's tilt.

Detection (per facet seen by the camera): in up to ``columns`` image columns across the facet,
the grey profile between the facet's upper and lower boundary lines is split at the mid level
between its bright (sky) and dark (tube) levels; the longest dark run is the tube, and its two
ends are located to sub-pixel rows by the area (summed darkness) rule. The facet's edge offset from the theoretical overlay is
the median over columns.

Tilt: the facet is rotated about a line parallel to X through its strip centre on the parabola
until the modelled edge (the same B/E solver, for the tilted facet) falls on the detected one.
Each edge gives a tilt; their mean is the facet's tilt, their difference (``spread``) shows a
change of the tube image's width that a tilt cannot explain (bending, wrong position, focus).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helicalib.errors import MeasurementError
from helicalib.trough.camera import PinholeCamera
from helicalib.trough.config import Collector
from helicalib.trough.overlay import Overlay, edges_in_image, v_at_u

TILT_SEARCH_MRAD = 25.0
"""Tilts are searched in ±this range [mrad]."""
MODEL_EXTENSION_MM = 1500.0
"""The tilt model extends each facet's surface by this much so edges move smoothly [mm]."""


@dataclass(frozen=True)
class Detection:
    """Detected tube edges per facet (arrays shape (N,), rows in px; NaN where not detected)."""

    u_px: np.ndarray  # column where the offsets are reported (middle of the columns used)
    lower_v_px: np.ndarray  # detected lower edge (B) at u_px
    upper_v_px: np.ndarray  # detected upper edge (E) at u_px
    lower_offset_px: np.ndarray  # detected - theoretical (median over columns), + = lower in the photo
    upper_offset_px: np.ndarray
    columns_used: np.ndarray  # int


def _profile_edges(profile: np.ndarray, min_contrast: float, window_px: int = 3):
    """Sub-pixel rows (in profile index) of the top and bottom ends of the longest dark run.

    The run is found with a mid-level threshold; each end is then located by the area rule: over
    ``2 * window_px`` pixels straddling it, the summed darkness fraction ``(bright - I)/(bright - dark)``
    is the dark length inside the window. This is exact for a sharp edge averaged over the pixel
    (and for any symmetric blur narrower than the window), unlike interpolating the threshold.
    """
    hi, lo = np.percentile(profile, 90), np.percentile(profile, 5)
    if hi - lo < min_contrast:
        return np.nan, np.nan
    thr = 0.5 * (hi + lo)
    padded = np.concatenate([[0], (profile < thr).astype(np.int8), [0]])
    starts = np.flatnonzero(np.diff(padded) == 1)
    stops = np.flatnonzero(np.diff(padded) == -1) - 1  # inclusive
    if starts.size == 0:
        return np.nan, np.nan
    k = int(np.argmax(stops - starts))
    s, e = int(starts[k]), int(stops[k])
    w = max(1, min(window_px, (e - s + 1) // 2))
    inner = profile[s + w:e - w + 1]
    dark = np.median(inner) if inner.size else profile[s:e + 1].min()
    outside = np.concatenate([profile[:max(s - w, 0)], profile[e + w + 1:]])
    if outside.size == 0:
        return np.nan, np.nan
    bright = np.median(outside)
    if bright - dark < min_contrast:
        return np.nan, np.nan
    frac = (bright - profile) / (bright - dark)
    top = bottom = np.nan
    if s - w >= 0:  # rows s-w .. s+w-1: bright above, dark below
        top = (s + w - 0.5) - np.sum(frac[s - w:s + w])
    if e + w <= profile.size - 1:  # rows e-w+1 .. e+w: dark above, bright below
        bottom = (e - w + 0.5) + np.sum(frac[e - w + 1:e + w + 1])
    return top, bottom


def detect_edges(image: np.ndarray, overlay: Overlay, camera: PinholeCamera, columns: int = 31,
                 margin_px: float = 3.0, min_contrast: float = 20.0) -> Detection:
    """Detect the tube edges in every facet where the overlay expects them.

    Parameters
    ----------
    image : ndarray, shape (height, width)
        Grey photo (any numeric type, 0–255 scale for ``min_contrast``).
    overlay : Overlay
        The theoretical overlay for this camera.
    camera : PinholeCamera
    columns : int
        Columns sampled per facet.
    margin_px : float
        Distance kept from the facet's boundary lines and the frame [px].
    min_contrast : float
        Smallest bright-minus-dark difference accepted in a column [grey levels].

    Returns
    -------
    Detection
    """
    img = np.asarray(image, dtype=float)
    h, w = img.shape[:2]
    if (w, h) != tuple(camera.image_size_px):
        raise MeasurementError(f"photo is {w}×{h} px but CAMERA.yaml says {camera.image_size_px[0]}×{camera.image_size_px[1]}")
    n = overlay.found.shape[0]
    u_range = overlay.u_range_px()
    out = {k: np.full(n, np.nan) for k in ("u", "lv", "uv", "lo", "uo")}
    used = np.zeros(n, dtype=int)
    for i in np.flatnonzero(overlay.visible):
        lo, hi = u_range[i]
        shrink = 0.1 * (hi - lo)
        lo, hi = max(lo + shrink, margin_px), min(hi - shrink, w - 1 - margin_px)
        if not hi > lo:
            continue
        us = np.unique(np.rint(np.linspace(lo, hi, columns)).astype(int))
        top_v = v_at_u(overlay.strip_top_uv_px[i:i + 1], us[None, :])[0]
        bot_v = v_at_u(overlay.strip_bottom_uv_px[i:i + 1], us[None, :])[0]
        th_l = v_at_u(overlay.lower_uv_px[i:i + 1], us[None, :])[0]
        th_u = v_at_u(overlay.upper_uv_px[i:i + 1], us[None, :])[0]
        d_l, d_u = [], []
        for u, v0, v1, tl, tu in zip(us, top_v, bot_v, th_l, th_u):
            a = int(np.ceil(max(min(v0, v1) + margin_px, 0)))
            b = int(np.floor(min(max(v0, v1) - margin_px, h - 1)))
            if b - a < 8:
                continue
            top, bottom = _profile_edges(img[a:b + 1, u], min_contrast)
            if np.isfinite(bottom):
                d_l.append(a + bottom - tl)
            if np.isfinite(top):
                d_u.append(a + top - tu)
        if not d_l and not d_u:
            continue
        uc = 0.5 * (us[0] + us[-1])
        out["u"][i] = uc
        used[i] = max(len(d_l), len(d_u))
        if d_l:
            out["lo"][i] = np.median(d_l)
            out["lv"][i] = v_at_u(overlay.lower_uv_px[i:i + 1], np.array([uc]))[0] + out["lo"][i]
        if d_u:
            out["uo"][i] = np.median(d_u)
            out["uv"][i] = v_at_u(overlay.upper_uv_px[i:i + 1], np.array([uc]))[0] + out["uo"][i]
    return Detection(u_px=out["u"], lower_v_px=out["lv"], upper_v_px=out["uv"], lower_offset_px=out["lo"],
                     upper_offset_px=out["uo"], columns_used=used)


@dataclass(frozen=True)
class TiltEstimate:
    """Per-facet tilt estimates (arrays shape (N,)).

    ``tilt_mrad`` is the rotation about +X (right hand: the facet's upper edge moves towards the
    focal line for positive values); NaN where it could not be estimated, with ``status`` saying why.
    """

    tilt_mrad: np.ndarray
    lower_tilt_mrad: np.ndarray
    upper_tilt_mrad: np.ndarray
    spread_mrad: np.ndarray
    upper_edge_shift_mm: np.ndarray  # tilt × facet width [mm]: the upper edge stands out this much
    # (towards the focal line, relative to the lower edge); a shim of this height under the lower
    # edge's supports, or its removal under the upper edge's, corrects the tilt
    status: tuple[str, ...]  # "ok" | "adjust" | "not_visible" | "not_detected" | "out_of_range"


def _solve_tilt(collector: Collector, overlay: Overlay, camera: PinholeCamera, u_px, target_v_px, edge: str, steps: int = 40):
    """Vectorised bisection over facets: the tilt whose modelled edge row at ``u_px`` is ``target_v_px``."""
    n = target_v_px.shape[0]
    ok = np.isfinite(target_v_px) & np.isfinite(u_px)
    uu = np.where(ok, u_px, 0.0)

    def residual(tilt):
        ov = edges_in_image(collector, overlay.layout, camera, tilt, extend_mm=MODEL_EXTENSION_MM)
        # the edge's visible x extent may vanish at extreme tilts: use the facet's full length
        return v_at_u(_full_length_segment(ov, camera, edge), uu) - target_v_px

    lo, hi = np.full(n, -TILT_SEARCH_MRAD), np.full(n, TILT_SEARCH_MRAD)
    g_lo, g_hi = residual(lo), residual(hi)
    ok &= np.isfinite(g_lo) & np.isfinite(g_hi) & (np.sign(g_lo) != np.sign(g_hi))
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        g = residual(mid)
        same = np.sign(g) == np.sign(g_lo)
        lo, g_lo = np.where(same, mid, lo), np.where(same, g, g_lo)
        hi = np.where(same, hi, mid)
    return np.where(ok, 0.5 * (lo + hi), np.nan), ok


def _full_length_segment(ov: Overlay, camera: PinholeCamera, edge: str) -> np.ndarray:
    yz = ov.lower_yz_mm if edge == "lower" else ov.upper_yz_mm
    lay = ov.layout
    ends = np.stack([np.stack([x, yz[:, 0], yz[:, 1]], axis=-1) for x in (lay.x_min_mm, lay.x_max_mm)], axis=1)
    return camera.project(ends)[0]


def estimate_tilts(collector: Collector, overlay: Overlay, camera: PinholeCamera, detection: Detection) -> TiltEstimate:
    """Estimate each facet's tilt about the collector axis from its detected edges.

    Parameters
    ----------
    collector : Collector
    overlay : Overlay
        Theoretical overlay (untilted) for this camera.
    camera : PinholeCamera
    detection : Detection

    Returns
    -------
    TiltEstimate
    """
    t_l, ok_l = _solve_tilt(collector, overlay, camera, detection.u_px, detection.lower_v_px, "lower")
    t_u, ok_u = _solve_tilt(collector, overlay, camera, detection.u_px, detection.upper_v_px, "upper")
    both = np.stack([t_l, t_u])
    count = np.sum(np.isfinite(both), axis=0)
    tilt = np.where(count > 0, np.nansum(both, axis=0) / np.maximum(count, 1), np.nan)
    spread = t_u - t_l
    lay = overlay.layout
    f = collector.focal_length_mm
    dy = lay.y_max_mm - lay.y_min_mm
    dz = (lay.y_max_mm**2 - lay.y_min_mm**2) / (4 * f)
    width = np.hypot(dy, dz)
    status = []
    for i in range(tilt.shape[0]):
        if not overlay.visible[i]:
            status.append("not_visible")
        elif np.isnan(detection.lower_v_px[i]) and np.isnan(detection.upper_v_px[i]):
            status.append("not_detected")
        elif np.isnan(tilt[i]):
            status.append("out_of_range")
        else:
            status.append("ok" if abs(tilt[i]) <= collector.tilt_tolerance_mrad else "adjust")
    return TiltEstimate(tilt_mrad=tilt, lower_tilt_mrad=t_l, upper_tilt_mrad=t_u, spread_mrad=spread,
                        upper_edge_shift_mm=tilt * 1e-3 * width, status=tuple(status))
