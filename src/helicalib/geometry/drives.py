"""Two-axis drive kinematics and the push-rod triangle linkage, vectorised over heliostats.

Conventions (``FIELD_CONFIG.md``, "Drive kinematics"): with axis angles θ1, θ2 the mirror normal is

    n = R(a1, θ1) · R(a2, θ2) · n0

with R(a, θ) the right-handed rotation about the unit vector a (a1 fixed to the pedestal, a2 given
in the zero pose and turning with axis 1, n0 the normal in the zero pose). Each axis is driven by a
linear actuator in a triangle of a fixed arm ``ra`` and a moving arm ``rb`` meeting at the axis with
angle γ = γ0 + sign·θ, γ ∈ (0, π); actuator length ℓ = sqrt(ra² + rb² − 2·ra·rb·cos γ) and stroke
s = 1000·(ℓ − ℓ0) [mm].

Every function comes with its inverse (``strokes_to_angles`` / ``angles_to_strokes``,
``angles_to_normal`` / ``normal_to_angles``). Nothing is clipped: impossible strokes give NaN
angles, angles outside the linkage give NaN strokes, unreachable normals are flagged.

These four (and ``normal_to_angles``) run the compiled kernels of :mod:`helicalib.geometry.kernels`
(the same maths without numpy's per-call cost on tiny arrays) below ``kernels.MAX_ROWS`` rows and
for (2,) or (1 or N, k) inputs; ``reference=True`` forces the numpy code, the reference the kernels
are tested against, which also takes every shape the kernels do not.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass
from types import ModuleType

import numpy as np

TWO_PI = 2.0 * np.pi
_KERNELS: list[ModuleType] = []


def kernels() -> ModuleType:
    """:mod:`helicalib.geometry.kernels`, imported on first use (numba's import is not free)."""
    if not _KERNELS:
        from helicalib.geometry import kernels as k

        _KERNELS.append(k)
    return _KERNELS[0]


def use_kernels(n_rows: int) -> bool:
    """Whether ``n_rows`` heliostats go to the compiled kernels (below ``kernels.MAX_ROWS``)."""
    return 0 < n_rows < kernels().MAX_ROWS


def kernel_rows(a, width: int, n_rows: int) -> np.ndarray | None:
    """``a`` as a float (1 or ``n_rows``, ``width``) array for a kernel of ``n_rows`` heliostats, or
    None when the kernels are not worth it or ``a``'s shape needs numpy's broadcasting."""
    if not use_kernels(n_rows):
        return None
    r = kernels().rows2(a, width)
    return r if r is not None and r.shape[0] in (1, n_rows) else None


@dataclass(frozen=True)
class DriveArrays:
    """Drive parameters of N heliostats as arrays (one row per heliostat).

    Attributes
    ----------
    axis1_enu, axis2_enu, normal0_enu : ndarray, shape (N, 3)
        Unit vectors a1, a2 (zero pose), n0 in ENU.
    arm_fixed_m, arm_moving_m : ndarray, shape (N, 2)
        Triangle arms ``ra``, ``rb`` of actuator 1 (main, axis 1) and 2 (secondary, axis 2) [m].
    gamma0_rad : ndarray, shape (N, 2)
        Triangle angle at θ = 0 [rad].
    sign : ndarray, shape (N, 2)
        +1 or −1: γ = γ0 + sign·θ.
    length_at_zero_m : ndarray, shape (N, 2)
        Actuator length at stroke 0 [m].
    stroke_min_mm, stroke_max_mm : ndarray, shape (N, 2)
        Commandable stroke range [mm].
    mirror_offset_m : ndarray, shape (N,)
        Distance from pivot to mirror centre along the normal [m].
    mirror_size_m : ndarray, shape (N, 2)
        Mirror width and height [m].
    """

    axis1_enu: np.ndarray
    axis2_enu: np.ndarray
    normal0_enu: np.ndarray
    arm_fixed_m: np.ndarray
    arm_moving_m: np.ndarray
    gamma0_rad: np.ndarray
    sign: np.ndarray
    length_at_zero_m: np.ndarray
    stroke_min_mm: np.ndarray
    stroke_max_mm: np.ndarray
    mirror_offset_m: np.ndarray
    mirror_size_m: np.ndarray

    @classmethod
    def from_drives(cls, drives: Sequence) -> DriveArrays:
        """Stack ``config.Drive`` objects (one per heliostat) into arrays."""
        drives = list(drives)
        axes = [d.axes for d in drives]

        def act(attr: str) -> np.ndarray:
            return np.array([[float(getattr(a, attr)) for a in d.actuators] for d in drives], dtype=float).reshape(-1, 2)

        ranges = np.array([[a.stroke_range_mm for a in d.actuators] for d in drives], dtype=float).reshape(-1, 2, 2)
        return cls(
            axis1_enu=np.array([a[0] for a in axes], dtype=float).reshape(-1, 3),
            axis2_enu=np.array([a[1] for a in axes], dtype=float).reshape(-1, 3),
            normal0_enu=np.array([a[2] for a in axes], dtype=float).reshape(-1, 3),
            arm_fixed_m=act("arm_fixed_m"),
            arm_moving_m=act("arm_moving_m"),
            gamma0_rad=np.radians(act("gamma0_deg")),
            sign=act("sign"),
            length_at_zero_m=act("length_at_zero_stroke_m"),
            stroke_min_mm=ranges[:, :, 0],
            stroke_max_mm=ranges[:, :, 1],
            mirror_offset_m=np.array([float(d.mirror_offset_m) for d in drives], dtype=float),
            mirror_size_m=np.array([d.mirror_size_m for d in drives], dtype=float).reshape(-1, 2),
        )

    def __len__(self) -> int:
        return int(self.axis1_enu.shape[0])

    def take(self, indices) -> DriveArrays:
        """Rows ``indices`` (any integer index array; repeats allowed) as a new DriveArrays."""
        idx = np.asarray(indices, dtype=int)
        out = DriveArrays(**{f.name: getattr(self, f.name)[idx] for f in dataclasses.fields(self)})
        if "packed" in self.__dict__:  # the rows of the packed form too, not packed again
            out.__dict__["packed"] = self.packed[idx]
        return out

    @functools.cached_property
    def packed(self) -> np.ndarray:
        """The arrays as one (N, ``kernels.PACKED_WIDTH``) float array, the compiled kernels' input."""
        return kernels().pack(self.axis1_enu, self.axis2_enu, self.normal0_enu, self.arm_fixed_m, self.arm_moving_m,
                              self.gamma0_rad, self.sign, self.length_at_zero_m, self.stroke_min_mm,
                              self.stroke_max_mm, self.mirror_offset_m)

    def replace(self, **changes) -> DriveArrays:
        return dataclasses.replace(self, **changes)


# ---------------------------------------------------------------------------- rotations
def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of 3-vectors (..., 3) × (..., 3) with broadcasting; ``np.cross`` without its
    generality, about 2.5× faster on the small arrays of the fit's inner loop."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    x = a1 * b2 - a2 * b1
    out = np.empty(x.shape + (3,))
    out[..., 0] = x
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def rotate(axis: np.ndarray, angle_rad: np.ndarray, v: np.ndarray, reference: bool = False) -> np.ndarray:
    """Rodrigues: rotate vectors ``v`` (..., 3) about unit ``axis`` (..., 3) by ``angle_rad`` (...).

    Rows (K, 3) or (3,) with angles (K,) or scalar, K rows in all, run the compiled kernel
    (``reference=True``, or other shapes: numpy)."""
    if not reference:
        out = _rotate_by_kernel(axis, angle_rad, v)
        if out is not None:
            return out
    return _np_rotate(axis, angle_rad, v)


def _rotate_by_kernel(axis, angle_rad, v) -> np.ndarray | None:
    """:func:`rotate` by the kernel when the result is (K, 3) rows of (1 or K)-row inputs, else None."""
    axis = np.asarray(axis, dtype=float)
    v = np.asarray(v, dtype=float)
    ang = np.asarray(angle_rad, dtype=float)
    if ang.ndim > 1 or axis.ndim > 2 or v.ndim > 2 or (axis.ndim < 2 and v.ndim < 2 and ang.ndim < 1):
        return None
    k = max(axis.shape[0] if axis.ndim == 2 else 1, v.shape[0] if v.ndim == 2 else 1, ang.size)
    a_rows, v_rows = kernel_rows(axis, 3, k), kernel_rows(v, 3, k)
    if a_rows is None or v_rows is None or ang.size not in (1, k):
        return None
    return kernels().rotate_rows(a_rows, np.array(ang, dtype=float).reshape(-1), v_rows)


def _np_rotate(axis: np.ndarray, angle_rad: np.ndarray, v: np.ndarray) -> np.ndarray:
    """numpy reference of :func:`rotate`."""
    axis = np.asarray(axis, dtype=float)
    v = np.asarray(v, dtype=float)
    c = np.cos(angle_rad)[..., None]
    s = np.sin(angle_rad)[..., None]
    dot = _dot(axis, v, keepdims=True)
    return v * c + cross3(axis, v) * s + axis * dot * (1.0 - c)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.sqrt(_dot(v, v, keepdims=True))


def _dot(a: np.ndarray, b: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """Σ a·b over the last axis: ``np.sum(a * b, axis=-1)`` (the same reduction, without the
    wrapper's cost on the small arrays of one heliostat); ``np.linalg.norm(v, axis=-1)`` is
    ``sqrt(_dot(v, v))`` for real v."""
    return np.add.reduce(a * b, axis=-1, keepdims=keepdims)


def _rotation_angle(axis: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Signed angle about ``axis`` that takes ``a`` to ``b`` (their components ⊥ axis) [rad]."""
    a_perp = a - axis * _dot(axis, a, keepdims=True)
    b_perp = b - axis * _dot(axis, b, keepdims=True)
    return np.arctan2(_dot(axis, cross3(a_perp, b_perp)), _dot(a_perp, b_perp))


# ---------------------------------------------------------------------------- linkage
def _by_kernel(name: str, drives: DriveArrays, values) -> np.ndarray | None:
    """``name`` (``strokes_to_angles``, ``angles_to_strokes`` or ``angles_to_normal``) of (1 or N, 2)
    ``values`` by the compiled kernel; None where numpy's path applies."""
    rows = kernel_rows(values, 2, len(drives))
    if rows is None:
        return None
    k = kernels()
    if name == "angles_to_normal":
        return k.angles_to_normal(drives.packed, rows)
    return k.linkage(drives.packed, rows, k.NO_APPROACH, name == "strokes_to_angles")


def gamma_rad(drives: DriveArrays, angles_rad: np.ndarray) -> np.ndarray:
    """Triangle angle γ = γ0 + sign·θ, shape (N, 2) [rad]."""
    return drives.gamma0_rad + drives.sign * np.asarray(angles_rad, dtype=float)


def angle_interval_rad(drives: DriveArrays) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) axis angles, shape (N, 2) each, between which γ stays inside (0, π) [rad] (open)."""
    a = -drives.gamma0_rad / drives.sign
    b = (np.pi - drives.gamma0_rad) / drives.sign
    return np.minimum(a, b), np.maximum(a, b)


def angles_to_strokes(drives: DriveArrays, angles_rad: np.ndarray, reference: bool = False) -> np.ndarray:
    """Axis angles (N, 2) [rad] → actuator strokes (N, 2) [mm]; NaN where γ leaves (0, π)."""
    out = None if reference else _by_kernel("angles_to_strokes", drives, angles_rad)
    return _np_angles_to_strokes(drives, angles_rad) if out is None else out


def _np_angles_to_strokes(drives: DriveArrays, angles_rad: np.ndarray) -> np.ndarray:
    """numpy reference of :func:`angles_to_strokes`."""
    g = gamma_rad(drives, angles_rad)
    ra, rb = drives.arm_fixed_m, drives.arm_moving_m
    length = np.sqrt(ra * ra + rb * rb - 2.0 * ra * rb * np.cos(g))
    strokes = 1000.0 * (length - drives.length_at_zero_m)
    bad = ~((g > 0.0) & (g < np.pi))
    return np.where(bad, np.nan, strokes)


def strokes_to_angles(drives: DriveArrays, strokes_mm: np.ndarray, reference: bool = False) -> np.ndarray:
    """Actuator strokes (N, 2) [mm] → axis angles (N, 2) [rad]; NaN where no triangle exists."""
    out = None if reference else _by_kernel("strokes_to_angles", drives, strokes_mm)
    return _np_strokes_to_angles(drives, strokes_mm) if out is None else out


def _np_strokes_to_angles(drives: DriveArrays, strokes_mm: np.ndarray) -> np.ndarray:
    """numpy reference of :func:`strokes_to_angles`."""
    length = drives.length_at_zero_m + np.asarray(strokes_mm, dtype=float) / 1000.0
    ra, rb = drives.arm_fixed_m, drives.arm_moving_m
    cos_g = (ra * ra + rb * rb - length * length) / (2.0 * ra * rb)
    ok = (length > 0.0) & (cos_g > -1.0) & (cos_g < 1.0)
    g = np.arccos(np.where(ok, cos_g, 0.0))
    return np.where(ok, (g - drives.gamma0_rad) / drives.sign, np.nan)


def strokes_in_range(drives: DriveArrays, strokes_mm: np.ndarray) -> np.ndarray:
    """(N, 2) bool: stroke finite and inside ``[stroke_min_mm, stroke_max_mm]``."""
    s = np.asarray(strokes_mm, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(s) & (s >= drives.stroke_min_mm) & (s <= drives.stroke_max_mm)


def stroke_margin_mm(drives: DriveArrays, strokes_mm: np.ndarray) -> np.ndarray:
    """(N, 2) distance to the nearer end of the stroke range [mm]; negative outside, NaN if NaN."""
    s = np.asarray(strokes_mm, dtype=float)
    return np.minimum(s - drives.stroke_min_mm, drives.stroke_max_mm - s)


# ---------------------------------------------------------------------------- axes ↔ normal
def angles_to_normal(drives: DriveArrays, angles_rad: np.ndarray, reference: bool = False) -> np.ndarray:
    """Axis angles (N, 2) [rad] → unit mirror normal (N, 3), ENU: n = R(a1,θ1)·R(a2,θ2)·n0."""
    out = None if reference else _by_kernel("angles_to_normal", drives, angles_rad)
    return _np_angles_to_normal(drives, angles_rad) if out is None else out


def _np_angles_to_normal(drives: DriveArrays, angles_rad: np.ndarray) -> np.ndarray:
    """numpy reference of :func:`angles_to_normal`."""
    th = np.asarray(angles_rad, dtype=float)
    n = _np_rotate(drives.axis2_enu, th[..., 1], drives.normal0_enu)
    return _np_rotate(drives.axis1_enu, th[..., 0], n)


def _wrap_into_interval(theta: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """θ + 2πk nearest to the centre of (low, high) (the interval is at most π long)."""
    centre = 0.5 * (low + high)
    return theta + TWO_PI * np.round((centre - theta) / TWO_PI)


def normal_to_angles(drives: DriveArrays, normal_enu: np.ndarray, tol: float = 1e-12, reference: bool = False
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Unit mirror normal (N, 3) → axis angles (N, 2) [rad] and ``reachable`` (N,) bool.

    Solves R(a1,θ1)·R(a2,θ2)·n0 = n in closed form (intersection of the two cones a2·c = a2·n0 and
    a1·c = a1·n on the unit sphere; general, non-orthogonal axes allowed). Of the two solutions the
    one whose triangle angles both lie in (0, π) is returned (angles unwrapped into the linkage's
    range, never wrapped to ±π); if both or neither do, the one nearer the middle of the linkage range.
    ``reachable`` is False when no exact solution exists (angles NaN) or when the best solution
    leaves the linkage range (angles returned as found, so the caller can see how far off it is).
    """
    rows = None if reference else kernel_rows(normal_enu, 3, len(drives))
    if rows is not None:
        return kernels().normal_to_angles(drives.packed, rows, float(tol))
    return _np_normal_to_angles(drives, normal_enu, tol)


def _np_normal_to_angles(drives: DriveArrays, normal_enu: np.ndarray, tol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """numpy reference of :func:`normal_to_angles`."""
    n = _unit(np.asarray(normal_enu, dtype=float))
    a1, a2, n0 = drives.axis1_enu, drives.axis2_enu, drives.normal0_enu
    c12 = _dot(a1, a2)
    p = _dot(a1, n)
    q = _dot(a2, n0)
    det = 1.0 - c12 * c12
    alpha = (p - c12 * q) / det
    beta = (q - c12 * p) / det
    rem = 1.0 - (alpha * alpha + beta * beta + 2.0 * alpha * beta * c12)
    exists = rem > -tol
    g = np.sqrt(np.clip(rem, 0.0, None) / det)
    w = cross3(a1, a2)
    low, high = angle_interval_rad(drives)
    half = 0.5 * (high - low)
    mid = 0.5 * (high + low)
    # both solutions at once, on a new axis before the vector's: (..., 2, 3), sign +1 then −1
    sg = np.array([1.0, -1.0])[:, None] * g[..., None, None]
    c = (alpha[..., None] * a1 + beta[..., None] * a2)[..., None, :] + sg * w[..., None, :]
    a1s, a2s = a1[..., None, :], a2[..., None, :]
    th2 = _rotation_angle(a2s, n0[..., None, :], c)
    th1 = _rotation_angle(a1s, c, n[..., None, :])
    th = _wrap_into_interval(np.stack([th1, th2], axis=-1), low[..., None, :], high[..., None, :])
    dist = np.abs(th - mid[..., None, :]) / half[..., None, :]  # < 1 inside the linkage range
    inside = np.all(dist < 1.0, axis=-1)
    scores = np.where(inside, 0.0, 10.0) + np.max(dist, axis=-1)  # (..., 2)
    pick = scores[..., 1] < scores[..., 0]
    angles = np.where(pick[..., None], th[..., 1, :], th[..., 0, :])
    angles = np.where(exists[..., None], angles, np.nan)
    gam = gamma_rad(drives, angles)
    with np.errstate(invalid="ignore"):
        reachable = exists & np.all((gam > 0.0) & (gam < np.pi), axis=-1)
    return angles, reachable
