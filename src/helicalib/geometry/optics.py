"""Heliostat optics: reflection, the aim normal, target-plane intersection, tracking error.

Conventions (``FIELD_CONFIG.md``, "Optics"): the sun vector ``s`` points from the heliostat to the
sun; the reflected direction is ``r = 2 (s·n) n − s``; reflected rays leave the mirror centre
``M = P + mirror_offset_m · n``; the normal that puts the beam on the aim point T solves the fixed
point ``n = unit(s + unit(T − M(n)))``. All functions broadcast over leading dimensions ``(...)``.

:func:`aim_normal` on (3,) or (K, 3) rows runs the compiled kernel of
:mod:`helicalib.geometry.kernels` (``reference=True``, or other shapes: the numpy code, the
reference it is tested against).
"""

from __future__ import annotations

import numpy as np

from helicalib.geometry.drives import kernel_rows, kernels, use_kernels

AIM_ITERATIONS = 6
"""Fixed-point steps of :func:`aim_normal`; each shrinks the error by ≈ offset / (2·|T − P|) (~1e-3)."""


def unit(v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) scaled to length 1."""
    v = np.asarray(v, dtype=float)
    return v / np.sqrt(np.add.reduce(v * v, axis=-1, keepdims=True))  # np.linalg.norm's own sum, its wrapper left out


def reflect(sun_enu: np.ndarray, normal_enu: np.ndarray) -> np.ndarray:
    """Reflected beam direction ``r = 2 (s·n) n − s``, shape (..., 3), ENU (unit if s and n are)."""
    s = np.asarray(sun_enu, dtype=float)
    n = np.asarray(normal_enu, dtype=float)
    return 2.0 * np.add.reduce(s * n, axis=-1, keepdims=True) * n - s


def mirror_centre(pivot_enu: np.ndarray, normal_enu: np.ndarray, mirror_offset_m) -> np.ndarray:
    """Mirror centre ``M = P + mirror_offset_m · n`` (..., 3) [m, ENU]."""
    off = np.asarray(mirror_offset_m, dtype=float)[..., None]
    return np.asarray(pivot_enu, dtype=float) + off * np.asarray(normal_enu, dtype=float)


def aim_normal(pivot_enu: np.ndarray, sun_enu: np.ndarray, aim_enu: np.ndarray, mirror_offset_m,
               iterations: int = AIM_ITERATIONS, reference: bool = False) -> np.ndarray:
    """Mirror normal (..., 3) that reflects the sun from the mirror centre onto the aim point.

    Parameters
    ----------
    pivot_enu : (..., 3) [m]
    sun_enu : (..., 3) unit vector toward the sun
    aim_enu : (..., 3) [m] aim point T
    mirror_offset_m : (...) [m]
    iterations : fixed-point steps of ``n = unit(s + unit(T − M(n)))``, starting from the
        pivot-based bisector.
    reference : the numpy code, never the compiled kernel.
    """
    if not reference:
        n = _aim_normal_kernel(pivot_enu, sun_enu, aim_enu, mirror_offset_m, iterations)
        if n is not None:
            return n
    return _np_aim_normal(pivot_enu, sun_enu, aim_enu, mirror_offset_m, iterations)


def _aim_normal_kernel(pivot_enu, sun_enu, aim_enu, mirror_offset_m, iterations: int) -> np.ndarray | None:
    """:func:`aim_normal` by the kernel for (3,) or (K, 3) rows, else None (numpy's case)."""
    off = np.asarray(mirror_offset_m, dtype=float)
    if off.ndim > 1:
        return None
    ins = [np.asarray(a, dtype=float) for a in (pivot_enu, sun_enu, aim_enu)]
    k = max([a.shape[0] if a.ndim == 2 else 1 for a in ins] + [off.shape[0] if off.ndim == 1 else 1])
    rows = [kernel_rows(a, 3, k) for a in ins]
    if any(r is None for r in rows) or not use_kernels(k) or (off.ndim == 1 and off.shape[0] not in (1, k)):
        return None
    n = kernels().aim_normal(rows[0], rows[1], rows[2], np.array(off, dtype=float).reshape(-1), int(iterations))
    return n if off.ndim == 1 or any(a.ndim == 2 for a in ins) else n[0]


def _np_aim_normal(pivot_enu: np.ndarray, sun_enu: np.ndarray, aim_enu: np.ndarray, mirror_offset_m,
                   iterations: int = AIM_ITERATIONS) -> np.ndarray:
    """numpy reference of :func:`aim_normal`."""
    p = np.asarray(pivot_enu, dtype=float)
    s = unit(sun_enu)
    t = np.asarray(aim_enu, dtype=float)
    n = unit(s + unit(t - p))
    for _ in range(int(iterations)):
        n = unit(s + unit(t - mirror_centre(p, n, mirror_offset_m)))
    return n


def observed_normal_from_spot(origin_pivot_enu: np.ndarray, sun_enu: np.ndarray, spot_enu: np.ndarray,
                              mirror_offset_m, iterations: int = AIM_ITERATIONS) -> np.ndarray:
    """The normal that explains a beam seen at ``spot_enu`` (same fixed point as :func:`aim_normal`)."""
    return aim_normal(origin_pivot_enu, sun_enu, spot_enu, mirror_offset_m, iterations)


def intersect_target(origin_enu: np.ndarray, direction_enu: np.ndarray, target
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intersect rays with a target plane.

    Parameters
    ----------
    origin_enu, direction_enu : (..., 3) ray origins [m] and directions, ENU
    target : ``config.Target`` (plane through ``center_enu_m`` with normal ``normal_enu``)

    Returns
    -------
    uv_m : (..., 2) hit point in the target frame (u right, v up) [m]; NaN where invalid
    hit_enu : (..., 3) hit point [m, ENU]; NaN where invalid
    valid : (...) bool, False where the ray is parallel to the plane or points away from it
    """
    o = np.asarray(origin_enu, dtype=float)
    d = np.asarray(direction_enu, dtype=float)
    frame = target.frame_enu
    w = frame[2]
    c = np.asarray(target.center_enu_m, dtype=float)
    denom = d @ w
    num = (c - o) @ w
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = num / denom
    valid = (np.abs(denom) > 1e-12) & (lam > 0.0)
    lam = np.where(valid, lam, np.nan)
    hit = o + lam[..., None] * d
    uv = (hit - c) @ frame[:2].T
    return uv, hit, valid


def tracking_error_mrad(spot_enu: np.ndarray, aim_enu: np.ndarray, pivot_enu: np.ndarray) -> np.ndarray:
    """Tracking error by T/GRLM 02-2014 formula (1): ``|X − T| / |T − P| × 1000`` [mrad], shape (...)."""
    x = np.asarray(spot_enu, dtype=float)
    t = np.asarray(aim_enu, dtype=float)
    p = np.asarray(pivot_enu, dtype=float)
    return 1000.0 * np.linalg.norm(x - t, axis=-1) / np.linalg.norm(t - p, axis=-1)


def tracking_error_exact_mrad(spot_enu: np.ndarray, aim_enu: np.ndarray, pivot_enu: np.ndarray) -> np.ndarray:
    """The angle at the pivot P between the spot X and the aim point T [mrad], shape (...)."""
    p = np.asarray(pivot_enu, dtype=float)
    a = np.asarray(spot_enu, dtype=float) - p
    b = np.asarray(aim_enu, dtype=float) - p
    return 1000.0 * angle_between_rad(a, b)


def angle_between_rad(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors (..., 3) [rad], accurate for tiny angles (atan2 of |a×b| and a·b)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
