"""The fast solver of :func:`helicalib.calibration.fit.fit_error_model` (``method="fast"``).

Two parts:

* :class:`BeamJacobian`: the fit's residuals of one heliostat **and their analytic Jacobian**
  with respect to all 15 error parameters, in one pass over the K observations. The effective
  drive is built once per parameter set from 3 × 3 rotation matrices (the same rotations as
  :func:`helicalib.geometry.error_model.apply`); every parameter then moves the mirror normal by a
  rotation ``δn = Ω × n`` about an axis Ω carried through the drive (pedestal and canting
  angles, axis non-orthogonality), through the push-rod triangles' axis angles (stroke offsets,
  arm scales, dead bands), or moves the pivot. The beam residual's derivative follows from
  ``r = 2 (s·n) n − s`` and ``e = unit(X − M)``, ``M = P + offset · n``. For the ``"normal"``
  residual the observed normal's dependence on the pivot is taken by central differences.
* :func:`gauss_newton`: a damped Gauss-Newton (Newton with the robust loss's Gauss-Newton
  Hessian ``Jᵀ diag(ρ′ + 2zρ″) J``, as ``scipy.optimize.least_squares`` scales a robust problem)
  with a backtracking line search on the robust cost, run to a step of 1e-9 prior σ. It minimises
  the same cost as the reference solver (same residuals, priors, loss and scale) and so reaches
  the same minimum, without the finite-difference Jacobian and the trust-region bookkeeping.
"""

from __future__ import annotations

import math

import numpy as np

from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.drives import cross3

NAN_RESIDUAL_MRAD = 1000.0
"""Residual used where a parameter set makes a stroke impossible (keeps the solver finite)."""

_IDX = {name: em.index(name) for name in em.NAMES}
_ACT1 = [_IDX["stroke_offset_1_mm"], _IDX["arm_scale_1"], _IDX["backlash_1_mm"]]
_ACT2 = [_IDX["stroke_offset_2_mm"], _IDX["arm_scale_2"], _IDX["backlash_2_mm"]]
# rotations of the normal about Ω_k × n, k = 2..6 of BeamJacobian's axis stack (per mrad)
_ROT = [_IDX["pedestal_tilt_e_mrad"], _IDX["pedestal_tilt_n_mrad"], _IDX["pedestal_yaw_mrad"],
        _IDX["axis_nonorthogonality_mrad"], _IDX["canting_1_mrad"]]
_PIVOT = [_IDX["pivot_de_m"], _IDX["pivot_dn_m"], _IDX["pivot_du_m"]]
_DP = np.zeros((em.P, 3))
_DP[_PIVOT, :] = np.eye(3)
_PIVOT_STEP_M = 1e-4
"""Central-difference step of the observed normal's pivot derivative (``"normal"`` residual) [m]."""
EPS = np.finfo(float).eps
# A step that finds no lower cost while its predicted gain is below this share of the cost is at
# the minimum: the gain is then under the round-off of evaluating the cost (the reference solver
# stops at a relative gain of 1e-8, so this is still 100 times tighter).
STALL_FTOL = 1e-10


def beam_basis(d: np.ndarray) -> np.ndarray:
    """Two unit vectors (K, 2, 3) across unit directions d (K, 3): right (horizontal) and up (the
    two components of a beam-angle residual)."""
    d = np.asarray(d, dtype=float)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    zero = np.zeros_like(x)
    right = np.stack([y, -x, zero], axis=-1)  # d × up, written out (np.cross's own products, without its overhead)
    small = np.sqrt(np.add.reduce(right * right, axis=-1)) < 1e-9
    right[small] = np.stack([-z[small], zero[small], x[small]], axis=-1)  # d × north
    right = optics.unit(right)
    rx, ry, rz = right[..., 0], right[..., 1], right[..., 2]
    up = np.stack([ry * z - rz * y, rz * x - rx * z, rx * y - ry * x], axis=-1)
    return np.stack([right, up], axis=-2)


def rotation_matrix(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """3 × 3 matrix of the right-handed rotation about unit ``axis`` (3,) by ``angle_rad``
    (Rodrigues, the rotation of :func:`helicalib.geometry.drives.rotate`)."""
    x, y, z = (float(v) for v in axis)
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    t = 1.0 - c
    return np.array([[c + x * x * t, x * y * t - z * s, x * z * t + y * s],
                     [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
                     [z * x * t - y * s, z * y * t + x * s, c + z * z * t]])


def _unit_or(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    norm = float(np.linalg.norm(v))
    return v / norm if norm > 1e-12 else fallback


def _rotate_rows(axis: np.ndarray, cos: np.ndarray, sin: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors ``v`` (K, M, 3) or (M, 3) rotated about one axis (3,) by per-row angles (K,)."""
    c, s = cos[:, None, None], sin[:, None, None]
    return v * c + cross3(axis, v) * s + axis * (np.add.reduce(axis * v, axis=-1, keepdims=True) * (1.0 - c))


class BeamJacobian:
    """Residuals (K, 2) [mrad] of one heliostat's observations and their Jacobian (K, 2, P) with
    respect to the error parameters (per parameter unit), for one parameter set at a time.

    Parameters
    ----------
    drives : nominal DriveArrays of the heliostat (N = 1)
    pivot_enu : (3,) nominal pivot [m]
    strokes : (K, 2) held strokes [mm]; ``approach`` (K, 2) signs or None
    sun, spot : (K, 3) unit sun vectors, observed spots [m]
    basis : (K, 2, 3) the residual's two directions; ``kind`` "beam" or "normal"
    """

    def __init__(self, drives, pivot_enu, strokes, approach, sun, spot, basis, kind):
        self.kind = kind
        self.a1, self.a2, self.n0 = drives.axis1_enu[0], drives.axis2_enu[0], drives.normal0_enu[0]
        self.u = _unit_or(cross3(self.a2, self.n0), em.EAST)
        self.w = _unit_or(cross3(self.a1, self.a2), em.UP)
        self.ra, self.rb0 = drives.arm_fixed_m[0], drives.arm_moving_m[0]
        self.gamma0, self.sign, self.l0 = drives.gamma0_rad[0], drives.sign[0], drives.length_at_zero_m[0]
        self.offset = float(drives.mirror_offset_m[0])
        self.pivot0 = np.asarray(pivot_enu, dtype=float)
        self.strokes, self.sun, self.spot, self.basis = strokes, sun, spot, basis
        self.approach = np.zeros_like(strokes) if approach is None else approach
        self.has_approach = approach is not None

    def evaluate(self, params: np.ndarray, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals (K, 2) [mrad] for one parameter row (P,), and with ``jacobian`` their
        derivatives (K, 2, P) [mrad per parameter unit]; NaN residuals become
        ``NAN_RESIDUAL_MRAD`` with zero derivatives."""
        p = np.asarray(params, dtype=float)
        mrad = 1e-3
        # the effective drive (errors.apply): canting, non-orthogonality, then the pedestal R_e·R_n·R_u
        rc2 = rotation_matrix(self.a2, p[_IDX["canting_2_mrad"]] * mrad)
        rw = rotation_matrix(self.w, p[_IDX["axis_nonorthogonality_mrad"]] * mrad)
        re = rotation_matrix(em.EAST, p[_IDX["pedestal_tilt_e_mrad"]] * mrad)
        ren = re @ rotation_matrix(em.NORTH, p[_IDX["pedestal_tilt_n_mrad"]] * mrad)
        q = ren @ rotation_matrix(em.UP, p[_IDX["pedestal_yaw_mrad"]] * mrad)
        qrw = q @ rw
        n0 = rc2 @ (rotation_matrix(self.u, p[_IDX["canting_1_mrad"]] * mrad) @ self.n0)
        a1e, a2e = q @ self.a1, qrw @ self.a2
        # axis 2 turns the mirror normal and the canting-1 axis; axis 1 turns those, axis 2 and w
        zero_pose = np.stack([qrw @ n0, qrw @ (rc2 @ self.u)])
        # the push-rod triangles (drives.strokes_to_angles with the errors)
        b = p[[_IDX["backlash_1_mm"], _IDX["backlash_2_mm"]]]
        strokes = self.strokes + (-0.5 * b * self.approach) if self.has_approach else self.strokes
        length = (self.l0 + p[[_IDX["stroke_offset_1_mm"], _IDX["stroke_offset_2_mm"]]] / 1000.0) + strokes / 1000.0
        ra, rb = self.ra, self.rb0 * (1.0 + p[[_IDX["arm_scale_1"], _IDX["arm_scale_2"]]])
        cos_g = (ra * ra + rb * rb - length * length) / (2.0 * ra * rb)
        ok = (length > 0.0) & (cos_g > -1.0) & (cos_g < 1.0)
        g = np.arccos(np.where(ok, cos_g, 0.0))
        theta = np.where(ok, (g - self.gamma0) / self.sign, np.nan)
        c, s = np.cos(theta), np.sin(theta)
        m = _rotate_rows(a2e, c[:, 1], s[:, 1], zero_pose)
        k = len(theta)
        stack = np.concatenate([m, np.broadcast_to(np.stack([a2e, q @ self.w]), (k, 2, 3))], axis=1)
        turned = _rotate_rows(a1e, c[:, 0], s[:, 0], stack)
        n = turned[:, 0]
        pivot = self.pivot0 + p[_PIVOT]
        sun, spot = self.sun, self.spot
        if self.kind == "beam":
            mc = pivot + self.offset * n
            to_spot = spot - mc
            dist = np.sqrt(np.add.reduce(to_spot * to_spot, axis=-1, keepdims=True))
            e = to_spot / dist
            sn = np.add.reduce(sun * n, axis=-1, keepdims=True)
            diff = (2.0 * sn * n - sun) - e
        else:
            diff = n - optics.aim_normal(pivot, sun, spot, self.offset)
        res = 1000.0 * np.einsum("kij,kj->ki", self.basis, diff)
        bad = ~np.isfinite(res)
        res[bad] = NAN_RESIDUAL_MRAD
        if not jacobian:
            return res, None
        # δn = Ω × n for each rotation axis Ω carried to the observation's pose
        omega = np.concatenate([np.broadcast_to(a1e, (k, 1, 3)), turned[:, 2:3],
                                np.broadcast_to(np.stack([em.EAST, re @ em.NORTH, ren @ em.UP]), (k, 3, 3)),
                                turned[:, 3:4], turned[:, 1:2]], axis=1)
        t = cross3(omega, n[:, None, :])  # (K, 7, 3)
        sin_g = np.sqrt(np.maximum(1.0 - cos_g * cos_g, 0.0))
        dth_dl = length / (ra * rb * sin_g * self.sign)  # dθ/dℓ [rad/m]
        dth_drb = -(rb * rb - ra * ra + length * length) / (2.0 * ra * rb * rb * sin_g * self.sign)
        dn = np.zeros((k, em.P, 3))
        for act, cols in ((0, _ACT1), (1, _ACT2)):
            coef = np.stack([dth_dl[:, act] * 1e-3, dth_drb[:, act] * self.rb0[act],
                             dth_dl[:, act] * (-0.5e-3 * self.approach[:, act])], axis=-1)
            dn[:, cols] = coef[:, :, None] * t[:, act, None, :]
        dn[:, _IDX["canting_2_mrad"]] = mrad * t[:, 1]
        dn[:, _ROT] = mrad * t[:, 2:]
        if self.kind == "beam":
            sdn = np.einsum("kj,kpj->kp", sun, dn)
            d_move = self.offset * dn + _DP  # δM
            edm = np.einsum("kj,kpj->kp", e, d_move)
            d_diff = (2.0 * sdn[:, :, None] * n[:, None, :] + 2.0 * sn[:, :, None] * dn
                      + (d_move - edm[:, :, None] * e[:, None, :]) / dist[:, :, None])
        else:
            d_diff = dn - self._aim_normal_pivot_derivative(pivot)
        jac = 1000.0 * np.einsum("kij,kpj->kip", self.basis, d_diff)
        jac[bad] = 0.0
        return res, jac

    def _aim_normal_pivot_derivative(self, pivot: np.ndarray) -> np.ndarray:
        """d(observed normal)/d(pivot parameter) (K, P, 3) by central differences (zero elsewhere)."""
        h = _PIVOT_STEP_M
        shifted = pivot + np.concatenate([np.eye(3), -np.eye(3)]) * h  # (6, 3)
        k = len(self.sun)
        normals = optics.aim_normal(np.broadcast_to(shifted, (k, 6, 3)), self.sun[:, None, :],
                                    self.spot[:, None, :], self.offset)
        out = np.zeros((k, em.P, 3))
        out[:, _PIVOT] = (normals[:, :3] - normals[:, 3:]) / (2.0 * h)
        return out


# ---------------------------------------------------------------------------------- robust loss
def loss_weights(loss: str, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row weights of ``least_squares``' robust losses at z = (r / f_scale)²: ρ'(z) for the
    gradient and ρ'(z) + 2 z ρ''(z) for the Gauss-Newton Hessian (the cost is ½ Σ f_scale² ρ(z))."""
    one = np.ones_like(z)
    zc = np.maximum(z, 1.0)
    table = {"linear": lambda: (one, one),
             "soft_l1": lambda: ((1.0 + z) ** -0.5, (1.0 + z) ** -1.5),
             "huber": lambda: (np.where(z <= 1.0, 1.0, zc ** -0.5), np.where(z <= 1.0, 1.0, 0.0)),
             "cauchy": lambda: (1.0 / (1.0 + z), (1.0 - z) / (1.0 + z) ** 2),
             "arctan": lambda: (1.0 / (1.0 + z**2), (1.0 - 3.0 * z**2) / (1.0 + z**2) ** 2)}
    if loss not in table:
        raise ValueError(f"unknown loss {loss!r}; known: {', '.join(table)}")
    return table[loss]()


def robust_cost(loss: str, r: np.ndarray, f_scale: float) -> float:
    """``least_squares``' cost ½ Σ f_scale² ρ((r / f_scale)²)."""
    z = (r / f_scale) ** 2
    rho = {"linear": lambda: z,
           "soft_l1": lambda: 2.0 * (np.sqrt(1.0 + z) - 1.0),
           "huber": lambda: np.where(z <= 1.0, z, 2.0 * np.sqrt(np.maximum(z, 1.0)) - 1.0),
           "cauchy": lambda: np.log1p(z),
           "arctan": lambda: np.arctan(z)}[loss]()
    return 0.5 * f_scale * f_scale * float(np.sum(rho))


# ---------------------------------------------------------------------------------- solver
def gauss_newton(fun_jac, x0: np.ndarray, loss: str, f_scale: float, *, xtol: float = 1e-8, ftol: float = 1e-14,
                 max_iter: int = 100):
    """Minimise ``½ Σ f_scale² ρ((r(x)/f_scale)²)`` from ``x0``.

    ``fun_jac(x)`` → (r (R,), J (R, F)). Each step solves ``Jᵀ V J Δ = −Jᵀ W r`` with W = ρ′ and
    V = max(ρ′ + 2zρ″, eps), the Gauss-Newton Hessian ``least_squares`` scales a robust problem
    with. Where that step raises the cost (far from the minimum, rows with large residuals have
    tiny V), the iteratively-reweighted step (V = W, never longer for ``soft_l1``) is tried, then
    halved until the cost does not grow (to round-off). Stops when the next step is below
    ``xtol · (1 + |x|)`` (in prior σ: far below anything a beam can show) or would lower the cost
    by less than ``ftol · (1 + cost)`` (the cost's round-off; the reference solver's ``ftol`` is 1e-8).
    Where no step lowers the cost, it has converged if the steps' predicted gain is below
    ``STALL_FTOL · (1 + cost)`` (the evaluation's own round-off hides a smaller gain), and has
    failed otherwise.

    Returns ``(x, r, J, converged, nfev)`` with r and J at x.
    """
    x = np.asarray(x0, dtype=float).copy()
    r, j = fun_jac(x)
    nfev = 1
    cost = robust_cost(loss, r, f_scale)
    for _ in range(max_iter):
        w, v = loss_weights(loss, (r / f_scale) ** 2)
        grad = j.T @ (w * r)
        steps = [(j, np.maximum(v, EPS))]
        if not np.array_equal(v, w):
            steps.append((j, np.maximum(w, EPS)))
        x_new = None
        least_gain = np.inf
        for jj, vv in steps:
            try:
                dx = np.linalg.solve(jj.T @ (jj * vv[:, None]), -grad)
            except np.linalg.LinAlgError:
                return x, r, j, False, nfev
            if not np.all(np.isfinite(dx)):
                return x, r, j, False, nfev
            # converged: a step too small to matter, or one whose predicted gain is below round-off
            if (np.linalg.norm(dx) <= xtol * (1.0 + np.linalg.norm(x))
                    or -float(grad @ dx) <= ftol * (1.0 + cost)):
                return x, r, j, True, nfev
            least_gain = min(least_gain, -float(grad @ dx))
            step = 1.0
            while step >= (1.0 if len(steps) > 1 and vv is steps[0][1] else 1e-6):
                r_new, j_new = fun_jac(x + step * dx)
                nfev += 1
                cost_new = robust_cost(loss, r_new, f_scale)
                if cost_new <= cost * (1.0 + 1e-13):
                    x_new = x + step * dx
                    break
                step *= 0.5
            if x_new is not None:
                break
        if x_new is None:
            # no step lowers the cost: at the minimum when what a step could gain is below the
            # cost's own evaluation round-off (summation order alone moves it by ~1e-12 relative)
            return x, r, j, least_gain <= STALL_FTOL * (1.0 + cost), nfev
        x, r, j, cost = x_new, r_new, j_new, cost_new
    return x, r, j, False, nfev
