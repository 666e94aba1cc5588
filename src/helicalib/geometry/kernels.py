"""Compiled (numba) kernels of the one-heliostat geometry: the maths of ``drives``, ``optics`` and
``heliostat`` as loops over a few rows, without numpy's per-call overhead on tiny arrays.

The numpy functions stay the reference (``reference=True`` on the wired functions, or the
``_np_*`` functions); these kernels follow them operation by operation (same conventions, same
NaN and range semantics, same choice between the two gimbal solutions), so results agree to float
rounding (tests hold them within 1e-9 rad and 1e-9 mm). Callers use them for every model size
(:data:`MAX_ROWS`: they beat numpy's vectorisation at any N measured), numpy for shapes the kernels
do not take (more than 2-D, or rows that need broadcasting).

A drive enters as one packed float array, shape (N, :data:`PACKED_WIDTH`), one row per heliostat
(:func:`pack`, cached as ``DriveArrays.packed``); the columns are the ``DriveArrays`` fields in the
order of the ``_C_*`` offsets below. A heliostat model's kernels (``model_*``) take that array with
the effective pivot and the two backlash parameters appended (:data:`MODEL_WIDTH` columns,
:func:`pack_model`). Row arguments (strokes, sun, aim, approach, normals) have 1 row (used for every
heliostat) or N rows. ``approach`` with 0 rows means "no backlash shift". Every array passed is
writable and C-contiguous (:func:`rows2`), so each kernel has one compiled signature, the one
:func:`warm` compiles.

Compiled with ``cache=True``: the machine code lands in ``__pycache__`` on first use; :func:`warm`
compiles every kernel once (at install time), so no run pays the compile. The helpers live in this
one file on purpose: numba's cache checks only the calling function's own source file, so a helper
edited in another module would leave stale machine code behind.
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

_C_A1, _C_A2, _C_N0 = 0, 3, 6
_C_RA, _C_RB, _C_G0, _C_SG, _C_L0, _C_SMIN, _C_SMAX = 9, 11, 13, 15, 17, 19, 21
_C_OFF = 23
PACKED_WIDTH = 24
"""Columns of a packed drive: a1, a2, n0 (3 each), ra, rb, γ0, sign, ℓ0, stroke min, max (2 each), offset."""
_C_PIV, _C_BL = 24, 27
MODEL_WIDTH = 29
"""Columns of a packed model: the packed drive, then the effective pivot (3) and backlash_1, _2 [mm]."""

MAX_ROWS = 1 << 40
"""Callers use the kernels below this many rows, numpy at or above it. ``benchmarks/bench_kernels.py``
found no crossover (the kernels 4× faster per heliostat than numpy at 65 536 rows for the aim, 2× for
the normal, 15–140× on one heliostat), so the limit is no limit; it stays a knob for measurement."""

NO_APPROACH = np.zeros((0, 2))
"""The ``approach`` argument meaning "no backlash shift" (numpy's ``approach=None``)."""

AIM_ITERATIONS = 6
"""Fixed-point steps of the aim normal (``optics.AIM_ITERATIONS``, repeated here to keep the
kernels free of imports from the modules that call them)."""

_PI = math.pi
_TWO_PI = 2.0 * math.pi
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")  # a division by zero gives inf/NaN, as numpy


def pack(axis1_enu, axis2_enu, normal0_enu, arm_fixed_m, arm_moving_m, gamma0_rad, sign, length_at_zero_m,
         stroke_min_mm, stroke_max_mm, mirror_offset_m) -> np.ndarray:
    """The drive arrays of N heliostats as one C-contiguous (N, PACKED_WIDTH) float array."""
    return np.ascontiguousarray(np.concatenate([
        axis1_enu, axis2_enu, normal0_enu, arm_fixed_m, arm_moving_m, gamma0_rad, sign, length_at_zero_m,
        stroke_min_mm, stroke_max_mm, np.asarray(mirror_offset_m, dtype=float).reshape(-1, 1)], axis=1), dtype=float)


def pack_model(drive_packed: np.ndarray, pivots_enu: np.ndarray, backlash_mm: np.ndarray) -> np.ndarray:
    """A packed drive (N, PACKED_WIDTH) with pivots (N, 3) and backlash (N, 2): (N, MODEL_WIDTH)."""
    return np.ascontiguousarray(np.concatenate([drive_packed, pivots_enu, backlash_mm], axis=1), dtype=float)


def rows2(a, width: int) -> np.ndarray | None:
    """``a`` as a writable C-contiguous float (m, width) array if it is (width,) or (m, width), else
    None (then the caller takes the numpy path, which broadcasts anything)."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 1 and a.shape[0] == width:
        a = np.ascontiguousarray(a.reshape(1, width))  # (a strided row would compile another layout)
    elif a.ndim == 2 and a.shape[1] == width:
        a = np.ascontiguousarray(a)
    else:
        return None
    return a if a.flags.writeable else a.copy()


# ---------------------------------------------------------------------------- scalar helpers
@_jit
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@_jit
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@_jit
def _unit(x, y, z):
    r = math.sqrt(x * x + y * y + z * z)
    return x / r, y / r, z / r


@_jit
def _rotate(ax, ay, az, ang, vx, vy, vz):
    """Rodrigues, as ``drives.rotate``: v·c + (a×v)·s + a·(a·v)·(1 − c)."""
    c = math.cos(ang)
    s = math.sin(ang)
    d = _dot(ax, ay, az, vx, vy, vz)
    cx, cy, cz = _cross(ax, ay, az, vx, vy, vz)
    k = 1.0 - c
    return vx * c + cx * s + ax * d * k, vy * c + cy * s + ay * d * k, vz * c + cz * s + az * d * k


@_jit
def _rotation_angle(ax, ay, az, vx, vy, vz, bx, by, bz):
    """Signed angle about a that takes v to b (their components ⊥ a), as ``drives._rotation_angle``."""
    da = _dot(ax, ay, az, vx, vy, vz)
    px, py, pz = vx - ax * da, vy - ay * da, vz - az * da
    db = _dot(ax, ay, az, bx, by, bz)
    qx, qy, qz = bx - ax * db, by - ay * db, bz - az * db
    cx, cy, cz = _cross(px, py, pz, qx, qy, qz)
    return math.atan2(_dot(ax, ay, az, cx, cy, cz), _dot(px, py, pz, qx, qy, qz))


@_jit
def _max_nan(a, b):
    """max propagating NaN (``np.max``)."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


@_jit
def _stroke_to_angle(d, i, j, stroke):
    """Stroke [mm] of actuator j of packed row i → axis angle [rad]; NaN where no triangle exists."""
    ra = d[i, _C_RA + j]
    rb = d[i, _C_RB + j]
    length = d[i, _C_L0 + j] + stroke / 1000.0
    cos_g = (ra * ra + rb * rb - length * length) / (2.0 * ra * rb)
    if length > 0.0 and cos_g > -1.0 and cos_g < 1.0:
        return (math.acos(cos_g) - d[i, _C_G0 + j]) / d[i, _C_SG + j]
    return math.nan


@_jit
def _angle_to_stroke(d, i, j, angle):
    """Axis angle [rad] of actuator j of packed row i → stroke [mm]; NaN where γ leaves (0, π)."""
    g = d[i, _C_G0 + j] + d[i, _C_SG + j] * angle
    ra = d[i, _C_RA + j]
    rb = d[i, _C_RB + j]
    length = math.sqrt(ra * ra + rb * rb - 2.0 * ra * rb * math.cos(g))
    if g > 0.0 and g < _PI:
        return 1000.0 * (length - d[i, _C_L0 + j])
    return math.nan


@_jit
def _normal_of_angles(d, i, th1, th2):
    """n = R(a1, θ1)·R(a2, θ2)·n0 of packed row i."""
    vx, vy, vz = _rotate(d[i, _C_A2], d[i, _C_A2 + 1], d[i, _C_A2 + 2], th2,
                         d[i, _C_N0], d[i, _C_N0 + 1], d[i, _C_N0 + 2])
    return _rotate(d[i, _C_A1], d[i, _C_A1 + 1], d[i, _C_A1 + 2], th1, vx, vy, vz)


@_jit
def _shift(d, approach, i, j):
    """Commanded → effective stroke shift [mm]: −backlash/2 · sign(approach); 0 without approach."""
    m = approach.shape[0]
    if m == 0:
        return 0.0
    a = approach[i if m > 1 else 0, j]
    sg = 1.0 if a > 0.0 else (-1.0 if a < 0.0 else (a if a != a else 0.0))
    return -0.5 * d[i, _C_BL + j] * sg


@_jit
def _wrap(theta, low, high):
    centre = 0.5 * (low + high)
    return theta + _TWO_PI * np.rint((centre - theta) / _TWO_PI)


@_jit
def _interval(d, i, j):
    """(low, high) axis angle of actuator j of packed row i keeping γ inside (0, π) (``angle_interval_rad``)."""
    a = -d[i, _C_G0 + j] / d[i, _C_SG + j]
    b = (_PI - d[i, _C_G0 + j]) / d[i, _C_SG + j]
    return min(a, b), max(a, b)


@_jit
def _normal_to_angles_row(d, i, nx, ny, nz, tol):
    """(θ1, θ2, reachable) for the normal (nx, ny, nz) of packed row i, as ``drives.normal_to_angles``."""
    nx, ny, nz = _unit(nx, ny, nz)
    a1x, a1y, a1z = d[i, _C_A1], d[i, _C_A1 + 1], d[i, _C_A1 + 2]
    a2x, a2y, a2z = d[i, _C_A2], d[i, _C_A2 + 1], d[i, _C_A2 + 2]
    n0x, n0y, n0z = d[i, _C_N0], d[i, _C_N0 + 1], d[i, _C_N0 + 2]
    c12 = _dot(a1x, a1y, a1z, a2x, a2y, a2z)
    p = _dot(a1x, a1y, a1z, nx, ny, nz)
    q = _dot(a2x, a2y, a2z, n0x, n0y, n0z)
    det = 1.0 - c12 * c12
    alpha = (p - c12 * q) / det
    beta = (q - c12 * p) / det
    rem = 1.0 - (alpha * alpha + beta * beta + 2.0 * alpha * beta * c12)
    exists = rem > -tol
    g = math.sqrt((0.0 if rem < 0.0 else rem) / det)
    wx, wy, wz = _cross(a1x, a1y, a1z, a2x, a2y, a2z)
    lo0, hi0 = _interval(d, i, 0)
    lo1, hi1 = _interval(d, i, 1)
    best1 = 0.0
    best2 = 0.0
    best_score = 0.0
    for k in range(2):
        sgg = (1.0 if k == 0 else -1.0) * g
        cx = alpha * a1x + beta * a2x + sgg * wx
        cy = alpha * a1y + beta * a2y + sgg * wy
        cz = alpha * a1z + beta * a2z + sgg * wz
        th2 = _rotation_angle(a2x, a2y, a2z, n0x, n0y, n0z, cx, cy, cz)
        th1 = _rotation_angle(a1x, a1y, a1z, cx, cy, cz, nx, ny, nz)
        th1 = _wrap(th1, lo0, hi0)
        th2 = _wrap(th2, lo1, hi1)
        d1 = abs(th1 - 0.5 * (hi0 + lo0)) / (0.5 * (hi0 - lo0))
        d2 = abs(th2 - 0.5 * (hi1 + lo1)) / (0.5 * (hi1 - lo1))
        inside = d1 < 1.0 and d2 < 1.0
        score = (0.0 if inside else 10.0) + _max_nan(d1, d2)
        if k == 0 or score < best_score:
            best1, best2, best_score = th1, th2, score
    if not exists:
        return math.nan, math.nan, False
    g1 = d[i, _C_G0] + d[i, _C_SG] * best1
    g2 = d[i, _C_G0 + 1] + d[i, _C_SG + 1] * best2
    return best1, best2, (g1 > 0.0 and g1 < _PI and g2 > 0.0 and g2 < _PI)


@_jit
def _aim_normal_row(px, py, pz, sx, sy, sz, tx, ty, tz, off, iterations):
    """Normal putting the beam from the mirror centre on T, as ``optics.aim_normal`` (s unit-scaled)."""
    sx, sy, sz = _unit(sx, sy, sz)
    ux, uy, uz = _unit(tx - px, ty - py, tz - pz)
    nx, ny, nz = _unit(sx + ux, sy + uy, sz + uz)
    for _ in range(iterations):
        ux, uy, uz = _unit(tx - (px + off * nx), ty - (py + off * ny), tz - (pz + off * nz))
        nx, ny, nz = _unit(sx + ux, sy + uy, sz + uz)
    return nx, ny, nz


# ---------------------------------------------------------------------------- drives
@_jit
def linkage(d, values, approach, to_angles):
    """Push-rod triangles of N packed rows for values (1 or N, 2): commanded strokes [mm] → axis
    angles [rad] (``to_angles``; the backlash shift for ``approach`` applied first, as
    ``HeliostatModel.angles``; ``drives.strokes_to_angles`` without approach), or axis angles → strokes
    (``drives.angles_to_strokes``, no shift). Shape (N, 2)."""
    n = d.shape[0]
    m = values.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        r = i if m > 1 else 0
        for j in range(2):
            if to_angles:
                out[i, j] = _stroke_to_angle(d, i, j, values[r, j] + _shift(d, approach, i, j))
            else:
                out[i, j] = _angle_to_stroke(d, i, j, values[r, j])
    return out


@_jit
def rotate_rows(axis, angle, v):
    """Rodrigues on rows: axis, v (1 or K, 3), angle (1 or K,) → (K, 3) (``drives.rotate``)."""
    k = max(axis.shape[0], angle.shape[0], v.shape[0])
    out = np.empty((k, 3))
    for i in range(k):
        a = i if axis.shape[0] > 1 else 0
        r = i if v.shape[0] > 1 else 0
        t = angle[i if angle.shape[0] > 1 else 0]
        out[i, 0], out[i, 1], out[i, 2] = _rotate(axis[a, 0], axis[a, 1], axis[a, 2], t, v[r, 0], v[r, 1], v[r, 2])
    return out


@_jit
def angles_to_normal(d, angles):
    """Axis angles (1 or N, 2) [rad] → unit normals (N, 3) (``drives.angles_to_normal``)."""
    n = d.shape[0]
    m = angles.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        r = i if m > 1 else 0
        out[i, 0], out[i, 1], out[i, 2] = _normal_of_angles(d, i, angles[r, 0], angles[r, 1])
    return out


@_jit
def normal_to_angles(d, normal, tol):
    """Normals (1 or N, 3) → (angles (N, 2) [rad], reachable (N,)) (``drives.normal_to_angles``)."""
    n = d.shape[0]
    m = normal.shape[0]
    angles = np.empty((n, 2))
    reachable = np.empty(n, dtype=np.bool_)
    for i in range(n):
        r = i if m > 1 else 0
        angles[i, 0], angles[i, 1], reachable[i] = _normal_to_angles_row(d, i, normal[r, 0], normal[r, 1],
                                                                         normal[r, 2], tol)
    return angles, reachable


# ---------------------------------------------------------------------------- optics
@_jit
def aim_normal(pivot, sun, aim, offset, iterations):
    """Aim normals (K, 3) for rows of pivot, sun, aim (1 or K, 3) and offset (1 or K,) (``optics.aim_normal``)."""
    k = max(pivot.shape[0], sun.shape[0], aim.shape[0], offset.shape[0])
    out = np.empty((k, 3))
    for i in range(k):
        p = i if pivot.shape[0] > 1 else 0
        s = i if sun.shape[0] > 1 else 0
        t = i if aim.shape[0] > 1 else 0
        o = i if offset.shape[0] > 1 else 0
        out[i, 0], out[i, 1], out[i, 2] = _aim_normal_row(
            pivot[p, 0], pivot[p, 1], pivot[p, 2], sun[s, 0], sun[s, 1], sun[s, 2],
            aim[t, 0], aim[t, 1], aim[t, 2], offset[o], iterations)
    return out


@_jit
def _intersect_row(ox, oy, oz, dx, dy, dz, centre, frame):
    """(u, v) of the ray's hit on the plane (centre, frame rows u, v, w); NaN where it misses."""
    wx, wy, wz = frame[2, 0], frame[2, 1], frame[2, 2]
    denom = _dot(dx, dy, dz, wx, wy, wz)
    num = _dot(centre[0] - ox, centre[1] - oy, centre[2] - oz, wx, wy, wz)
    lam = num / denom if denom != 0.0 else math.nan
    if not (abs(denom) > 1e-12 and lam > 0.0):
        return math.nan, math.nan
    hx = ox + lam * dx - centre[0]
    hy = oy + lam * dy - centre[1]
    hz = oz + lam * dz - centre[2]
    return (_dot(hx, hy, hz, frame[0, 0], frame[0, 1], frame[0, 2]),
            _dot(hx, hy, hz, frame[1, 0], frame[1, 1], frame[1, 2]))


# ---------------------------------------------------------------------------- the heliostat model
@_jit
def _normal_commanded(d, i, strokes, r, approach):
    """Normal of packed row i for commanded strokes row r, the backlash shift applied."""
    th1 = _stroke_to_angle(d, i, 0, strokes[r, 0] + _shift(d, approach, i, 0))
    th2 = _stroke_to_angle(d, i, 1, strokes[r, 1] + _shift(d, approach, i, 1))
    return _normal_of_angles(d, i, th1, th2)


@_jit
def model_normal(d, strokes, approach):
    """``HeliostatModel.normal``: normals (N, 3) for commanded strokes (1 or N, 2)."""
    n = d.shape[0]
    m = strokes.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        out[i, 0], out[i, 1], out[i, 2] = _normal_commanded(d, i, strokes, i if m > 1 else 0, approach)
    return out


@_jit
def model_beam(d, strokes, sun, approach):
    """``HeliostatModel.beam``: (mirror centres (N, 3), unit beam directions (N, 3))."""
    n = d.shape[0]
    origin = np.empty((n, 3))
    direction = np.empty((n, 3))
    for i in range(n):
        nx, ny, nz = _normal_commanded(d, i, strokes, i if strokes.shape[0] > 1 else 0, approach)
        s = i if sun.shape[0] > 1 else 0
        sx, sy, sz = _unit(sun[s, 0], sun[s, 1], sun[s, 2])
        off = d[i, _C_OFF]
        origin[i, 0] = d[i, _C_PIV] + off * nx
        origin[i, 1] = d[i, _C_PIV + 1] + off * ny
        origin[i, 2] = d[i, _C_PIV + 2] + off * nz
        k = 2.0 * _dot(sx, sy, sz, nx, ny, nz)
        direction[i, 0] = k * nx - sx
        direction[i, 1] = k * ny - sy
        direction[i, 2] = k * nz - sz
    return origin, direction


@_jit
def model_spot(d, strokes, sun, approach, centres, frames, which):
    """``HeliostatModel.spot_on_target``: (u, v) (N, 2) on target ``which[i]`` of ``centres`` (T, 3)
    and ``frames`` (T, 3, 3); NaN where the beam misses its plane."""
    origin, direction = model_beam(d, strokes, sun, approach)
    n = d.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        t = which[i]
        out[i, 0], out[i, 1] = _intersect_row(origin[i, 0], origin[i, 1], origin[i, 2], direction[i, 0],
                                              direction[i, 1], direction[i, 2], centres[t], frames[t])
    return out


@_jit
def _strokes_of_normal(d, i, nx, ny, nz, approach, strokes, angles, reachable):
    """Row i of ``HeliostatModel.normal_to_strokes`` written into the output arrays."""
    th1, th2, ok = _normal_to_angles_row(d, i, nx, ny, nz, 1e-12)
    angles[i, 0] = th1
    angles[i, 1] = th2
    s1 = _angle_to_stroke(d, i, 0, th1) - _shift(d, approach, i, 0)
    s2 = _angle_to_stroke(d, i, 1, th2) - _shift(d, approach, i, 1)
    strokes[i, 0] = s1
    strokes[i, 1] = s2
    reachable[i] = ok and math.isfinite(s1) and math.isfinite(s2)


@_jit
def model_normal_to_strokes(d, normal, approach):
    """``HeliostatModel.normal_to_strokes``: (strokes (N, 2), angles (N, 2), reachable (N,))."""
    n = d.shape[0]
    m = normal.shape[0]
    strokes = np.empty((n, 2))
    angles = np.empty((n, 2))
    reachable = np.empty(n, dtype=np.bool_)
    for i in range(n):
        r = i if m > 1 else 0
        _strokes_of_normal(d, i, normal[r, 0], normal[r, 1], normal[r, 2], approach, strokes, angles,
                           reachable)
    return strokes, angles, reachable


@_jit
def model_strokes_for_aim(d, sun, aim, approach, iterations):
    """``HeliostatModel.strokes_for_aim``: (strokes, angles, normal, in_range, reachable) for sun and
    aim rows (1 or N, 3); the stroke range is the packed one (the commanded strokes' range)."""
    n = d.shape[0]
    strokes = np.empty((n, 2))
    angles = np.empty((n, 2))
    normal = np.empty((n, 3))
    reachable = np.empty(n, dtype=np.bool_)
    in_range = np.empty(n, dtype=np.bool_)
    for i in range(n):
        s = i if sun.shape[0] > 1 else 0
        t = i if aim.shape[0] > 1 else 0
        sx, sy, sz = _unit(sun[s, 0], sun[s, 1], sun[s, 2])
        nx, ny, nz = _aim_normal_row(d[i, _C_PIV], d[i, _C_PIV + 1], d[i, _C_PIV + 2], sx, sy, sz,
                                     aim[t, 0], aim[t, 1], aim[t, 2], d[i, _C_OFF], iterations)
        normal[i, 0] = nx
        normal[i, 1] = ny
        normal[i, 2] = nz
        _strokes_of_normal(d, i, nx, ny, nz, approach, strokes, angles, reachable)
        ok = reachable[i]
        for j in range(2):
            sj = strokes[i, j]
            ok = ok and sj >= d[i, _C_SMIN + j] and sj <= d[i, _C_SMAX + j]
        in_range[i] = ok
    return strokes, angles, normal, in_range, reachable


# ---------------------------------------------------------------------------- warming the cache
def warm() -> dict[str, float]:
    """Compile (or load from the cache) every kernel once; returns ``{"seconds": …, "kernels": k}``
    (k public kernels ready).

    Called at install time so that no run pays the first-call compile."""
    t0 = time.perf_counter()
    d = pack(np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]),
             np.array([[1.6, 1.2]]), np.array([[1.1, 0.9]]), np.radians([[90.0, 90.0]]), np.array([[1.0, 1.0]]),
             np.array([[0.85, 0.62]]), np.array([[0.0, 0.0]]), np.array([[1750.0, 1400.0]]), np.array([0.3]))
    row2 = np.array([[700.0, 600.0]])
    row3 = np.array([[0.0, 0.6, 0.8]])
    piv = np.array([[12.0, 150.0, 4.2]])
    aim = np.array([[0.0, 9.0, 120.0]])
    m = pack_model(d, piv, np.zeros((1, 2)))
    frames = np.eye(3).reshape(1, 3, 3)
    which = np.zeros(1, dtype=np.int64)
    calls = (
        lambda: linkage(d, row2, NO_APPROACH, True), lambda: linkage(m, row2, row2, True),
        lambda: angles_to_normal(d, row2), lambda: normal_to_angles(d, row3, 1e-12),
        lambda: rotate_rows(row3, np.array([0.1]), row3),
        lambda: aim_normal(piv, row3, aim, np.array([0.3]), AIM_ITERATIONS),
        lambda: model_normal(m, row2, NO_APPROACH), lambda: model_beam(m, row2, row3, NO_APPROACH),
        lambda: model_spot(m, row2, row3, NO_APPROACH, aim, frames, which),
        lambda: model_normal_to_strokes(m, row3, NO_APPROACH),
        lambda: model_strokes_for_aim(m, row3, aim, NO_APPROACH, AIM_ITERATIONS),
    )
    for call in calls:
        call()
    compiled = [k for k, v in globals().items()
                if isinstance(v, numba.core.registry.CPUDispatcher) and v.signatures and not k.startswith("_")]
    return {"seconds": time.perf_counter() - t0, "kernels": len(compiled)}


if __name__ == "__main__":
    print(warm())
