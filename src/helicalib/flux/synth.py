"""Forward model of a flux camera: a known flux on the board → the raw frame a camera would give.

Used by the tests and benchmarks to check that :func:`helicalib.flux.measure.measure_flux` inverts
it. The model, per pixel i looking at board point (u, v):

    linear grey  s_i = G_dark + g_i · (G_ambient(u, v) + LB · E(u, v) / F_e)
    raw grey     G_i = N(s_i)  (response curve), + Gaussian noise, rounded and clipped to 0..255

with g_i the pixel gain (mean 1), LB the non-Lambertian relative response and N the inverse of
:meth:`ResponseCurve.linearise`. Marks are drawn as a reflectance ``mark_reflectance`` times the
board's in the four L-shapes of ``FIELD_CONFIG.md``; the area outside the board shows
``outside_grey``. Lens distortion is applied when ``distortion`` is given.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from helicalib.flux.corrections import ResponseCurve

__all__ = ["apply_response", "homography_uv_to_px", "mark_mask", "render_frame"]


def homography_uv_to_px(center_enu_m, frame_enu, camera_enu_m, camera_matrix, look_at_enu_m=None) -> np.ndarray:
    """Homography board (u, v) [m] → image px of a pinhole camera looking at ``look_at_enu_m``.

    The camera looks from ``camera_enu_m`` at the board centre (default), image x to the right
    (horizontal), image y down. ``frame_enu`` has rows u, v, w (``Target.frame_enu``).

    Returns
    -------
    np.ndarray, shape (3, 3)
        ``px ~ H · (u, v, 1)``; its inverse is the px → (u, v) homography of the marks.
    """
    c = np.asarray(center_enu_m, dtype=float)
    cam = np.asarray(camera_enu_m, dtype=float)
    target = c if look_at_enu_m is None else np.asarray(look_at_enu_m, dtype=float)
    z = target - cam
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z])
    f = np.asarray(frame_enu, dtype=float)
    m = np.stack([f[0], f[1], c - cam], axis=1)
    h = np.asarray(camera_matrix, dtype=float) @ rot @ m
    return h / h[2, 2]


def apply_response(curve: ResponseCurve, linear_grey: np.ndarray) -> np.ndarray:
    """The camera's non-linear response N: linear grey → raw grey (inverse of ``curve.linearise``)."""
    lin_pts = curve.k0_grey + curve.k1_grey_per_input * curve.input
    return np.interp(np.asarray(linear_grey, dtype=float), lin_pts, curve.grey)


def mark_mask(u_m: np.ndarray, v_m: np.ndarray, vertices_m, arm_m: float, thickness_m: float) -> np.ndarray:
    """True where (u, v) lies on one of the four L-shaped marks (arms run from the vertex inward)."""
    on = np.zeros(np.shape(u_m), dtype=bool)
    for vu, vv in vertices_m:
        su, sv = -np.sign(vu) or 1.0, -np.sign(vv) or 1.0  # direction toward the board centre
        du, dv = (u_m - vu) * su, (v_m - vv) * sv
        arm_u = (du >= 0) & (du <= arm_m) & (dv >= 0) & (dv <= thickness_m)
        arm_v = (dv >= 0) & (dv <= arm_m) & (du >= 0) & (du <= thickness_m)
        on |= arm_u | arm_v
    return on


def render_frame(shape_px: tuple[int, int], h_uv_to_px: np.ndarray, size_m: tuple[float, float],
                 flux_wm2: Callable[[np.ndarray, np.ndarray], np.ndarray] | None, fe_wm2_per_grey: float, *,
                 ambient_grey: float = 40.0, outside_grey: float = 10.0, dark_grey: float = 0.0,
                 gain: np.ndarray | None = None,
                 response: ResponseCurve | Callable[[np.ndarray], np.ndarray] | None = None,
                 relative_lb: float = 1.0, noise_grey: float = 0.0, marks: dict | None = None,
                 mark_reflectance: float = 0.08, camera_matrix: np.ndarray | None = None,
                 distortion: np.ndarray | None = None, rng: np.random.Generator | None = None) -> np.ndarray:
    """Render an 8-bit frame of the board under a known flux.

    Parameters
    ----------
    shape_px : (int, int)
        (height, width) of the frame.
    h_uv_to_px : np.ndarray, shape (3, 3)
        Board (u, v) [m] → undistorted image px.
    size_m : (float, float)
        Board width and height [m].
    flux_wm2 : callable (u, v) → E [W/m²], or None for no beam
    fe_wm2_per_grey : float
        True F_e of the camera [W/m² per grey level].
    ambient_grey, outside_grey, dark_grey : float
        Board under ambient light, background, dark output [linear grey].
    gain : np.ndarray, shape (height, width), optional
        Pixel gains (non-uniformity).
    response : ResponseCurve or callable (linear grey → raw grey), optional
        Non-linear response applied last.
    relative_lb : float
        Non-Lambertian relative response LB of the beam as seen by this camera.
    noise_grey : float
        Standard deviation of additive Gaussian noise [grey].
    marks : dict, optional
        ``{"vertices_m": ..., "arm_m": ..., "thickness_m": ...}`` to draw.
    camera_matrix, distortion : optional
        Lens distortion to apply (OpenCV model).
    rng : np.random.Generator, optional
    """
    hgt, wid = shape_px
    yy, xx = np.indices((hgt, wid), dtype=float)
    if camera_matrix is not None and distortion is not None and np.any(np.asarray(distortion) != 0):
        pts = np.stack([xx.ravel(), yy.ravel()], axis=1).reshape(-1, 1, 2)
        und = cv2.undistortPoints(pts, np.asarray(camera_matrix, float), np.asarray(distortion, float),
                                  P=np.asarray(camera_matrix, float)).reshape(-1, 2)
        xx, yy = und[:, 0].reshape(hgt, wid), und[:, 1].reshape(hgt, wid)
    inv = np.linalg.inv(np.asarray(h_uv_to_px, dtype=float))
    w = inv[2, 0] * xx + inv[2, 1] * yy + inv[2, 2]
    u = (inv[0, 0] * xx + inv[0, 1] * yy + inv[0, 2]) / w
    v = (inv[1, 0] * xx + inv[1, 1] * yy + inv[1, 2]) / w
    on_board = (np.abs(u) <= size_m[0] / 2) & (np.abs(v) <= size_m[1] / 2)
    refl = np.ones_like(u)
    if marks is not None:
        refl = np.where(mark_mask(u, v, marks["vertices_m"], marks["arm_m"], marks["thickness_m"]), mark_reflectance, 1.0)
    beam = np.zeros_like(u) if flux_wm2 is None else relative_lb * np.asarray(flux_wm2(u, v), dtype=float) / fe_wm2_per_grey
    signal = np.where(on_board, refl * (ambient_grey + beam), outside_grey)
    if gain is not None:
        signal = signal * gain
    linear = dark_grey + signal
    if response is None:
        raw = linear
    elif isinstance(response, ResponseCurve):
        raw = apply_response(response, linear)
    else:
        raw = np.asarray(response(linear), dtype=float)
    if noise_grey > 0:
        raw = raw + (rng or np.random.default_rng(0)).normal(0.0, noise_grey, raw.shape)
    return np.clip(np.rint(raw), 0, 255).astype(np.uint8)
