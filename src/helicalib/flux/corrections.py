"""Camera corrections that turn a raw frame into grey levels proportional to flux (Zhang & Wang).

The seed paper (``004``, section 3) lists six corrections; each is a pure function here and each is
optional:

* dark output (eq. 3): ``G_dark = mean(G_i)`` of a frame taken with the lens capped;
* non-linearity (eq. 4, ``I = K0 + K1·B``): a measured response curve (input irradiance ``B``,
  grey ``G``) maps a raw grey level onto the straight line ``K0 + K1·B`` fitted to the curve's
  linear (low-signal) part;
* pixel non-uniformity (eqs. 5, 6): ``a_NU,i = G_mean / G_i`` from a uniform (integrating-sphere)
  frame, ``ε_NU = std(G_i) / G_mean``;
* lens distortion: grid points are pushed through the camera's OpenCV distortion model, so the
  raw frame is sampled once (no second interpolation);
* perspective: the board is resampled onto a metric grid (:mod:`helicalib.flux.grid`) through the
  homography image px → target (u, v) m of the board marks, by bilinear interpolation (ref. 11);
  a Lambertian board's radiance does not depend on the viewing direction, so a sampled grey level
  is already proportional to the local flux and needs no area (Jacobian) factor;
* non-Lambertian board (eq. 7): ``LB_j = E_j / E_0`` measured against the angle between the
  light and the board normal; the correction factor is ``a_LB = 1 / LB``.

Equation (9) of the paper then gives the flux, ``E_i = (G_i − G_dark)·a_NL·a_NU·a_LB·F_e``
(:func:`helicalib.flux.fluxmap.flux_map`). All functions take and return arrays; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from helicalib.flux.grid import BoardGrid

__all__ = [
    "ResponseCurve",
    "correct_frame",
    "flat_field_factors",
    "incidence_angle_deg",
    "mean_dark_grey",
    "nonuniformity_error",
    "rectify_to_grid",
    "relative_response",
    "response_curve",
    "view_angles_deg",
]


# ----------------------------------------------------------------------------- dark output
def mean_dark_grey(dark_frame: np.ndarray) -> float:
    """Mean dark output ``G_dark = Σ G_i / N_total`` of a capped-lens frame (paper eq. 3) [grey].

    Parameters
    ----------
    dark_frame : np.ndarray, shape (H, W)
        Raw grey levels of a frame taken in the dark (lens capped, camera warmed up).
    """
    dark = np.asarray(dark_frame, dtype=float)
    if dark.size == 0:
        raise ValueError("empty dark frame")
    return float(dark.mean())


# ----------------------------------------------------------------------------- non-linearity
@dataclass(frozen=True)
class ResponseCurve:
    """A measured camera response, raw grey ``grey`` against input irradiance ``input``.

    Attributes
    ----------
    input : np.ndarray, shape (n,)
        Relative input irradiance B (any unit), strictly increasing.
    grey : np.ndarray, shape (n,)
        Mean raw grey level at each input, strictly increasing.
    k0_grey, k1_grey_per_input : float
        The straight line ``K0 + K1·B`` (eq. 4) fitted to the points with ``grey <= linear_up_to_grey``.
    linear_up_to_grey : float
        Upper end of the part of the curve taken as linear [grey].
    """

    input: np.ndarray
    grey: np.ndarray
    k0_grey: float
    k1_grey_per_input: float
    linear_up_to_grey: float

    def linearise(self, grey: np.ndarray) -> np.ndarray:
        """Raw grey → the grey an ideal linear camera would give, ``K0 + K1·B(G)``.

        ``B(G)`` is the curve inverted by linear interpolation; beyond its ends the first and last
        segments are extended. Shape is preserved; the result is float.
        """
        g = np.asarray(grey, dtype=float)
        b = np.interp(g, self.grey, self.input)
        lo, hi = g < self.grey[0], g > self.grey[-1]
        if lo.any():
            s = (self.input[1] - self.input[0]) / (self.grey[1] - self.grey[0])
            b = np.where(lo, self.input[0] + (g - self.grey[0]) * s, b)
        if hi.any():
            s = (self.input[-1] - self.input[-2]) / (self.grey[-1] - self.grey[-2])
            b = np.where(hi, self.input[-1] + (g - self.grey[-1]) * s, b)
        return self.k0_grey + self.k1_grey_per_input * b

    def factor(self, grey: np.ndarray) -> np.ndarray:
        """The non-linearity factor ``a_NL = linearise(G) / G`` of eq. (9) (1 where G = 0)."""
        g = np.asarray(grey, dtype=float)
        lin = self.linearise(g)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(g != 0, lin / np.where(g != 0, g, 1.0), 1.0)


def response_curve(input_rel: np.ndarray, grey: np.ndarray, linear_up_to_grey: float | None = None) -> ResponseCurve:
    """Build a :class:`ResponseCurve` from measured points (integrating sphere, paper section 3.4).

    Parameters
    ----------
    input_rel : array_like, shape (n,)
        Relative input irradiance of each measurement, strictly increasing, n >= 2.
    grey : array_like, shape (n,)
        Mean raw grey level of each measurement, strictly increasing.
    linear_up_to_grey : float, optional
        Points with ``grey`` at or below this are fitted by ``K0 + K1·B`` (least squares). Default:
        the lower half of the curve's grey span. At least two points must qualify.
    """
    b = np.asarray(input_rel, dtype=float).ravel()
    g = np.asarray(grey, dtype=float).ravel()
    if b.size != g.size or b.size < 2:
        raise ValueError("a response curve needs at least two (input, grey) points of equal count")
    if not (np.all(np.diff(b) > 0) and np.all(np.diff(g) > 0)):
        raise ValueError("response curve input and grey must both be strictly increasing")
    limit = float(g[0] + 0.5 * (g[-1] - g[0])) if linear_up_to_grey is None else float(linear_up_to_grey)
    sel = g <= limit + 1e-9
    if sel.sum() < 2:
        raise ValueError(f"fewer than two response points at or below linear_up_to_grey = {limit:g}")
    k1, k0 = np.polyfit(b[sel], g[sel], 1)
    if k1 <= 0:
        raise ValueError("the linear part of the response curve does not rise")
    return ResponseCurve(input=b, grey=g, k0_grey=float(k0), k1_grey_per_input=float(k1), linear_up_to_grey=limit)


# ----------------------------------------------------------------------------- non-uniformity
def flat_field_factors(flat_grey: np.ndarray) -> np.ndarray:
    """Per-pixel non-uniformity factors ``a_NU,i = G_mean / G_i`` (paper eq. 6).

    Parameters
    ----------
    flat_grey : np.ndarray, shape (H, W)
        A uniform frame (integrating sphere), already dark-subtracted and linearised.

    Returns
    -------
    np.ndarray, shape (H, W)
        Factors to multiply a frame by; pixels with no signal (G_i <= 0) get NaN.
    """
    flat = np.asarray(flat_grey, dtype=float)
    mean = float(flat[flat > 0].mean()) if (flat > 0).any() else 0.0
    if mean <= 0:
        raise ValueError("flat-field frame has no signal")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(flat > 0, mean / np.where(flat > 0, flat, 1.0), np.nan)


def nonuniformity_error(flat_grey: np.ndarray) -> float:
    """Non-uniformity error ``ε_NU = sqrt(mean((G_i − G_mean)²)) / G_mean`` of a uniform frame (eq. 5)."""
    flat = np.asarray(flat_grey, dtype=float)
    mean = float(flat.mean())
    if mean <= 0:
        raise ValueError("flat-field frame has no signal")
    return float(np.sqrt(np.mean((flat - mean) ** 2)) / mean)


def correct_frame(raw: np.ndarray, *, dark_grey: float | None = None, response: ResponseCurve | None = None,
                  flat_factors: np.ndarray | None = None) -> np.ndarray:
    """Raw frame → grey levels proportional to radiance, in image pixels.

    Order: linearise the raw signal (the non-linearity acts on what the sensor collects, dark
    current included), subtract the (linearised) mean dark output, multiply by the flat-field
    factors. Each step is skipped when its argument is None.

    Parameters
    ----------
    raw : np.ndarray, shape (H, W)
        Raw grey levels.
    dark_grey : float, optional
        Mean dark output ``G_dark`` [raw grey].
    response : ResponseCurve, optional
    flat_factors : np.ndarray, shape (H, W), optional
        ``a_NU`` from :func:`flat_field_factors`; must match the frame's shape.

    Returns
    -------
    np.ndarray, shape (H, W), float
    """
    g = np.asarray(raw, dtype=float)
    if response is not None:
        g = response.linearise(g)
    if dark_grey is not None:
        g = g - (float(response.linearise(np.array(dark_grey))) if response is not None else float(dark_grey))
    if flat_factors is not None:
        if flat_factors.shape != g.shape:
            raise ValueError(f"flat-field frame is {flat_factors.shape[1]}x{flat_factors.shape[0]} px, "
                             f"the frame {g.shape[1]}x{g.shape[0]} px")
        g = g * flat_factors
    return g


# ----------------------------------------------------------------------------- geometry
def rectify_to_grid(image: np.ndarray, homography_px_to_uv: np.ndarray, grid: BoardGrid, *,
                    camera_matrix: np.ndarray | None = None, distortion: np.ndarray | None = None) -> np.ndarray:
    """Resample a frame onto the board grid (perspective and, optionally, lens distortion).

    Each grid cell centre (u, v) is mapped to the image by the inverse homography; when a camera
    matrix and distortion coefficients are given, the homography is taken as that of the
    *undistorted* image and the point is then pushed through the distortion model, so the raw
    frame is sampled directly. Sampling is bilinear.

    Parameters
    ----------
    image : np.ndarray, shape (H, W)
        Corrected grey levels in image pixels.
    homography_px_to_uv : np.ndarray, shape (3, 3)
        Image pixel → target-frame (u, v) [m] homography (as from ``vision.marks.find_marks``).
    grid : BoardGrid
    camera_matrix : np.ndarray, shape (3, 3), optional
    distortion : array_like, shape (4,), (5,) or (8,), optional
        OpenCV coefficients k1 k2 p1 p2 [k3 ...].

    Returns
    -------
    np.ndarray, shape grid.shape
        Grey levels on the grid; NaN where a cell centre falls outside the frame.
    """
    img = np.asarray(image, dtype=np.float32)
    h_img, w_img = img.shape
    uu, vv = grid.mesh_m()
    pts = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])
    px = np.linalg.inv(np.asarray(homography_px_to_uv, dtype=float)) @ pts
    x, y = px[0] / px[2], px[1] / px[2]
    if camera_matrix is not None and distortion is not None and np.any(np.asarray(distortion) != 0):
        k = np.asarray(camera_matrix, dtype=float)
        norm = np.linalg.inv(k) @ np.stack([x, y, np.ones_like(x)])
        obj = np.stack([norm[0] / norm[2], norm[1] / norm[2], np.ones_like(x)], axis=1)
        proj, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k,
                                    np.asarray(distortion, dtype=float))
        x, y = proj[:, 0, 0], proj[:, 0, 1]
    map_x = x.reshape(grid.shape).astype(np.float32)
    map_y = y.reshape(grid.shape).astype(np.float32)
    out = cv2.remap(img, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    outside = (map_x < 0) | (map_x > w_img - 1) | (map_y < 0) | (map_y > h_img - 1)
    out = out.astype(float)
    out[outside] = np.nan
    return out


def relative_response(angle_deg: np.ndarray, table_angle_deg: np.ndarray, table_relative: np.ndarray) -> np.ndarray:
    """Non-Lambertian relative response ``LB = E_j / E_0`` at ``angle_deg`` (paper eq. 7).

    Linear interpolation in a measured table; held constant beyond its ends. The correction factor
    of eq. (9) is ``a_LB = 1 / LB``.
    """
    a = np.asarray(table_angle_deg, dtype=float)
    r = np.asarray(table_relative, dtype=float)
    return np.interp(np.abs(np.asarray(angle_deg, dtype=float)), a, r)


def incidence_angle_deg(normal_enu: np.ndarray, point_enu_m: np.ndarray, source_enu_m: np.ndarray) -> np.ndarray:
    """Angle between the board normal and the direction from a board point to a source [deg].

    Parameters
    ----------
    normal_enu : array_like, shape (3,)
        Board normal (toward the field), unit [ENU].
    point_enu_m : array_like, shape (..., 3)
        Points on the board [m, ENU].
    source_enu_m : array_like, shape (3,)
        The heliostat (incidence) or camera (viewing) position [m, ENU].
    """
    d = np.asarray(source_enu_m, dtype=float) - np.asarray(point_enu_m, dtype=float)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    c = np.clip(d @ np.asarray(normal_enu, dtype=float), -1.0, 1.0)
    return np.degrees(np.arccos(c))


def view_angles_deg(grid: BoardGrid, center_enu_m: np.ndarray, frame_enu: np.ndarray,
                    camera_enu_m: np.ndarray) -> np.ndarray:
    """Viewing angle of the camera at every grid cell [deg], shape grid.shape.

    ``frame_enu`` is ``Target.frame_enu`` (rows u, v, w); w is the board normal.
    """
    uu, vv = grid.mesh_m()
    f = np.asarray(frame_enu, dtype=float)
    pts = np.asarray(center_enu_m, dtype=float) + uu[..., None] * f[0] + vv[..., None] * f[1]
    return incidence_angle_deg(f[2], pts, camera_enu_m)
