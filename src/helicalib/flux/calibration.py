"""The flux calibration factor F_e (W/m² per grey level) and the system error (Zhang & Wang).

Equation (1) of the seed paper, ``E = F_e·G``, needs F_e. Two ways to get it:

* **Two radiometers** (section 2, eq. 2). Radiometer a sits at the focus and reads ``E_a`` while
  the reference radiometer b, elsewhere on the board, reads ``E_b``. Radiometer a is removed;
  b now reads ``E_b'`` and the camera takes the frame whose mean corrected grey level over a circle
  of a's receiving area S, centred on the focus, is ``G_av``. The flux at the focus while the frame
  was taken is ``E_a·E_b'/E_b`` (b tracks the change of sunlight during the swap), so

      F_e = E_a · E_b' / (E_b · G_av).

  A single-radiometer calibration would have been off by ``ε_mea = |E_b' − E_b| / E_b``
  (our reading of eq. 8, the sunlight change the second radiometer removes).

* **Camera on the sun** (ref. 5). The same camera, same focus, aperture and exposure, looks at the
  sun through an ND filter of transmittance τ (relative to the filter used for board frames). A
  pixel's grey level is ``c·L`` for the radiance L it sees. Summed over the sun's image,
  ``Σ G_sun = c·τ·DNI / Ω_px`` (``Ω_px`` = one pixel's solid angle, ``1/(f_x·f_y)`` sr); a
  Lambertian board of reflectance ρ under flux E has radiance ``ρE/π``, so

      F_e = E / G = π · τ · DNI / (ρ · Ω_px · Σ G_sun).

  Summing over the disc makes the result independent of sun shape and limb darkening.

The system error (section 4) is ``ε_sys = sqrt(Σ ε_i²)`` of independent component errors.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from helicalib.flux.grid import BoardGrid

__all__ = [
    "PAPER_COMPONENT_ERRORS",
    "fe_camera_on_sun",
    "fe_two_radiometer",
    "mean_grey_in_circle",
    "single_radiometer_error",
    "sun_grey_sum",
    "system_error",
]

PAPER_COMPONENT_ERRORS: dict[str, tuple[float, float]] = {
    "dark": (0.005, 0.01),
    "nonlinearity": (0.02, 0.04),
    "nonuniformity": (0.001, 0.006),
    "non_lambertian": (0.02, 0.08),
}
"""Ranges of the component errors the paper found by survey (fractions): ε_dark, ε_NL, ε_NU, ε_LB."""


def fe_two_radiometer(ea_wm2: float, eb_wm2: float, eb_prime_wm2: float, gav_grey: float) -> float:
    """Calibration factor by the two-radiometer method, ``F_e = E_a·E_b' / (E_b·G_av)`` (eq. 2).

    Parameters
    ----------
    ea_wm2 : float
        Radiometer a at the focus [W/m²].
    eb_wm2 : float
        Reference radiometer b, read together with a [W/m²].
    eb_prime_wm2 : float
        Radiometer b after a was removed, when the frame was taken [W/m²].
    gav_grey : float
        Mean corrected grey level over a circle of a's receiving area centred on the focus [grey].

    Returns
    -------
    float
        F_e [W/m² per grey level].
    """
    for name, value in (("ea_wm2", ea_wm2), ("eb_wm2", eb_wm2), ("eb_prime_wm2", eb_prime_wm2), ("gav_grey", gav_grey)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(ea_wm2) * float(eb_prime_wm2) / (float(eb_wm2) * float(gav_grey))


def single_radiometer_error(eb_wm2: float, eb_prime_wm2: float) -> float:
    """Error a single-radiometer calibration would carry, ``|E_b' − E_b| / E_b`` (fraction)."""
    if not eb_wm2 > 0:
        raise ValueError(f"eb_wm2 must be positive, got {eb_wm2!r}")
    return abs(float(eb_prime_wm2) - float(eb_wm2)) / float(eb_wm2)


def mean_grey_in_circle(grey_map: np.ndarray, grid: BoardGrid, centre_uv_m: tuple[float, float],
                        area_m2: float) -> float:
    """``G_av``: mean grey level over the circle of area ``area_m2`` centred at ``centre_uv_m``.

    Cells whose centre lies inside the circle count (NaN cells are skipped). The circle must
    cover at least one cell; use a grid finer than the radiometer's aperture.

    Parameters
    ----------
    grey_map : np.ndarray, shape grid.shape
        Corrected grey levels on the board grid.
    grid : BoardGrid
    centre_uv_m : (float, float)
        The focus, where radiometer a was [m, target frame].
    area_m2 : float
        Radiometer a's receiving area S [m²].
    """
    radius = math.sqrt(area_m2 / math.pi)
    uu, vv = grid.mesh_m()
    inside = (uu - centre_uv_m[0]) ** 2 + (vv - centre_uv_m[1]) ** 2 <= radius**2
    values = np.asarray(grey_map, dtype=float)[inside]
    values = values[np.isfinite(values)]
    if values.size == 0:
        raise ValueError(f"no grid cell lies within {radius:.4g} m of ({centre_uv_m[0]}, {centre_uv_m[1]})")
    return float(values.mean())


def sun_grey_sum(grey: np.ndarray, radius_factor: float = 2.0) -> float:
    """Σ G over the sun's image in a corrected (dark-free) frame taken at the sun [grey].

    The disc is found as the pixels above half the maximum; the sum runs over a circle
    ``radius_factor`` times that disc's equivalent radius around its centroid, so the dim limb and
    blur are included while the rest of the (dark) frame is not.

    Parameters
    ----------
    grey : np.ndarray, shape (H, W)
        Corrected grey levels (dark subtracted, linearised, flat-fielded).
    radius_factor : float
        Summing radius / equivalent radius of the half-maximum disc.
    """
    g = np.asarray(grey, dtype=float)
    peak = float(np.nanmax(g))
    if not peak > 0:
        raise ValueError("the sun frame has no signal")
    disc = g >= peak / 2
    ys, xs = np.nonzero(disc)
    w = g[disc]
    cy, cx = float((ys * w).sum() / w.sum()), float((xs * w).sum() / w.sum())
    r = radius_factor * math.sqrt(disc.sum() / math.pi)
    yy, xx = np.indices(g.shape)
    window = (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r
    return float(np.nansum(g[window]))


def fe_camera_on_sun(sun_grey_sum_grey: float, pixel_solid_angle_sr: float, dni_wm2: float,
                     nd_transmittance: float, board_reflectance: float) -> float:
    """Calibration factor from a frame of the sun, ``F_e = π·τ·DNI / (ρ·Ω_px·Σ G_sun)``.

    Parameters
    ----------
    sun_grey_sum_grey : float
        Σ G over the sun's image (:func:`sun_grey_sum`), same camera settings as the board frames [grey].
    pixel_solid_angle_sr : float
        Solid angle of one pixel, ``1 / (f_x·f_y)`` with focal lengths in pixels [sr].
    dni_wm2 : float
        Direct normal irradiance when the sun frame was taken [W/m²].
    nd_transmittance : float
        Transmittance of the ND filter used for the sun frame, relative to the optics used for
        the board frames (0 < τ <= 1).
    board_reflectance : float
        Hemispherical reflectance ρ of the white board (0 < ρ <= 1).

    Returns
    -------
    float
        F_e [W/m² per grey level].
    """
    for name, value in (("sun_grey_sum_grey", sun_grey_sum_grey), ("pixel_solid_angle_sr", pixel_solid_angle_sr),
                        ("dni_wm2", dni_wm2), ("nd_transmittance", nd_transmittance),
                        ("board_reflectance", board_reflectance)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    if nd_transmittance > 1 or board_reflectance > 1:
        raise ValueError("nd_transmittance and board_reflectance must not exceed 1")
    return math.pi * nd_transmittance * dni_wm2 / (board_reflectance * pixel_solid_angle_sr * sun_grey_sum_grey)


def system_error(components: Mapping[str, float]) -> float:
    """``ε_sys = sqrt(Σ ε_i²)`` of independent component errors (fractions).

    Parameters
    ----------
    components : mapping of str to float
        e.g. ``{"dark": 0.01, "nonlinearity": 0.03, "nonuniformity": 0.006, "non_lambertian": 0.05,
        "calibration": 0.012}``. Every value must be a finite number >= 0.
    """
    total = 0.0
    for name, eps in components.items():
        if not (math.isfinite(eps) and eps >= 0):
            raise ValueError(f"component error {name} must be a number >= 0, got {eps!r}")
        total += float(eps) ** 2
    return math.sqrt(total)
