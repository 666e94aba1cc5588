"""A mirror's cleanliness from one calibration visit's frames (pure: arrays in, a record out).

A visit already has what the estimate needs: a "before" frame without the heliostat's beam, an
"after" frame with it, the board marks found in the before frame (their homography), the sun
vector and DNI at the capture, and the heliostat's model (pivot, mirror normal at the held strokes,
mirror offset and size). :func:`cleanliness_from_visit` turns the after − before difference into
a flux map on the board (:func:`helicalib.flux.measure.measure_flux`, ``E = Fe·G``), sums it into
the power on the board and divides by the power a clean mirror would deliver
(:func:`helicalib.flux.cleanliness.estimate_cleanliness`)::

    c = P_board / (DNI · A · ρ_clean · cos θ · τ_atm · η_int)

with the mirror centre ``M = pivot + offset · normal``, the beam's landing point taken as the
flux-weighted centre of the measured map (``cos θ`` by the bisector of the sun and M → spot,
``τ_atm`` over |spot − M|), and the intercept ``η_int`` = 1 for a spot that lies wholly on the
board, or the Gaussian intercept when the spot's σ is given.

When no honest estimate can be made the value is None and ``reason`` says why (one code):

* ``no_fe`` — no calibration factor Fe for this camera;
* ``dni_low`` — DNI below ``min_dni_wm2`` (the spot is weak against the noise, and DNI itself is
  then often a passing cloud's, not the beam's);
* ``no_marks`` — the board marks were not found (no homography onto the board);
* ``saturated`` — after-frame pixels at the saturation level (their flux is only a lower bound);
* ``clipped`` — the spot reaches the board's edge (power lost off the board) or, with σ given,
  the modelled intercept is below ``min_intercept``;
* ``no_spot`` — no positive power on the board;
* ``no_expected_power`` — the clean mirror would deliver nothing (sun behind the mirror, …);
* ``flux_error`` — the flux map could not be made (frames of different size, board not seen).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from helicalib.errors import MeasurementError
from helicalib.flux.cleanliness import (
    atmospheric_attenuation,
    cos_incidence,
    estimate_cleanliness,
    expected_power_w,
    gaussian_intercept,
)
from helicalib.flux.grid import board_grid
from helicalib.flux.measure import auto_cell_m, measure_flux

__all__ = ["REASONS", "CleanlinessEstimate", "cleanliness_from_visit", "edge_fraction"]

REASONS = ("ok", "no_fe", "dni_low", "no_marks", "saturated", "clipped", "no_spot", "no_expected_power", "flux_error")
"""Reason codes of :class:`CleanlinessEstimate` (``ok`` when a value was estimated)."""

MIN_DNI_WM2 = 200.0
"""Default lowest DNI at which a visit estimates cleanliness [W/m²]."""
MAX_EDGE_FRACTION = 0.05
"""A spot whose smoothed flux along the board's edge exceeds this fraction of its smoothed peak is clipped."""
MIN_INTERCEPT = 0.5
"""With a modelled Gaussian spot, intercepts below this are refused (the model carries the estimate)."""
SMOOTH_M = 0.5
"""Side of the box [m] that smooths the flux map for the edge test (averages the sensor noise away;
measured on the simulated plant: 0.25 m left an edge fraction up to 0.036 for spots wholly on the
board, 0.5 m up to 0.014)."""
MAX_GRID_CELLS = 256
"""The board grid has at most this many cells along its longer side (the power is an integral:
finer cells add time, not accuracy)."""


@dataclass(frozen=True)
class CleanlinessEstimate:
    """One visit's cleanliness estimate and the figures it came from.

    Attributes
    ----------
    value : float or None
        Estimated cleanliness (soiled/clean reflectance; not clipped to [0, 1]); None when it
        cannot be estimated (see ``reason``).
    power_w : float or None
        Measured power on the board [W] (None when no flux map was made).
    expected_w : float or None
        Power a clean mirror would put on the board under these conditions [W].
    intercept : float or None
        Fraction of the beam assumed on the board (1 for a spot wholly on it).
    reason : str
        ``ok`` or one of :data:`REASONS`.
    cos_incidence, attenuation : float or None
        cos of the sun's incidence on the mirror, atmospheric transmittance used.
    centre_uv_m : (float, float) or None
        Flux-weighted spot centre on the board [m, target frame].
    edge_fraction : float or None
        Smoothed flux along the board edge / smoothed peak (the clipping test's figure).
    saturated_px : int
        After-frame pixels at the saturation level.
    """

    value: float | None
    power_w: float | None
    expected_w: float | None
    intercept: float | None
    reason: str
    cos_incidence: float | None = None
    attenuation: float | None = None
    centre_uv_m: tuple[float, float] | None = None
    edge_fraction: float | None = None
    saturated_px: int = 0

    @property
    def ok(self) -> bool:
        return self.value is not None


def _none(reason: str, **kw) -> CleanlinessEstimate:
    base = dict(value=None, power_w=None, expected_w=None, intercept=None)
    base.update(kw)
    return CleanlinessEstimate(reason=reason, **base)


def edge_fraction(flux_wm2: np.ndarray, cell_m: float, smooth_m: float = SMOOTH_M) -> float:
    """Largest box-smoothed flux within one box of the board edge, over the largest smoothed flux.

    Parameters
    ----------
    flux_wm2 : np.ndarray, shape (nv, nu)
        Flux map on the board grid [W/m²]; NaN cells (unseen) count as missing, not as zero.
    cell_m : float
        Grid cell side [m].
    smooth_m : float
        Side of the smoothing box [m] (at least one cell).

    Returns
    -------
    float
        0 for a spot far from every edge, about 0.5 for a spot centred on an edge; NaN when the
        map has no positive smoothed flux.
    """
    import cv2

    f = np.asarray(flux_wm2, dtype=np.float32)
    seen = np.isfinite(f)
    k = max(1, int(round(smooth_m / cell_m)))
    k = min(k, max(1, min(f.shape) // 4))
    num = cv2.blur(np.where(seen, f, 0.0).astype(np.float32), (k, k), borderType=cv2.BORDER_REFLECT)
    den = cv2.blur(seen.astype(np.float32), (k, k), borderType=cv2.BORDER_REFLECT)
    with np.errstate(invalid="ignore", divide="ignore"):
        sm = np.where(den > 0.5, num / np.maximum(den, 1e-6), np.nan)
    peak = float(np.nanmax(sm)) if np.isfinite(sm).any() else float("nan")
    if not peak > 0:
        return float("nan")
    ring = np.zeros(f.shape, dtype=bool)
    ring[:k, :] = ring[-k:, :] = True
    ring[:, :k] = ring[:, -k:] = True
    edge = sm[ring]
    edge = edge[np.isfinite(edge)]
    return float(max(0.0, edge.max()) / peak) if edge.size else 0.0


def cleanliness_from_visit(before: np.ndarray, after: np.ndarray, marks, target, *, fe_wm2_per_grey: float | None,
                           reflectivity_clean: float, dni_wm2: float | None, sun_enu: np.ndarray,
                           pivot_enu: np.ndarray, normal_enu: np.ndarray, mirror_offset_m: float,
                           mirror_area_m2: float, spot_sigma_m: float | None = None,
                           atmosphere: str | None = "clear", min_dni_wm2: float = MIN_DNI_WM2,
                           max_edge_fraction: float = MAX_EDGE_FRACTION, min_intercept: float = MIN_INTERCEPT,
                           saturation_grey: float = 255.0, cell_m: float | None = None) -> CleanlinessEstimate:
    """Estimate a mirror's cleanliness from a visit's before and after frames.

    Parameters
    ----------
    before, after : np.ndarray, shape (H, W)
        Raw frames without and with the heliostat's beam [grey] (uint8 or float). With several
        after frames, pass the last one (or their mean).
    marks : vision.marks.MarksResult
        Marks found in ``before``; ``marks.homography`` maps image px → target (u, v) [m].
    target : config.Target
        The board (``size_m``, ``uvw_to_enu``).
    fe_wm2_per_grey : float or None
        The camera's calibration factor Fe [W/m² per grey]; None → ``no_fe``.
    reflectivity_clean : float
        Clean mirror reflectivity, 0..1.
    dni_wm2 : float or None
        DNI at the capture [W/m²].
    sun_enu : np.ndarray, shape (3,)
        Unit vector toward the sun at the capture [ENU].
    pivot_enu : np.ndarray, shape (3,)
        The heliostat's pivot [m, ENU] (the model's effective pivot).
    normal_enu : np.ndarray, shape (3,)
        Mirror normal at the held strokes [ENU] (the model's).
    mirror_offset_m : float
        Mirror centre = pivot + offset · normal [m].
    mirror_area_m2 : float
        Reflective area [m²].
    spot_sigma_m : float, optional
        σ of a Gaussian spot on the board [m]: the intercept is then
        :func:`~helicalib.flux.cleanliness.gaussian_intercept` at the measured centre. None: the spot
        must lie wholly on the board (the edge test) and the intercept is 1.
    atmosphere : {"clear", "hazy", "none"} or None
        Atmospheric attenuation model over the slant range; None or "none": no attenuation (τ = 1,
        e.g. the simulated plant).
    min_dni_wm2 : float
        Below this DNI no estimate is made [W/m²].
    max_edge_fraction : float
        Edge test limit (see :func:`edge_fraction`).
    min_intercept : float
        Lowest modelled intercept accepted (with ``spot_sigma_m``).
    saturation_grey : float
        Raw level counted as saturated.
    cell_m : float, optional
        Board grid cell [m]; default one pixel's footprint, but at most :data:`MAX_GRID_CELLS`
        cells along the board's longer side.

    Returns
    -------
    CleanlinessEstimate
    """
    if fe_wm2_per_grey is None or not (math.isfinite(float(fe_wm2_per_grey)) and float(fe_wm2_per_grey) > 0):
        return _none("no_fe")
    if dni_wm2 is None or not math.isfinite(float(dni_wm2)) or float(dni_wm2) < min_dni_wm2:
        return _none("dni_low")
    h = getattr(marks, "homography", None)
    if not getattr(marks, "found", False) or h is None or not np.all(np.isfinite(h)):
        return _none("no_marks")
    before = np.asarray(before)
    after = np.asarray(after)
    if cell_m is None:
        try:
            cell_m = auto_cell_m(h, before.shape)
        except (ValueError, FloatingPointError):
            cell_m = 0.0
        cell_m = max(cell_m if math.isfinite(cell_m) else 0.0, max(target.size_m) / MAX_GRID_CELLS)
    try:
        grid = board_grid(target.size_m, cell_m)
        res = measure_flux(before, after, h, grid, float(fe_wm2_per_grey), saturation_grey=saturation_grey)
    except (MeasurementError, ValueError):
        return _none("flux_error")
    fm = res.fluxmap
    power = float(fm.power_w)
    centre = fm.centre_uv_m
    centre_t = None if not all(map(math.isfinite, centre)) else (float(centre[0]), float(centre[1]))
    edge = edge_fraction(fm.flux_wm2, grid.cell_m)
    common = dict(power_w=power, centre_uv_m=centre_t, edge_fraction=None if math.isnan(edge) else edge,
                  saturated_px=int(res.saturated_px))
    if res.saturated_px > 0:
        return _none("saturated", **common)
    if not power > 0 or centre_t is None or math.isnan(edge):
        return _none("no_spot", **common)
    sun = np.asarray(sun_enu, dtype=float)
    sun = sun / np.linalg.norm(sun)
    n = np.asarray(normal_enu, dtype=float)
    n = n / np.linalg.norm(n)
    mirror = np.asarray(pivot_enu, dtype=float) + float(mirror_offset_m) * n
    spot_enu = np.asarray(target.uvw_to_enu(np.asarray(centre_t)), dtype=float)
    cos_i = float(cos_incidence(sun, mirror, spot_enu))
    tau = 1.0 if atmosphere is None else float(atmospheric_attenuation(float(np.linalg.norm(spot_enu - mirror)),
                                                                       atmosphere))
    if spot_sigma_m is None:
        if edge > max_edge_fraction:
            return _none("clipped", cos_incidence=cos_i, attenuation=tau, **common)
        intercept = 1.0
    else:
        half = (target.size_m[0] / 2.0, target.size_m[1] / 2.0)
        intercept = float(gaussian_intercept(float(spot_sigma_m), half, centre_t))
        if intercept < min_intercept:
            return _none("clipped", intercept=intercept, cos_incidence=cos_i, attenuation=tau, **common)
    # the sun must light the mirror's front: s·n > 0 (the model's normal; cos_i alone is always >= 0)
    expected = float(expected_power_w(float(dni_wm2), float(mirror_area_m2), float(reflectivity_clean), cos_i,
                                      tau, intercept))
    if not expected > 0 or float(sun @ n) <= 0:
        return _none("no_expected_power", intercept=intercept, cos_incidence=cos_i, attenuation=tau, **common)
    c = float(estimate_cleanliness(power, float(dni_wm2), float(mirror_area_m2), float(reflectivity_clean), cos_i,
                                   tau, intercept))
    return CleanlinessEstimate(value=c, expected_w=expected, intercept=intercept, reason="ok", cos_incidence=cos_i,
                               attenuation=tau, **common)
