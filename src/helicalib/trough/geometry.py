"""Where the receiver tube appears in each facet of a parabolic trough (Ren et al. 2014, eqs 1–10).

Frame ``O-XYZ`` of the paper: origin at the parabola vertex, ``Z`` the optical axis (towards the
focal line), ``Y`` across the aperture (up when the aperture faces the horizon), ``X`` along the
collector; all lengths in mm. The mirror is ``z = y**2 / (4 f)`` and the tube a cylinder of radius
``r`` about the focal line ``(y, z) = (0, f)``.

Because the mirror normal has no ``X`` component and the tube is parallel to ``X``, the 3-D problem
separates: a camera ray reflected at a mirror point grazes the tube exactly when its projection
on the ``YZ`` plane does. For each facet strip we therefore solve, in ``YZ``, for the mirror
heights whose reflected ray lies at distance ``r`` from the focal line: the lower edge ``B`` and
the upper edge ``E`` of the paper. A facet may be tilted about a line parallel to ``X`` through its
pivot; the same solver then gives the edges of the tilted facet (used to estimate tilts).

Instead of the paper's closed chain (1)–(10), which needs one root of (4) discarded per edge, the
edges are found as the boundaries of the set ``{y : |miss(y)| < r}`` on a dense grid of each strip,
refined by vectorised bisection: robust (always bracketed) and vectorised over strips.
:mod:`helicalib.trough.paper` keeps the paper's own equations for cross-checking.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRID_SAMPLES = 512
"""Samples per strip for bracketing the edges (strip height / 511 ≈ 3 mm for the paper's unit)."""
BISECTION_STEPS = 50
"""Bisection halvings after bracketing: the bracket shrinks below 1e-12 mm."""


def _rotate_yz(vec_yz: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rotate ``(..., 2)`` YZ vectors about +X by ``angle_rad`` (right hand: +Y turns towards +Z)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    y, z = vec_yz[..., 0], vec_yz[..., 1]
    return np.stack([c * y - s * z, s * y + c * z], axis=-1)


def facet_surface_yz(y_local_mm, focal_length_mm: float, tilt_mrad=0.0, pivot_yz_mm=(0.0, 0.0)):
    """Points and unit normals of a (tilted) facet's cross-section in the collector frame.

    Parameters
    ----------
    y_local_mm : array_like, shape (...)
        Height on the untilted parabola [mm] (the facet's own coordinate).
    focal_length_mm : float
        Focal length ``f`` [mm].
    tilt_mrad : array_like, broadcastable to ``y_local_mm``
        Rotation of the facet about a line parallel to +X through ``pivot_yz_mm`` [mrad, right hand].
    pivot_yz_mm : array_like, shape (..., 2)
        Pivot of the tilt [mm, YZ].

    Returns
    -------
    point_yz_mm, normal_yz : ndarray, shape (..., 2)
        Mirror points [mm] and unit normals (pointing to the reflecting side, +Z at the vertex).
    """
    y = np.asarray(y_local_mm, dtype=float)
    pivot = np.asarray(pivot_yz_mm, dtype=float)
    angle = np.asarray(tilt_mrad, dtype=float) * 1e-3
    local = np.stack([y, y * y / (4.0 * focal_length_mm)], axis=-1)
    normal = np.stack([-y / (2.0 * focal_length_mm), np.ones_like(y)], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    point = _rotate_yz(local - pivot, angle) + pivot
    return point, _rotate_yz(normal, angle)


def reflected_miss_mm(y_local_mm, camera_yz_mm, focal_length_mm: float, tilt_mrad=0.0, pivot_yz_mm=(0.0, 0.0)):
    """Signed distance of the focal line from the camera ray reflected at mirror height ``y``.

    Parameters
    ----------
    y_local_mm : array_like, shape (...)
        Facet coordinate of the reflection point [mm].
    camera_yz_mm : array_like, shape (2,)
        Camera principal point ``P`` projected on the YZ plane [mm].
    focal_length_mm, tilt_mrad, pivot_yz_mm
        As in :func:`facet_surface_yz`.

    Returns
    -------
    miss_mm : ndarray, shape (...)
        Signed distance from the focal line to the reflected ray [mm]; positive when the focal line
        lies to the left of the ray (seen with +X towards the viewer). The ray grazes the tube at
        ``|miss_mm| == r``.
    ahead_mm : ndarray, shape (...)
        Distance along the reflected ray (YZ) from the mirror to the closest approach [mm];
        negative when the tube lies behind the mirror point.
    ratio : ndarray, shape (...)
        ``ahead_mm / |PQ|`` (YZ path after / before reflection): how far the ray advances along X.
    point_yz_mm : ndarray, shape (..., 2)
        The reflection point [mm].
    """
    point, normal = facet_surface_yz(y_local_mm, focal_length_mm, tilt_mrad, pivot_yz_mm)
    incoming = point - np.asarray(camera_yz_mm, dtype=float)
    path_in = np.linalg.norm(incoming, axis=-1)
    incoming = incoming / path_in[..., None]
    out = incoming - 2.0 * np.sum(incoming * normal, axis=-1, keepdims=True) * normal
    to_focus = np.array([0.0, focal_length_mm]) - point
    miss = out[..., 0] * to_focus[..., 1] - out[..., 1] * to_focus[..., 0]
    ahead = np.sum(out * to_focus, axis=-1)
    return miss, ahead, ahead / path_in, point


@dataclass(frozen=True)
class TubeEdges:
    """Edges of the tube's reflection in N facet strips (all arrays shape (N,), lengths in mm).

    ``lower`` is the paper's B (smaller Y, lower in the photo), ``upper`` its E. Where a strip shows
    no tube, ``found`` is False and the edge fields are NaN. An edge that coincides with a strip
    boundary (the tube's image runs off the facet) is flagged ``*_clipped``.
    """

    found: np.ndarray
    lower_y_local_mm: np.ndarray
    upper_y_local_mm: np.ndarray
    lower_yz_mm: np.ndarray  # (N, 2)
    upper_yz_mm: np.ndarray  # (N, 2)
    lower_ratio: np.ndarray
    upper_ratio: np.ndarray
    lower_clipped: np.ndarray
    upper_clipped: np.ndarray
    multiple_bands: np.ndarray


def tube_edges(camera_yz_mm, focal_length_mm: float, tube_radius_mm: float, y_min_mm, y_max_mm,
               tilt_mrad=0.0, pivot_yz_mm=None, samples: int = GRID_SAMPLES) -> TubeEdges:
    """Solve for B and E (eqs 1–10) in every facet strip at once.

    Parameters
    ----------
    camera_yz_mm : array_like, shape (2,)
        Camera principal point ``(y_p, z_p)`` [mm].
    focal_length_mm, tube_radius_mm : float
        ``f`` and ``r`` [mm].
    y_min_mm, y_max_mm : array_like, shape (N,)
        Strip bounds in facet coordinates [mm].
    tilt_mrad : array_like, shape (N,) or scalar
        Facet tilts about +X [mrad].
    pivot_yz_mm : array_like, shape (N, 2), optional
        Tilt pivots [mm]; default the strip centre on the parabola.
    samples : int
        Grid samples per strip used to bracket the edges.

    Returns
    -------
    TubeEdges
    """
    y0 = np.atleast_1d(np.asarray(y_min_mm, dtype=float))
    y1 = np.atleast_1d(np.asarray(y_max_mm, dtype=float))
    n = y0.shape[0]
    tilt = np.broadcast_to(np.asarray(tilt_mrad, dtype=float), (n,))
    if pivot_yz_mm is None:
        yc = 0.5 * (y0 + y1)
        pivot = np.stack([yc, yc * yc / (4.0 * focal_length_mm)], axis=-1)
    else:
        pivot = np.broadcast_to(np.asarray(pivot_yz_mm, dtype=float), (n, 2))
    r = float(tube_radius_mm)

    def gap(y, k=slice(None)):
        """|miss| - r, with rays leaving away from the tube counted as misses (> 0)."""
        miss, ahead, _, _ = reflected_miss_mm(y, camera_yz_mm, focal_length_mm, tilt[k, None], pivot[k, None, :])
        return np.where(ahead > 0.0, np.abs(miss) - r, np.abs(miss) + r)

    t = np.linspace(0.0, 1.0, samples)
    grid = y0[:, None] + (y1 - y0)[:, None] * t[None, :]
    inside = gap(grid) < 0.0
    found = inside.any(axis=1)
    first = np.argmax(inside, axis=1)
    last = samples - 1 - np.argmax(inside[:, ::-1], axis=1)
    runs = np.sum(np.diff(inside.astype(np.int8), axis=1) == 1, axis=1) + inside[:, 0]
    lower_clipped = found & (first == 0)
    upper_clipped = found & (last == samples - 1)

    def refine(outside_idx, inside_idx):
        lo = np.take_along_axis(grid, outside_idx[:, None], axis=1)[:, 0]  # gap > 0 here
        hi = np.take_along_axis(grid, inside_idx[:, None], axis=1)[:, 0]  # gap < 0 here
        for _ in range(BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            g = gap(mid[:, None])[:, 0]
            lo, hi = np.where(g > 0.0, mid, lo), np.where(g > 0.0, hi, mid)
        return 0.5 * (lo + hi)

    lower = refine(np.maximum(first - 1, 0), first)
    upper = refine(np.minimum(last + 1, samples - 1), last)
    lower = np.where(lower_clipped, y0, lower)
    upper = np.where(upper_clipped, y1, upper)
    lower = np.where(found, lower, np.nan)
    upper = np.where(found, upper, np.nan)
    safe_l, safe_u = np.where(found, lower, y0), np.where(found, upper, y1)
    _, _, ratio_l, pt_l = reflected_miss_mm(safe_l, camera_yz_mm, focal_length_mm, tilt, pivot)
    _, _, ratio_u, pt_u = reflected_miss_mm(safe_u, camera_yz_mm, focal_length_mm, tilt, pivot)
    nan2 = np.where(found[:, None], 0.0, np.nan)
    return TubeEdges(found=found, lower_y_local_mm=lower, upper_y_local_mm=upper,
                     lower_yz_mm=pt_l + nan2, upper_yz_mm=pt_u + nan2,
                     lower_ratio=np.where(found, ratio_l, np.nan), upper_ratio=np.where(found, ratio_u, np.nan),
                     lower_clipped=lower_clipped, upper_clipped=upper_clipped, multiple_bands=runs > 1)


def edge_x_extent_mm(camera_x_mm: float, ratio, tube_x_min_mm: float, tube_x_max_mm: float,
                     facet_x_min_mm, facet_x_max_mm):
    """Extent along X of an edge line in a facet: where the grazing ray meets the finite tube.

    A ray from ``P`` to the mirror point ``Q`` keeps its X advance per unit of YZ path after
    reflection, so it reaches the tube at ``x_A = x_Q + ratio (x_Q - x_P)``; requiring
    ``x_A`` inside the tube gives ``x_Q`` in ``[(x_t0 + ratio x_P)/(1+ratio), (x_t1 + ratio x_P)/(1+ratio)]``.

    Parameters
    ----------
    camera_x_mm : float
        ``x_P`` [mm].
    ratio : array_like, shape (N,)
        YZ path ratio after/before reflection (from :class:`TubeEdges`).
    tube_x_min_mm, tube_x_max_mm : float
        Tube ends [mm].
    facet_x_min_mm, facet_x_max_mm : array_like, shape (N,)
        Facet ends [mm].

    Returns
    -------
    x_min_mm, x_max_mm : ndarray, shape (N,)
        The visible part of the edge; ``x_min_mm > x_max_mm`` when none is.
    """
    k = np.asarray(ratio, dtype=float)
    lo = (tube_x_min_mm + k * camera_x_mm) / (1.0 + k)
    hi = (tube_x_max_mm + k * camera_x_mm) / (1.0 + k)
    return np.maximum(lo, facet_x_min_mm), np.minimum(hi, facet_x_max_mm)
