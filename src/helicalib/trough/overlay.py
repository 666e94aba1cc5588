"""The theoretical overlay: where each facet should show the tube's edges in the camera's image.

Combines the YZ solution (:func:`~helicalib.trough.geometry.tube_edges`), the edges' extent along
the collector (:func:`~helicalib.trough.geometry.edge_x_extent_mm`) and the pinhole projection.
Each edge is a straight line along X on the mirror, so its image is a straight segment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helicalib.trough.camera import PinholeCamera
from helicalib.trough.config import Collector, FacetLayout
from helicalib.trough.geometry import edge_x_extent_mm, tube_edges


@dataclass(frozen=True)
class Overlay:
    """Theoretical tube edges of N facets for one camera (arrays shape (N, ...)).

    Attributes
    ----------
    layout : FacetLayout
    found : ndarray of bool, (N,)
        The facet shows the tube at all (from this camera).
    lower_yz_mm, upper_yz_mm : ndarray, (N, 2)
        Reflection points B (lower edge) and E (upper edge) [mm, YZ].
    lower_x_mm, upper_x_mm : ndarray, (N, 2)
        Visible extent of each edge along X, ``[x_min, x_max]`` [mm]; NaN if none.
    lower_uv_px, upper_uv_px : ndarray, (N, 2, 2)
        Image segments ``[[u0, v0], [u1, v1]]`` of the edges [px], unclipped.
    strip_top_uv_px, strip_bottom_uv_px : ndarray, (N, 2, 2)
        Image segments of the facet's upper and lower boundary lines over the facet length [px].
    visible : ndarray of bool, (N,)
        Both edges found, not clipped by the facet boundary, and their middle inside the frame.
    lower_clipped, upper_clipped : ndarray of bool, (N,)
    """

    layout: FacetLayout
    found: np.ndarray
    lower_yz_mm: np.ndarray
    upper_yz_mm: np.ndarray
    lower_x_mm: np.ndarray
    upper_x_mm: np.ndarray
    lower_uv_px: np.ndarray
    upper_uv_px: np.ndarray
    strip_top_uv_px: np.ndarray
    strip_bottom_uv_px: np.ndarray
    visible: np.ndarray
    lower_clipped: np.ndarray
    upper_clipped: np.ndarray

    def u_range_px(self) -> np.ndarray:
        """Image columns where both edges of each facet are visible, ``[u_min, u_max]``, shape (N, 2) [px]."""
        lu = np.sort(self.lower_uv_px[:, :, 0], axis=1)
        uu = np.sort(self.upper_uv_px[:, :, 0], axis=1)
        return np.stack([np.fmax(lu[:, 0], uu[:, 0]), np.fmin(lu[:, 1], uu[:, 1])], axis=1)


def v_at_u(segment_uv_px, u_px) -> np.ndarray:
    """Image row of segments' supporting lines at columns ``u_px``.

    Parameters
    ----------
    segment_uv_px : array_like, shape (N, 2, 2)
        Segments ``[[u0, v0], [u1, v1]]`` [px].
    u_px : array_like, shape (N,) or (N, K)
        Columns [px].

    Returns
    -------
    ndarray, shape of ``u_px``
    """
    seg = np.asarray(segment_uv_px, dtype=float)
    u = np.asarray(u_px, dtype=float)
    (u0, v0), (u1, v1) = seg[:, 0].T, seg[:, 1].T
    du = np.where(np.abs(u1 - u0) > 1e-12, u1 - u0, 1e-12)
    if u.ndim == 2:
        u0, v0, v1, du = u0[:, None], v0[:, None], v1[:, None], du[:, None]
    return v0 + (v1 - v0) * (u - u0) / du


def _segments(camera: PinholeCamera, x_mm: np.ndarray, yz_mm: np.ndarray) -> np.ndarray:
    ends = np.stack([np.stack([x_mm[:, k], yz_mm[:, 0], yz_mm[:, 1]], axis=-1) for k in (0, 1)], axis=1)
    uv, _ = camera.project(ends)
    return uv


def edges_in_image(collector: Collector, layout: FacetLayout, camera: PinholeCamera, tilt_mrad=0.0,
                   extend_mm: float = 0.0) -> Overlay:
    """Theoretical (or, with ``tilt_mrad``, modelled) tube edges of every facet in the image.

    Parameters
    ----------
    collector : Collector
    layout : FacetLayout
        Facets (from ``collector.facets()``), N of them.
    camera : PinholeCamera
    tilt_mrad : array_like, shape (N,) or scalar
        Facet tilts about +X through each strip's centre [mrad]; 0 gives the theoretical overlay.
    extend_mm : float
        Extend each facet's surface by this much beyond its strip bounds [mm] (used when fitting
        tilts, so an edge keeps a smooth model position even near the facet boundary).

    Returns
    -------
    Overlay
    """
    f, r = collector.focal_length_mm, collector.tube_radius_mm
    pos = np.asarray(camera.position_mm, dtype=float)
    pivot = collector.pivots_yz_mm(layout)
    e = tube_edges(pos[1:], f, r, layout.y_min_mm - extend_mm, layout.y_max_mm + extend_mm, tilt_mrad, pivot)
    tx0, tx1 = collector.tube_x_range_mm
    lx = np.stack(edge_x_extent_mm(pos[0], e.lower_ratio, tx0, tx1, layout.x_min_mm, layout.x_max_mm), axis=1)
    ux = np.stack(edge_x_extent_mm(pos[0], e.upper_ratio, tx0, tx1, layout.x_min_mm, layout.x_max_mm), axis=1)
    lx[~(lx[:, 0] < lx[:, 1])] = np.nan
    ux[~(ux[:, 0] < ux[:, 1])] = np.nan
    lower_uv = _segments(camera, lx, e.lower_yz_mm)
    upper_uv = _segments(camera, ux, e.upper_yz_mm)
    fx = np.stack([layout.x_min_mm, layout.x_max_mm], axis=1)
    top = np.stack([layout.y_max_mm, layout.y_max_mm**2 / (4 * f)], axis=1)
    bottom = np.stack([layout.y_min_mm, layout.y_min_mm**2 / (4 * f)], axis=1)
    mid_l = camera.contains(lower_uv.mean(axis=1))
    mid_u = camera.contains(upper_uv.mean(axis=1))
    visible = e.found & ~e.lower_clipped & ~e.upper_clipped & mid_l & mid_u
    return Overlay(layout=layout, found=e.found, lower_yz_mm=e.lower_yz_mm, upper_yz_mm=e.upper_yz_mm,
                   lower_x_mm=lx, upper_x_mm=ux, lower_uv_px=lower_uv, upper_uv_px=upper_uv,
                   strip_top_uv_px=_segments(camera, fx, top), strip_bottom_uv_px=_segments(camera, fx, bottom),
                   visible=visible, lower_clipped=e.lower_clipped, upper_clipped=e.upper_clipped)
