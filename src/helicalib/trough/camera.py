"""Pinhole camera in the collector frame: projection of points and back-projection of pixels.

Nominal attitude (the paper's calibrated cameras): the optical axis looks along -Z at the
collector, image ``u`` (right) runs along +X and image ``v`` (down) along -Y. Small residual
attitude angles ``rotation_deg = (rx, ry, rz)`` rotate the camera about the collector's X, then Y,
then Z axes (``R = Rz Ry Rx R_nominal``). Pixel ``(u, v)`` is the centre of column ``u``, row ``v``
(pixel ``(0, 0)`` covers ``[-0.5, 0.5]^2``). No lens distortion: the paper used a low-distortion lens;
undistort real photos first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_NOMINAL = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # columns: camera x, y, z in O-XYZ


def _rot(axis: int, angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera at principal point ``position_mm`` (collector frame, mm).

    Attributes
    ----------
    position_mm : ndarray, shape (3,)
        Principal point ``P`` [mm, O-XYZ].
    focal_length_px : float
        Focal length in pixels [px].
    principal_point_px : tuple of float
        ``(c_u, c_v)`` [px].
    image_size_px : tuple of int
        ``(width, height)`` [px].
    rotation_deg : tuple of float
        Residual attitude about X, Y, Z [deg].
    """

    position_mm: np.ndarray
    focal_length_px: float
    principal_point_px: tuple[float, float]
    image_size_px: tuple[int, int]
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def world_from_camera(self) -> np.ndarray:
        """Rotation whose columns are the camera x (right), y (down), z (forward) axes in O-XYZ, (3, 3)."""
        rx, ry, rz = np.radians(self.rotation_deg)
        return _rot(2, rz) @ _rot(1, ry) @ _rot(0, rx) @ _NOMINAL

    def project(self, points_mm) -> tuple[np.ndarray, np.ndarray]:
        """Image positions of collector-frame points.

        Parameters
        ----------
        points_mm : array_like, shape (..., 3)
            Points [mm, O-XYZ].

        Returns
        -------
        uv_px : ndarray, shape (..., 2)
            Image positions [px]; NaN for points behind the camera.
        depth_mm : ndarray, shape (...)
            Distance along the optical axis [mm].
        """
        rel = np.asarray(points_mm, dtype=float) - np.asarray(self.position_mm, dtype=float)
        cam = rel @ self.world_from_camera  # (..., 3) in camera axes
        depth = cam[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.principal_point_px[0] + self.focal_length_px * cam[..., 0] / depth
            v = self.principal_point_px[1] + self.focal_length_px * cam[..., 1] / depth
        uv = np.stack([u, v], axis=-1)
        uv[depth <= 0] = np.nan
        return uv, depth

    def rays(self, u_px, v_px) -> np.ndarray:
        """Unit directions of the rays through image positions.

        Parameters
        ----------
        u_px, v_px : array_like, shape (...)
            Image positions [px].

        Returns
        -------
        ndarray, shape (..., 3)
            Unit ray directions [O-XYZ].
        """
        u = np.asarray(u_px, dtype=float)
        v = np.asarray(v_px, dtype=float)
        cam = np.stack([(u - self.principal_point_px[0]) / self.focal_length_px,
                        (v - self.principal_point_px[1]) / self.focal_length_px, np.ones(np.broadcast(u, v).shape)], axis=-1)
        world = cam @ self.world_from_camera.T
        return world / np.linalg.norm(world, axis=-1, keepdims=True)

    def contains(self, uv_px, margin_px: float = 0.0) -> np.ndarray:
        """Whether image positions lie inside the frame (at least ``margin_px`` from its border)."""
        uv = np.asarray(uv_px, dtype=float)
        w, h = self.image_size_px
        with np.errstate(invalid="ignore"):
            return ((uv[..., 0] >= -0.5 + margin_px) & (uv[..., 0] <= w - 0.5 - margin_px)
                    & (uv[..., 1] >= -0.5 + margin_px) & (uv[..., 1] <= h - 0.5 - margin_px))
