"""The compiled refit: numba kernels of the fast solver's forward beam, its analytic Jacobian and
the damped Gauss-Newton with its robust loss (:mod:`.fit_solver` holds the numpy reference).

A campaign refits one heliostat after every valid point: a dozen to a few dozen observations, 13
to 15 unknowns. In numpy each of the solver's evaluations is some hundred array calls on arrays of
that size, so the time is the calls' overhead, not the arithmetic. Here one call does the whole
solve: :func:`solve` builds the whitened residuals and Jacobian of
:func:`helicalib.calibration.fit._solve_fast` (with the tilt rate and the epochs' offsets) and
runs :func:`helicalib.calibration.fit_solver.gauss_newton`'s steps, line search and stopping
rules, observation by observation in scalar code. The same formulas in the same order: residuals
and Jacobian agree with :class:`~.fit_solver.BeamJacobian` to round-off, fits to far below 0.001
mrad (``tests/test_kernels_fit.py``). The ``"beam"`` residual only; the ``"normal"`` one stays numpy.

Kernels are compiled on first use and cached on disk (``cache=True``); :func:`warm` compiles all
of them once (an install runs it, so no test or campaign pays the compile time).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from helicalib.geometry import error_model as em

NAN_RESIDUAL_MRAD = 1000.0
"""Residual where a parameter set makes a stroke impossible (:data:`.fit_solver.NAN_RESIDUAL_MRAD`)."""
LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")
"""The robust losses by code (the index is the kernels' loss code)."""
_EPS = float(np.finfo(float).eps)
STALL_FTOL = 1e-10
"""As :data:`.fit_solver.STALL_FTOL`."""

_NAMES = ("stroke_offset_1_mm", "stroke_offset_2_mm", "pedestal_tilt_e_mrad", "pedestal_tilt_n_mrad",
          "axis_nonorthogonality_mrad", "canting_1_mrad", "canting_2_mrad", "pivot_de_m", "pivot_dn_m", "pivot_du_m",
          "arm_scale_1", "arm_scale_2", "pedestal_yaw_mrad", "backlash_1_mm", "backlash_2_mm")
"""The error model's parameters in their order, written out here: numba bakes the columns below into
the compiled kernels as constants and its cache checks only this file, so a change of
:data:`helicalib.geometry.error_model.NAMES` must change this file too (checked at import)."""


def check_names(names) -> None:
    """Raise ImportError unless ``names`` are :data:`_NAMES` in order (run at import on the error model's)."""
    if tuple(names) != _NAMES:
        raise ImportError("calibration.fit_kernels: the error model's parameters changed "
                          "(geometry/error_model.py NAMES); update fit_kernels._NAMES, which renews the compiled cache")


check_names(em.NAMES)
_I = {name: k for k, name in enumerate(_NAMES)}
# columns of the parameters the kernels need, as plain ints (compile-time constants)
SO1, SO2 = _I["stroke_offset_1_mm"], _I["stroke_offset_2_mm"]
TE, TN, YAW = _I["pedestal_tilt_e_mrad"], _I["pedestal_tilt_n_mrad"], _I["pedestal_yaw_mrad"]
NONORTH, CAN1, CAN2 = _I["axis_nonorthogonality_mrad"], _I["canting_1_mrad"], _I["canting_2_mrad"]
PIV_E, PIV_N, PIV_U = _I["pivot_de_m"], _I["pivot_dn_m"], _I["pivot_du_m"]
ARM1, ARM2, BL1, BL2 = _I["arm_scale_1"], _I["arm_scale_2"], _I["backlash_1_mm"], _I["backlash_2_mm"]
P = len(_NAMES)
XTOL, FTOL, MAX_ITER = 1e-8, 1e-14, 100
"""The stopping rules of :func:`.fit_solver.gauss_newton` (its defaults)."""
GEO_SIZE = 29
"""Length of a packed drive (:func:`pack_drive`)."""


def pack_drive(drives, pivot_enu) -> np.ndarray:
    """One heliostat's nominal drive (DriveArrays, N = 1) and pivot (3,) as the flat array (29,) the
    kernels read: a1, a2, n0, u (the canting-1 axis), w (the non-orthogonality axis), then ra, rb0,
    γ0, sign, ℓ0 per actuator, the mirror offset and the pivot."""
    geo = np.concatenate([drives.axis1_enu[0], drives.axis2_enu[0], drives.normal0_enu[0], np.zeros(6),
                          drives.arm_fixed_m[0], drives.arm_moving_m[0], drives.gamma0_rad[0], drives.sign[0],
                          drives.length_at_zero_m[0], drives.mirror_offset_m[:1], pivot_enu]).astype(float)
    _fill_axes(geo)
    return geo


@numba.njit(cache=True, error_model="numpy")
def _unit_or_into(x, y, z, fx, fy, fz, out):
    norm = math.sqrt(x * x + y * y + z * z)
    if norm > 1e-12:
        out[0], out[1], out[2] = x / norm, y / norm, z / norm
    else:
        out[0], out[1], out[2] = fx, fy, fz


@numba.njit(cache=True, error_model="numpy")
def _fill_axes(geo):
    """u = unit(a2 × n0) (else east) and w = unit(a1 × a2) (else up) into ``geo`` (BeamJacobian's)."""
    a1, a2, n0 = geo[0:3], geo[3:6], geo[6:9]
    _unit_or_into(a2[1] * n0[2] - a2[2] * n0[1], a2[2] * n0[0] - a2[0] * n0[2], a2[0] * n0[1] - a2[1] * n0[0],
                  1.0, 0.0, 0.0, geo[9:12])
    _unit_or_into(a1[1] * a2[2] - a1[2] * a2[1], a1[2] * a2[0] - a1[0] * a2[2], a1[0] * a2[1] - a1[1] * a2[0],
                  0.0, 0.0, 1.0, geo[12:15])


# ---------------------------------------------------------------------------------- small algebra
@numba.njit(cache=True, error_model="numpy")
def _rot(ax, ay, az, angle):
    """3 × 3 Rodrigues matrix about unit (ax, ay, az) (:func:`.fit_solver.rotation_matrix`)."""
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    r = np.empty((3, 3))
    r[0, 0], r[0, 1], r[0, 2] = c + ax * ax * t, ax * ay * t - az * s, ax * az * t + ay * s
    r[1, 0], r[1, 1], r[1, 2] = ay * ax * t + az * s, c + ay * ay * t, ay * az * t - ax * s
    r[2, 0], r[2, 1], r[2, 2] = az * ax * t - ay * s, az * ay * t + ax * s, c + az * az * t
    return r


@numba.njit(cache=True, error_model="numpy")
def _mv(m, v):
    out = np.empty(3)
    for i in range(3):
        out[i] = m[i, 0] * v[0] + m[i, 1] * v[1] + m[i, 2] * v[2]
    return out


@numba.njit(cache=True, error_model="numpy")
def _rotate_into(axis, c, s, v, out):
    """``v`` turned about unit ``axis`` by the angle of cosine c and sine s (``fit_solver._rotate_rows``),
    written into ``out`` (3,) (not ``v`` itself)."""
    d = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]
    x = axis[1] * v[2] - axis[2] * v[1]
    y = axis[2] * v[0] - axis[0] * v[2]
    z = axis[0] * v[1] - axis[1] * v[0]
    out[0] = v[0] * c + x * s + axis[0] * (d * (1.0 - c))
    out[1] = v[1] * c + y * s + axis[1] * (d * (1.0 - c))
    out[2] = v[2] * c + z * s + axis[2] * (d * (1.0 - c))


@numba.njit(cache=True, error_model="numpy")
def _triangle(p, geo, stroke, approach, has_approach, a):
    """Actuator ``a``'s push-rod triangle at the held stroke: (length [m], moving arm [m], cos γ,
    cos θ, sin θ); θ is NaN where the triangle cannot close (``drives.strokes_to_angles``)."""
    so = p[SO1] if a == 0 else p[SO2]
    arm = p[ARM1] if a == 0 else p[ARM2]
    bl = p[BL1] if a == 0 else p[BL2]
    ra, rb0, gamma0, sign, l0 = geo[15 + a], geo[17 + a], geo[19 + a], geo[21 + a], geo[23 + a]
    st = stroke[a] + (-0.5 * bl * approach[a]) if has_approach else stroke[a]
    length = (l0 + so / 1000.0) + st / 1000.0
    rb = rb0 * (1.0 + arm)
    cos_g = (ra * ra + rb * rb - length * length) / (2.0 * ra * rb)
    ok = length > 0.0 and cos_g > -1.0 and cos_g < 1.0
    theta = (math.acos(cos_g) - gamma0) / sign if ok else np.nan
    return length, rb, cos_g, math.cos(theta), math.sin(theta)


# ---------------------------------------------------------------------------------- forward beam
@numba.njit(cache=True, error_model="numpy")
def _drive_pose(p, geo):
    """The effective drive of parameter row ``p`` (P,): rows a1e, a2e, the zero pose's normal and
    canting-1 axis, q·w, east, re·north, ren·up, the pivot (9, 3) (as ``BeamJacobian.evaluate``)."""
    mrad = 1e-3
    a1, a2, n0, u, w = geo[0:3], geo[3:6], geo[6:9], geo[9:12], geo[12:15]
    rc2 = _rot(a2[0], a2[1], a2[2], p[CAN2] * mrad)
    rw = _rot(w[0], w[1], w[2], p[NONORTH] * mrad)
    re = _rot(1.0, 0.0, 0.0, p[TE] * mrad)
    ren = re @ _rot(0.0, 1.0, 0.0, p[TN] * mrad)
    q = ren @ _rot(0.0, 0.0, 1.0, p[YAW] * mrad)
    qrw = q @ rw
    n0e = _mv(rc2, _mv(_rot(u[0], u[1], u[2], p[CAN1] * mrad), n0))
    out = np.empty((9, 3))
    out[0] = _mv(q, a1)
    out[1] = _mv(qrw, a2)
    out[2] = _mv(qrw, n0e)
    out[3] = _mv(qrw, _mv(rc2, u))
    out[4] = _mv(q, w)
    out[5] = np.array([1.0, 0.0, 0.0])
    out[6] = _mv(re, np.array([0.0, 1.0, 0.0]))
    out[7] = _mv(ren, np.array([0.0, 0.0, 1.0]))
    out[8, 0] = geo[26] + p[PIV_E]
    out[8, 1] = geo[27] + p[PIV_N]
    out[8, 2] = geo[28] + p[PIV_U]
    return out


@numba.njit(cache=True, error_model="numpy")
def _observe(p, geo, pose, stroke, approach, has_approach, sun, spot, basis, want_jac, res, jac, work):
    """One observation's residual ``res`` (2,) [mrad] and, with ``want_jac``, its Jacobian ``jac``
    (2, P) for parameter row ``p`` with its pose (:func:`_drive_pose`); ``work`` (17 + P, 3) scratch.
    A residual that is not finite becomes NAN_RESIDUAL_MRAD with zero derivatives."""
    offset = geo[25]
    # the push-rod triangles: (ℓ, rb, cos γ, cos θ, sin θ) per actuator
    l_1, rb_1, cg_1, c_1, s_1 = _triangle(p, geo, stroke, approach, has_approach, 0)
    l_2, rb_2, cg_2, c_2, s_2 = _triangle(p, geo, stroke, approach, has_approach, 1)
    a1e, a2e = pose[0], pose[1]
    m0, m1, n = work[14 + P], work[15 + P], work[16 + P]
    _rotate_into(a2e, c_2, s_2, pose[2], m0)
    _rotate_into(a2e, c_2, s_2, pose[3], m1)
    _rotate_into(a1e, c_1, s_1, m0, n)
    pivot = pose[8]
    t0 = spot[0] - (pivot[0] + offset * n[0])
    t1 = spot[1] - (pivot[1] + offset * n[1])
    t2 = spot[2] - (pivot[2] + offset * n[2])
    dist = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    e0, e1, e2 = t0 / dist, t1 / dist, t2 / dist
    sn = sun[0] * n[0] + sun[1] * n[1] + sun[2] * n[2]
    f0 = (2.0 * sn * n[0] - sun[0]) - e0
    f1 = (2.0 * sn * n[1] - sun[1]) - e1
    f2 = (2.0 * sn * n[2] - sun[2]) - e2
    bad0 = bad1 = False
    for i in range(2):
        v = 1000.0 * (basis[i, 0] * f0 + basis[i, 1] * f1 + basis[i, 2] * f2)
        ok = math.isfinite(v)
        res[i] = v if ok else NAN_RESIDUAL_MRAD
        if i == 0:
            bad0 = not ok
        else:
            bad1 = not ok
    if not want_jac:
        return
    # δn = Ω × n for the axes Ω carried to the observation's pose (scalar loops: no temporaries)
    omega, t, dn = work[0:7], work[7:14], work[14:14 + P]
    omega[0] = a1e
    _rotate_into(a1e, c_1, s_1, a2e, omega[1])
    omega[2], omega[3], omega[4] = pose[5], pose[6], pose[7]
    _rotate_into(a1e, c_1, s_1, pose[4], omega[5])
    _rotate_into(a1e, c_1, s_1, m1, omega[6])
    for r in range(7):
        t[r, 0] = omega[r, 1] * n[2] - omega[r, 2] * n[1]
        t[r, 1] = omega[r, 2] * n[0] - omega[r, 0] * n[2]
        t[r, 2] = omega[r, 0] * n[1] - omega[r, 1] * n[0]
    dn[:] = 0.0
    for a in range(2):
        length, rb, cos_g = (l_1, rb_1, cg_1) if a == 0 else (l_2, rb_2, cg_2)
        ra, sign = geo[15 + a], geo[21 + a]
        sin_g = math.sqrt(max(1.0 - cos_g * cos_g, 0.0))
        dth_dl = length / (ra * rb * sin_g * sign)
        dth_drb = -(rb * rb - ra * ra + length * length) / (2.0 * ra * rb * rb * sin_g * sign)
        cols = (SO1, ARM1, BL1) if a == 0 else (SO2, ARM2, BL2)
        coef = (dth_dl * 1e-3, dth_drb * geo[17 + a], dth_dl * (-0.5e-3 * approach[a]))
        for j in range(3):
            for x in range(3):
                dn[cols[j], x] = coef[j] * t[a, x]
    rot = (CAN2, TE, TN, YAW, NONORTH, CAN1)
    for j in range(6):
        for x in range(3):
            dn[rot[j], x] = 1e-3 * t[1 + j, x]
    for q in range(P):
        sdn = sun[0] * dn[q, 0] + sun[1] * dn[q, 1] + sun[2] * dn[q, 2]
        d0, d1, d2 = offset * dn[q, 0], offset * dn[q, 1], offset * dn[q, 2]  # δM
        if q == PIV_E:
            d0 += 1.0
        elif q == PIV_N:
            d1 += 1.0
        elif q == PIV_U:
            d2 += 1.0
        edm = e0 * d0 + e1 * d1 + e2 * d2
        dd0 = 2.0 * sdn * n[0] + 2.0 * sn * dn[q, 0] + (d0 - edm * e0) / dist
        dd1 = 2.0 * sdn * n[1] + 2.0 * sn * dn[q, 1] + (d1 - edm * e1) / dist
        dd2 = 2.0 * sdn * n[2] + 2.0 * sn * dn[q, 2] + (d2 - edm * e2) / dist
        for i in range(2):
            bad = bad0 if i == 0 else bad1
            jac[i, q] = 0.0 if bad else 1000.0 * (basis[i, 0] * dd0 + basis[i, 1] * dd1 + basis[i, 2] * dd2)


@numba.njit(cache=True, error_model="numpy")
def beam_residuals(p, geo, strokes, approach, has_approach, sun, spot, basis, want_jac):
    """Residuals (K, 2) [mrad] of K observations for one parameter row (P,) and, with ``want_jac``,
    their Jacobian (K, 2, P): :meth:`.fit_solver.BeamJacobian.evaluate` (kind ``"beam"``) compiled."""
    k = strokes.shape[0]
    res = np.empty((k, 2))
    jac = np.zeros((k, 2, P))
    pose = _drive_pose(p, geo)
    work = np.empty((17 + P, 3))
    for i in range(k):
        _observe(p, geo, pose, strokes[i], approach[i], has_approach, sun[i], spot[i], basis[i], want_jac,
                 res[i], jac[i], work)
    return res, jac


# ---------------------------------------------------------------------------------- whitened problem
@numba.njit(cache=True, error_model="numpy")
def fun_jac(x, geo, strokes, approach, has_approach, sun, spot, basis, base, centre, free_idx, sig_prior,
            inv_sigma, age, rate_scale, epoch, n_groups, ep_idx, ep_scale):
    """The fit's whitened residuals (2K + n_x,) and Jacobian (2K + n_x, n_x) at unknowns ``x``: the
    ``fun_jac`` of :func:`helicalib.calibration.fit._solve_fast`. ``age`` (K,) empty without a tilt
    rate; ``epoch`` (K,) each observation's epoch (all 0 without epochs), ``n_groups`` epochs;
    ``ep_idx`` (m,) the epoch parameters' columns, ``ep_scale`` (m,) their offsets' prior σ."""
    k = strokes.shape[0]
    f = free_idx.shape[0]
    n_x = x.shape[0]
    nr = 2 if age.shape[0] > 0 else 0
    m = ep_idx.shape[0]
    tilt = (TE, TN)
    p = base.copy()
    for j in range(f):
        p[free_idx[j]] = centre[free_idx[j]] + x[j] * sig_prior[j]
    res = np.empty((k, 2))
    jac = np.zeros((k, 2, P))
    work = np.empty((17 + P, 3))
    for g in range(n_groups):
        pe = p.copy()
        if g > 0:
            for j in range(m):
                pe[ep_idx[j]] += x[f + nr + (g - 1) * m + j] * ep_scale[j]
        pose = _drive_pose(pe, geo)
        for i in range(k):
            if epoch[i] == g:
                _observe(pe, geo, pose, strokes[i], approach[i], has_approach, sun[i], spot[i], basis[i], True,
                         res[i], jac[i], work)
    rows = 2 * k + n_x
    r = np.zeros(rows)
    jj = np.zeros((rows, n_x))
    for i in range(k):
        for c in range(2):
            row = 2 * i + c
            v = res[i, c]
            if nr:
                for t in range(2):
                    d_rate = -age[i] * jac[i, c, tilt[t]] * rate_scale
                    v += d_rate * x[f + t]
                    jj[row, f + t] = d_rate * inv_sigma[row]
            r[row] = v * inv_sigma[row]
            for j in range(f):
                jj[row, j] = jac[i, c, free_idx[j]] * sig_prior[j] * inv_sigma[row]
            if epoch[i] > 0:
                col = f + nr + (epoch[i] - 1) * m
                for j in range(m):
                    jj[row, col + j] = jac[i, c, ep_idx[j]] * ep_scale[j] * inv_sigma[row]
    for j in range(n_x):
        r[2 * k + j] = x[j]
        jj[2 * k + j, j] = 1.0
    return r, jj


# ---------------------------------------------------------------------------------- robust loss
@numba.njit(cache=True, error_model="numpy")
def loss_weights(loss, z):
    """ρ'(z) and ρ'(z) + 2zρ''(z) of loss code ``loss`` (:data:`LOSSES`) (:func:`.fit_solver.loss_weights`)."""
    n = z.shape[0]
    w = np.empty(n)
    v = np.empty(n)
    for i in range(n):
        zi = z[i]
        if loss == 0:
            w[i], v[i] = 1.0, 1.0
        elif loss == 1:
            w[i], v[i] = (1.0 + zi) ** -0.5, (1.0 + zi) ** -1.5
        elif loss == 2:
            w[i] = 1.0 if zi <= 1.0 else max(zi, 1.0) ** -0.5
            v[i] = 1.0 if zi <= 1.0 else 0.0
        elif loss == 3:
            w[i], v[i] = 1.0 / (1.0 + zi), (1.0 - zi) / (1.0 + zi) ** 2
        else:
            w[i], v[i] = 1.0 / (1.0 + zi * zi), (1.0 - 3.0 * zi * zi) / (1.0 + zi * zi) ** 2
    return w, v


@numba.njit(cache=True, error_model="numpy")
def robust_cost(loss, r, f_scale):
    """½ Σ f_scale² ρ((r / f_scale)²) (:func:`.fit_solver.robust_cost`)."""
    total = 0.0
    for i in range(r.shape[0]):
        z = (r[i] / f_scale) ** 2
        if loss == 0:
            rho = z
        elif loss == 1:
            rho = 2.0 * (math.sqrt(1.0 + z) - 1.0)
        elif loss == 2:
            rho = z if z <= 1.0 else 2.0 * math.sqrt(max(z, 1.0)) - 1.0
        elif loss == 3:
            rho = math.log1p(z)
        else:
            rho = math.atan(z)
        total += rho
    return 0.5 * f_scale * f_scale * total


@numba.njit(cache=True, error_model="numpy")
def _norm(v):
    return math.sqrt(np.sum(v * v))


@numba.njit(cache=True, error_model="numpy")
def solve(x0, loss, f_scale, geo, strokes, approach, has_approach, sun, spot, basis, base, centre, free_idx,
          sig_prior, inv_sigma, age, rate_scale, epoch, n_groups, ep_idx, ep_scale, xtol, ftol, max_iter):
    """:func:`.fit_solver.gauss_newton` on :func:`fun_jac` (same steps, line search and stops;
    ``xtol``, ``ftol``, ``max_iter`` as there: :data:`XTOL`, :data:`FTOL`, :data:`MAX_ITER`). No
    default arguments: numba dispatches a call that omits some slowly.

    Returns ``(x, r, J, converged, nfev)`` with r and J at x."""
    args = (geo, strokes, approach, has_approach, sun, spot, basis, base, centre, free_idx, sig_prior, inv_sigma,
            age, rate_scale, epoch, n_groups, ep_idx, ep_scale)
    x = x0.copy()
    r, j = fun_jac(x, *args)
    nfev = 1
    cost = robust_cost(loss, r, f_scale)
    for _ in range(max_iter):
        z = (r / f_scale) ** 2
        w, v = loss_weights(loss, z)
        grad = j.T @ (w * r)
        two = not np.array_equal(v, w)
        n_steps = 2 if two else 1
        found = False
        least_gain = np.inf
        x_new = x
        r_new, j_new, cost_new = r, j, cost
        for step_kind in range(n_steps):
            vv = np.maximum(v if step_kind == 0 else w, _EPS)
            a = j.T @ (j * vv.reshape(-1, 1))
            try:
                dx = np.linalg.solve(a, -grad)
            except Exception:  # noqa: BLE001 - a singular system: no step
                return x, r, j, False, nfev
            if not np.all(np.isfinite(dx)):
                return x, r, j, False, nfev
            gain = -float(grad @ dx)
            if _norm(dx) <= xtol * (1.0 + _norm(x)) or gain <= ftol * (1.0 + cost):
                return x, r, j, True, nfev
            least_gain = min(least_gain, gain)
            step = 1.0
            floor = 1.0 if (two and step_kind == 0) else 1e-6
            while step >= floor:
                xt = x + step * dx
                rt, jt = fun_jac(xt, *args)
                nfev += 1
                ct = robust_cost(loss, rt, f_scale)
                if ct <= cost * (1.0 + 1e-13):
                    x_new, r_new, j_new, cost_new = xt, rt, jt, ct
                    found = True
                    break
                step *= 0.5
            if found:
                break
        if not found:
            return x, r, j, least_gain <= STALL_FTOL * (1.0 + cost), nfev
        x, r, j, cost = x_new, r_new, j_new, cost_new
    return x, r, j, False, nfev


# ---------------------------------------------------------------------------------- warm-up
def warm() -> float:
    """Compile (or load from the cache) every kernel once, on a small problem; returns the seconds
    it took (a few seconds cold, well under one from the cache)."""
    import time

    t0 = time.perf_counter()
    k = 3
    geo = np.zeros(GEO_SIZE)
    geo[0:3], geo[3:6], geo[6:9] = [0, 0, 1], [1, 0, 0], [0, 1, 0]
    _fill_axes(geo)
    geo[15:25] = [0.3, 0.3, 0.5, 0.5, 1.0, 1.0, 1.0, 1.0, 0.6, 0.6]
    geo[25] = 0.1
    strokes = np.full((k, 2), 10.0)
    sun = np.tile([0.0, 0.6, 0.8], (k, 1))
    spot = np.tile([0.0, 100.0, 50.0], (k, 1))
    basis = np.tile(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), (k, 1, 1))
    approach = np.zeros((k, 2))
    beam_residuals(np.zeros(P), geo, strokes, approach, False, sun, spot, basis, True)
    free_idx = np.arange(P, dtype=np.int64)
    ones = np.ones(P)
    epoch = np.zeros(k, dtype=np.int64)
    ep_idx = np.array([SO1, SO2, TE, TN], dtype=np.int64)
    for loss in range(len(LOSSES)):
        solve(np.zeros(P), loss, 1.0, geo, strokes, approach, True, sun, spot, basis, np.zeros(P), np.zeros(P),
              free_idx, ones, np.ones(2 * k), np.zeros(0), 0.0, epoch, 1, ep_idx, np.ones(4), XTOL, FTOL, MAX_ITER)
    return time.perf_counter() - t0


if __name__ == "__main__":  # an install's warm-up: python -m helicalib.calibration.fit_kernels
    print(f"fit kernels ready in {warm():.1f} s")
