"""Before/after frames → flux map on the board, with every correction recorded (pure).

:func:`measure_flux` chains the corrections of :mod:`helicalib.flux.corrections` in the paper's
order: each raw frame is linearised, dark-subtracted and flat-fielded in image pixels; the
difference after − before (the heliostat's beam alone; ambient light and other beams cancel) is
resampled onto the board grid through the marks' homography (with lens distortion when asked);
the non-Lambertian factor is applied per cell; ``E = F_e·G`` gives the map (eq. 9).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from helicalib.errors import MeasurementError
from helicalib.flux.corrections import correct_frame, rectify_to_grid, relative_response
from helicalib.flux.fluxmap import FluxMap, flux_map
from helicalib.flux.grid import BoardGrid

__all__ = ["FluxResult", "auto_cell_m", "measure_flux"]


@dataclass(frozen=True)
class FluxResult:
    """A measured flux map with the corrections that made it.

    Attributes
    ----------
    fluxmap : FluxMap
    fe_wm2_per_grey : float
        Calibration factor used [W/m² per grey level].
    corrections : dict
        One entry per correction (dark, nonlinearity, flat_field, distortion, perspective,
        non_lambertian): ``{"applied": bool, ...details}``.
    saturated_px : int
        Pixels of the after frame at or above the saturation level (their flux is a lower bound).
    """

    fluxmap: FluxMap
    fe_wm2_per_grey: float
    corrections: dict[str, Any] = field(default_factory=dict)
    saturated_px: int = 0


def auto_cell_m(homography_px_to_uv: np.ndarray, image_shape: tuple[int, int]) -> float:
    """The side of one image pixel's footprint at the image centre on the board [m].

    A grid of this cell size keeps the camera's resolution without inventing detail.
    """
    h = np.asarray(homography_px_to_uv, dtype=float)
    cy, cx = (image_shape[0] - 1) / 2, (image_shape[1] - 1) / 2
    pts = np.array([[cx, cy, 1.0], [cx + 1, cy, 1.0], [cx, cy + 1, 1.0]]).T
    uv = h @ pts
    uv = uv[:2] / uv[2]
    du, dv = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return float(np.sqrt(abs(du[0] * dv[1] - du[1] * dv[0])))


def measure_flux(before_raw: np.ndarray, after_raw: np.ndarray, homography_px_to_uv: np.ndarray, grid: BoardGrid,
                 fe_wm2_per_grey: float, *, dark_grey: float | None = None, response=None,
                 flat_factors: np.ndarray | None = None, camera_matrix: np.ndarray | None = None,
                 distortion: np.ndarray | None = None, incidence_deg: float | None = None,
                 incidence_table: tuple[np.ndarray, np.ndarray] | None = None,
                 view_deg: np.ndarray | None = None, view_table: tuple[np.ndarray, np.ndarray] | None = None,
                 saturation_grey: float = 255.0, record: dict[str, Any] | None = None) -> FluxResult:
    """Flux density map of one heliostat's beam from a before and an after frame.

    Parameters
    ----------
    before_raw, after_raw : np.ndarray, shape (H, W)
        Raw frames without and with the beam [grey].
    homography_px_to_uv : np.ndarray, shape (3, 3)
        Image px → target (u, v) [m]; of the undistorted image when ``distortion`` is given.
    grid : BoardGrid
        The board grid of the result.
    fe_wm2_per_grey : float
        F_e [W/m² per grey level].
    dark_grey, response, flat_factors
        As :func:`helicalib.flux.corrections.correct_frame`; None skips a correction.
    camera_matrix : np.ndarray, shape (3, 3), optional
    distortion : array_like, optional
        Lens distortion, OpenCV order; applied only with ``camera_matrix``.
    incidence_deg : float, optional
        Angle between the beam and the board normal [deg]; needed with ``incidence_table``.
    incidence_table : (angles_deg (n,), relative (n,)), optional
        Non-Lambertian response against incidence (eq. 7).
    view_deg : np.ndarray, shape grid.shape, optional
        Camera viewing angle per cell [deg]; needed with ``view_table``.
    view_table : (angles_deg (n,), relative (n,)), optional
        Non-Lambertian response against the viewing angle.
    saturation_grey : float
        Raw level counted as saturated.
    record : dict, optional
        Details of the loaded corrections (``CorrectionData.record``) merged into the result.

    Returns
    -------
    FluxResult

    Raises
    ------
    MeasurementError
        Frames of different or mismatched size, or a board not seen.
    """
    before = np.asarray(before_raw, dtype=float)
    after = np.asarray(after_raw, dtype=float)
    if before.ndim != 2 or before.shape != after.shape:
        raise MeasurementError(f"before and after frames differ in size: {before.shape} vs {after.shape}")
    if flat_factors is not None and flat_factors.shape != before.shape:
        raise MeasurementError(f"flat-field frame is {flat_factors.shape[1]}x{flat_factors.shape[0]} px, "
                               f"the frames {before.shape[1]}x{before.shape[0]} px")
    details = dict(record or {})
    rec: dict[str, Any] = {}
    rec["dark"] = {"applied": dark_grey is not None, **details.get("dark", {})}
    rec["nonlinearity"] = {"applied": response is not None, **details.get("nonlinearity", {})}
    rec["flat_field"] = {"applied": flat_factors is not None, **details.get("flat_field", {})}
    kw = {"dark_grey": dark_grey, "response": response, "flat_factors": flat_factors}
    diff = correct_frame(after, **kw) - correct_frame(before, **kw)
    use_dist = camera_matrix is not None and distortion is not None and bool(np.any(np.asarray(distortion) != 0))
    rec["distortion"] = {"applied": use_dist}
    if use_dist:
        rec["distortion"]["coefficients"] = [float(x) for x in np.asarray(distortion).ravel()]
    grey = rectify_to_grid(diff, homography_px_to_uv, grid, camera_matrix=camera_matrix,
                           distortion=distortion if use_dist else None)
    rec["perspective"] = {"applied": True, "interpolation": "bilinear", "cell_m": round(grid.cell_m, 6),
                          "grid_shape": list(grid.shape)}
    if not np.isfinite(grey).any():
        raise MeasurementError("the board lies outside the frame: no grid cell was seen")
    factor: np.ndarray | float = 1.0
    nl: dict[str, Any] = {"applied": False}
    if incidence_table is not None:
        if incidence_deg is None:
            raise MeasurementError("the non-Lambertian incidence table needs the beam's incidence angle "
                                   "(give the heliostat or --incidence-deg)")
        lb = float(relative_response(incidence_deg, *incidence_table))
        factor = factor / lb
        nl.update(applied=True, incidence_deg=round(float(incidence_deg), 3), incidence_relative=round(lb, 5))
    if view_table is not None:
        if view_deg is None:
            raise MeasurementError("the non-Lambertian view table needs the camera position (cameras[].position_enu_m)")
        lbv = relative_response(view_deg, *view_table)
        factor = factor / lbv
        nl.update(applied=True, view_deg_range=[round(float(np.nanmin(view_deg)), 3), round(float(np.nanmax(view_deg)), 3)])
    rec["non_lambertian"] = nl
    fm = flux_map(grey, grid, fe_wm2_per_grey, factor)
    saturated = int(np.count_nonzero(after >= saturation_grey))
    return FluxResult(fluxmap=fm, fe_wm2_per_grey=float(fe_wm2_per_grey), corrections=rec, saturated_px=saturated)
