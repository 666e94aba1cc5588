"""Error-model fit for one heliostat: regularised, robust non-linear least squares with uncertainty.

Data: K observations, each the strokes the heliostat held, the sun vector, and the observed spot
centre X in ENU (on whatever target plane) (:class:`FitPoints`). Unknowns: the named error
parameters of :mod:`helicalib.geometry.error_model` (all, or those named in ``free``). How to fit
them is a :class:`FitOptions` (its fields are the names in backquotes below).

Residual (``residual_kind``):

* ``"beam"`` (default): the angle between the model's reflected beam ``r`` and the direction from
  the model's mirror centre to the observed spot, ``unit(X − M)`` — the tracking error the model
  would have made, seen from the heliostat [mrad], two components (right, up across the line of sight).
* ``"normal"``: the model's normal minus the observed normal (the one that reflects the sun to X)
  [mrad], two components. A normal error is half the beam error, so ``sigma_mrad`` is halved.

The problem is solved in prior-whitened variables ``x = p / prior_sigma``; the priors (mean 0,
the nominal heliostat) enter as pseudo-observations ``x``; data residuals are divided by the
measurement noise ``sigma_mrad``. A robust loss (default ``soft_l1``, scale ``f_scale_mrad``, the
losses of ``scipy.optimize.least_squares``) keeps outliers from dragging the fit. The cost is
minimised by a damped Gauss-Newton with the analytic Jacobian (the default), compiled
(:mod:`.fit_kernels`, ``solver="compiled"``) or in numpy (:mod:`.fit_solver`, ``solver="numpy"``, the
reference the compiled one is tested against), or with ``method="reference"`` by ``least_squares``
(TRF) with a central-difference Jacobian.
The covariance is the Gauss-Newton ``(JᵀJ)⁻¹`` at the solution, inflated by the a-posteriori
variance factor when the residuals are larger than ``sigma_mrad`` says.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from helicalib.calibration import fit_kernels, fit_solver
from helicalib.calibration.fit_solver import NAN_RESIDUAL_MRAD, beam_basis
from helicalib.calibration.fit_inputs import (EPOCH, EPOCH_PARAMS, EPOCH_SIGMA, FIT_METHODS, SIGMA_MRAD,
                                              TILT, TILT_RATE_SIGMA_MRAD_PER_DAY, FitOptions, FitPoints, Unknowns,
                                              unknowns)
from helicalib.calibration.fit_solver import loss_weights as _loss_weights
from helicalib.calibration.uncertainty import beam_jacobians_mrad
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.drives import angles_to_normal, strokes_to_angles


SOLVERS = ("compiled", "numpy")
"""The fast method's implementations: ``"compiled"`` (:mod:`.fit_kernels`, numba) and ``"numpy"``
(:mod:`.fit_solver`, the reference). Same steps and stopping rules; the compiled one covers the
``"beam"`` residual (a ``"normal"`` fit runs the numpy one)."""
FAST_SOLVER = "compiled"
"""The default of :func:`fit_error_model`'s ``solver``."""


@dataclass(frozen=True)
class Identifiability:
    """What the data determine.

    Attributes
    ----------
    data_fraction : {name: f} for free parameters, ``1 − σ_post² / σ_prior²``: 1 = data alone, 0 = prior alone
    determined : names with ``data_fraction >= 0.75`` (posterior σ at most half the prior's)
    prior_dominated : names with ``data_fraction < 0.25``
    correlated : (name_a, name_b, ρ) pairs with ``|ρ| > 0.9``
    suggestions : list of ``{"azimuth_deg", "elevation_deg", "sun_enu", "gain"}``, the candidate sun
        positions whose observation would shrink the summed prior-normalised variance most
        (``gain`` = that reduction), best first
    """

    data_fraction: dict[str, float]
    determined: tuple[str, ...]
    prior_dominated: tuple[str, ...]
    correlated: tuple[tuple[str, str, float], ...]
    suggestions: tuple[dict, ...]


@dataclass(frozen=True)
class Linearisation:
    """The fit's problem linearised at its solution, in the solver's whitened units (each free
    parameter divided by its prior σ; each residual by the noise σ): what
    :func:`leave_out_params` needs.

    Attributes
    ----------
    jacobian : (2K + F, F) d(residual)/d(x) of the data rows (2 per observation) and the prior rows
    residual : (2K + F,) residuals at the solution
    weights : (2K + F,) robust-loss weights of the gradient at the solution, ρ'(z) (1 for a plain
        least-squares row)
    hessian_weights : (2K + F,) those of the Gauss-Newton Hessian, ρ'(z) + 2 z ρ''(z)
    x : (F,) the solution; ``free_idx`` (F,) their columns in ``errors.PARAMETERS``; ``scale`` (F,) prior σ
    centre : (F,) the priors' centre of those columns (parameter = centre + x · scale)
    tilt_rate_scale : prior σ of the tilt rate [mrad/day] when the fit has one (its two unknowns
        are then the last two of ``x``, whitened by it, and ``jacobian``, ``residual`` and the weights
        have two more columns or prior rows); 0 without
    age_days : (K,) each observation's age [days] (with a tilt rate), else None
    epoch : (K,) each observation's epoch (0 the newest; with ``FitPoints.epoch``), else None; the
        offsets of the E older epochs are then the last ``E · len(EPOCH_PARAMS)`` unknowns of ``x``,
        epoch by epoch, each whitened by ``epoch_scale`` (len(EPOCH_PARAMS),)
    """

    jacobian: np.ndarray
    residual: np.ndarray
    weights: np.ndarray
    hessian_weights: np.ndarray
    x: np.ndarray
    free_idx: np.ndarray
    scale: np.ndarray
    centre: np.ndarray
    tilt_rate_scale: float = 0.0
    age_days: np.ndarray | None = None
    epoch: np.ndarray | None = None
    epoch_scale: np.ndarray | None = None


@dataclass(frozen=True)
class FitResult:
    """Fitted error model of one heliostat.

    Attributes
    ----------
    params : (P,) fitted parameters (order of ``errors.PARAMETERS``; fixed ones as given)
    covariance : (P, P) posterior covariance (zero rows/columns for fixed parameters)
    sigma : (P,) posterior standard deviations
    residual_mrad : (K,) residual magnitude per observation [mrad] (``residual_kind``)
    residual_vec_mrad : (K, 2) residual components [mrad]
    rms_mrad : RMS of ``residual_mrad``
    residual_kind : "beam" or "normal"
    free : names of the fitted parameters
    identifiability : :class:`Identifiability`
    model : the fitted HeliostatModel (N = 1)
    success, message, nfev : from the solver
    linearisation : :class:`Linearisation` at the solution
    tilt_rate_mrad_per_day : (2,) fitted pedestal tilt rate (east, north) [mrad/day] when the fit
        had one (``FitPoints.age_days``), else None; ``tilt_rate_sigma`` (2,) its posterior σ.
        ``params`` are then the parameters at age 0; an observation of age ``a`` was made with
        the pedestal tilts ``params − a · rate``
    epoch_offsets : (E + 1, P) with ``FitPoints.epoch``: each epoch's parameters less ``params`` (row 0,
        the newest epoch, zero; nonzero only in :data:`EPOCH_PARAMS`), else None
    """

    params: np.ndarray
    covariance: np.ndarray
    sigma: np.ndarray
    residual_mrad: np.ndarray
    residual_vec_mrad: np.ndarray
    rms_mrad: float
    residual_kind: str
    free: tuple[str, ...]
    identifiability: Identifiability
    model: object
    success: bool
    message: str
    nfev: int
    linearisation: Linearisation | None = None
    tilt_rate_mrad_per_day: np.ndarray | None = None
    tilt_rate_sigma: np.ndarray | None = None
    epoch_offsets: np.ndarray | None = None

    def params_of_epoch(self, epoch: int) -> np.ndarray:
        """The parameters (P,) of an earlier epoch (0: ``params``): ``params + epoch_offsets[epoch]``."""
        if epoch == 0 or self.epoch_offsets is None:
            return self.params.copy()
        return self.params + self.epoch_offsets[epoch]

    def as_dict(self) -> dict:
        """Parameters with σ by name, and the summary figures (plain data for JSON)."""
        return {
            "params": em.as_dict(self.params), "sigma": em.as_dict(self.sigma), "rms_mrad": self.rms_mrad,
            "residual_kind": self.residual_kind, "free": list(self.free),
            "determined": list(self.identifiability.determined),
            "prior_dominated": list(self.identifiability.prior_dominated),
        }


class _Problem:
    """Vectorised residuals for many parameter sets at once."""

    def __init__(self, model, strokes, sun, spot, kind, approach=None):
        self.model, self.kind = model, kind
        self.strokes = np.asarray(strokes, dtype=float).reshape(-1, 2)
        self.approach = None if approach is None else np.sign(np.asarray(approach, dtype=float)).reshape(-1, 2)
        self.sun = optics.unit(np.asarray(sun, dtype=float).reshape(-1, 3))
        self.spot = np.asarray(spot, dtype=float).reshape(-1, 3)
        self.k = len(self.strokes)
        p0 = model.pivots_enu[0]
        if kind == "beam":
            ref = optics.unit(self.spot - p0)
        elif kind == "normal":
            ref = optics.aim_normal(np.broadcast_to(p0, self.spot.shape), self.sun, self.spot,
                                    np.full(self.k, model.mirror_offset_m[0]))
        else:
            raise ValueError(f"residual_kind must be 'beam' or 'normal', not {kind!r}")
        self.basis = beam_basis(ref)

    def residuals(self, param_sets: np.ndarray) -> np.ndarray:
        """(M, P) parameter sets, or (M, K, P) one per observation → residuals (M, K, 2) [mrad]."""
        param_sets = np.asarray(param_sets, dtype=float)
        m = len(param_sets)
        if param_sets.ndim == 3:  # one parameter row per observation (a pedestal that tilts with time)
            rows_p = param_sets.reshape(m * self.k, -1)
            eff, piv = em.apply(self.model.drives.take(np.zeros(m * self.k, dtype=int)),
                                np.broadcast_to(self.model.pivots_enu[0], (m * self.k, 3)), rows_p)
        else:
            # the errors applied once per parameter set, then shared by its K observations
            eff, piv = em.apply(self.model.drives.take(np.zeros(m, dtype=int)),
                                np.broadcast_to(self.model.pivots_enu[0], (m, 3)), param_sets)
            rows = np.repeat(np.arange(m), self.k)
            eff, piv, rows_p = eff.take(rows), piv[rows], param_sets[rows]
        strokes = np.tile(self.strokes, (m, 1))
        if self.approach is not None:  # backlash: half the dead band against each actuator's approach
            strokes = strokes + em.backlash_shift_mm(rows_p, np.tile(self.approach, (m, 1)))
        sun = np.tile(self.sun, (m, 1))
        spot = np.tile(self.spot, (m, 1))
        n = angles_to_normal(eff, strokes_to_angles(eff, strokes))
        if self.kind == "beam":
            mc = optics.mirror_centre(piv, n, eff.mirror_offset_m)
            diff = optics.reflect(sun, n) - optics.unit(spot - mc)
        else:
            diff = n - optics.aim_normal(piv, sun, spot, eff.mirror_offset_m)
        basis = np.tile(self.basis, (m, 1, 1))
        res = 1000.0 * np.einsum("kij,kj->ki", basis, diff)
        res = np.where(np.isfinite(res), res, NAN_RESIDUAL_MRAD)
        return res.reshape(m, self.k, 2)


def fit_error_model(model, points: FitPoints, options: FitOptions = FitOptions(), *,
                    start: np.ndarray | None = None, prior_mean: np.ndarray | None = None,
                    solver: str | None = None) -> FitResult:
    """Fit the error model of one heliostat to its observations.

    Parameters
    ----------
    model : HeliostatModel with N = 1 (nominal geometry; its params give the values of fixed parameters
        and, without ``start``, the solver's starting point)
    points : :class:`FitPoints`, the K observations (and the modes their optional columns switch on:
        weights, a tilt rate, epochs)
    options : :class:`FitOptions`, how to fit them (priors, free parameters, loss, noise, solver,
        identifiability report)
    start : (P,), optional
        Parameters the solver starts from (only the free ones are used; e.g. the previous fit).
        Default ``model.params``. The priors stay centred on ``prior_mean`` either way.
    prior_mean : (P,), optional
        Centre of the priors (default 0: the nominal heliostat). A heliostat known to have changed
        (a confirmed drift) is fitted with its earlier model as the centre.
    solver : :data:`SOLVERS`, optional
        The fast method's implementation (default :data:`FAST_SOLVER`, the compiled one).
    """
    if len(model) != 1:
        raise ValueError(f"fit_error_model fits one heliostat; got a model of {len(model)}")
    if options.method not in FIT_METHODS:
        raise ValueError(f"method must be one of {', '.join(FIT_METHODS)}, not {options.method!r}")
    solver = FAST_SOLVER if solver is None else solver
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, not {solver!r}")
    approach = points.approach
    if approach is not None and not np.any(np.asarray(approach, dtype=float)):
        approach = None
    sigma_eff = options.sigma_mrad / 2.0 if options.residual_kind == "normal" else options.sigma_mrad
    prob = _Problem(model, points.strokes_mm, points.sun_enu, points.spot_enu, options.residual_kind, approach)
    u = unknowns(model, prob.k, points, options, approach, prior_mean)
    scale_k = np.ones(prob.k) if points.sigma_scale is None else np.asarray(points.sigma_scale, float).reshape(prob.k)
    row_sigma = sigma_eff * np.repeat(scale_k, 2)  # the σ of each residual component (2 per observation)
    x0 = u.x0(start)
    f_scale = options.f_scale_mrad / sigma_eff
    solved = None
    if options.method == "fast":
        solve = _solve_compiled if solver == "compiled" and prob.kind == "beam" else _solve_fast
        solved = solve(prob, u, x0, row_sigma, options.loss, f_scale)
    if solved is None:
        plain = u.age is None and u.epoch is None
        solved = _solve_reference(prob, u.params_of if plain else u.rows_of, x0, row_sigma, options.loss, f_scale)
    return _result(model, prob, u, solved, row_sigma, sigma_eff, f_scale, options)


def _result(model, prob: _Problem, u: Unknowns, solved: tuple, row_sigma: np.ndarray, sigma_eff: float,
            f_scale: float, options: FitOptions) -> FitResult:
    """The :class:`FitResult` of a solution ``solved`` (``(x, J, residuals (K, 2), success, message,
    nfev)``): the covariance, inflated by the a-posteriori variance factor, the identifiability
    report and the linearisation at the solution."""
    x, j, res_vec, success, message, nfev = solved
    f, nr = u.f, u.nr
    jd = j[: 2 * prob.k]
    info = j.T @ j
    cov_x = np.linalg.inv(info)
    # a-posteriori variance factor from the data residuals (only when there are spare degrees of freedom)
    dof = 2 * prob.k - float(np.trace(jd @ cov_x @ jd.T))
    chi2 = float(np.sum((res_vec.ravel() / row_sigma) ** 2))
    factor = max(1.0, chi2 / dof) if dof >= 3.0 else 1.0
    cov_x = cov_x * factor
    params = u.params_of(x[None, :])[0]
    cov = np.zeros((em.P, em.P))
    cov[np.ix_(u.free_idx, u.free_idx)] = cov_x[:f, :f] * np.outer(u.sig_prior, u.sig_prior)
    sigma = np.sqrt(np.diag(cov))
    fitted = model.with_params(params)
    ident = _identifiability(fitted, prob, u, params, cov_x[:f, :f], sigma_eff, options)
    rate = rate_sigma = offsets = None
    if u.age is not None:
        rate, rate_sigma = x[f:f + nr] * u.rate_scale, np.sqrt(np.diag(cov_x)[f:f + nr]) * u.rate_scale
    if u.epoch is not None:
        offsets = np.zeros((u.n_ep + 1, em.P))
        offsets[:, EPOCH] = u.offsets_of(x[None, :])[0]
    mag = np.linalg.norm(res_vec, axis=-1)
    r_all = np.concatenate([res_vec.ravel() / row_sigma, x])
    z = (r_all / f_scale) ** 2
    weights, hessian_weights = _loss_weights(options.loss, z)
    lin = Linearisation(jacobian=j, residual=r_all, weights=weights, hessian_weights=hessian_weights, x=x.copy(),
                        free_idx=u.free_idx, scale=u.sig_prior, centre=u.centre[u.free_idx].copy(),
                        tilt_rate_scale=u.rate_scale, age_days=u.age, epoch=u.epoch, epoch_scale=u.ep_scale)
    return FitResult(params=params, covariance=cov, sigma=sigma, residual_mrad=mag, residual_vec_mrad=res_vec,
                     rms_mrad=float(np.sqrt(np.mean(mag**2))) if len(mag) else float("nan"),
                     residual_kind=options.residual_kind, free=u.free_names, identifiability=ident, model=fitted,
                     success=success, message=message, nfev=nfev, linearisation=lin,
                     tilt_rate_mrad_per_day=rate, tilt_rate_sigma=rate_sigma, epoch_offsets=offsets)


def _solve_reference(prob, params_of, x0, row_sigma, loss, f_scale):
    """``least_squares`` (TRF) with a central-difference Jacobian in one vectorised call; ``row_sigma``
    (2K,) the σ of each residual component; ``params_of`` maps (M, F) unknowns to (M, P)
    parameter sets or (M, K, P) rows per observation. Returns ``(x, J at x (2K + F, F),
    residuals (K, 2) [mrad], success, message, nfev)``."""
    f = len(x0)

    def fun(x):
        r = prob.residuals(params_of(x[None, :]))[0].ravel() / row_sigma
        return np.concatenate([r, x])

    h = 1e-4

    def jac(x):
        xs = np.repeat(x[None, :], 2 * f, axis=0)
        xs[np.arange(f), np.arange(f)] += h
        xs[f + np.arange(f), np.arange(f)] -= h
        r = prob.residuals(params_of(xs)).reshape(2 * f, -1) / row_sigma
        jd = ((r[:f] - r[f:]) / (2 * h)).T
        return np.vstack([jd, np.eye(f)])

    sol = least_squares(fun, x0, jac=jac, loss=loss, f_scale=f_scale, method="trf", x_scale=1.0)
    x = sol.x
    return x, jac(x), prob.residuals(params_of(x[None, :]))[0], bool(sol.success), str(sol.message), int(sol.nfev)


def _solve_fast(prob, u: Unknowns, x0, row_sigma, loss, f_scale):
    """Damped Gauss-Newton with the analytic Jacobian (:mod:`.fit_solver`); None if it does not
    converge (the caller then solves with the reference solver). ``row_sigma`` (2K,): the σ of
    each residual component. With ``u.age`` (K,) [days] the next two unknowns are the tilt rate
    (whitened by ``u.rate_scale``), taken to first order: ``r(p − a·rate) ≈ r(p) − a · ∂r/∂tilt · rate``.
    With ``u.epoch`` (K,) the last unknowns are the earlier epochs' offsets (whitened by
    ``u.ep_scale``); each epoch's observations are evaluated with their own parameters."""
    params_of, free_idx, sig_prior = u.params_of, u.free_idx, u.sig_prior
    age, rate_scale, epoch, ep_scale = u.age, u.rate_scale, u.epoch, u.ep_scale
    n_x = len(x0)
    f = len(free_idx)
    nr = 2 if age is not None else 0
    m = len(EPOCH)
    n_groups = 1 if epoch is None or not len(epoch) else int(epoch.max()) + 1
    groups = [np.arange(prob.k)] if epoch is None else [np.flatnonzero(epoch == e) for e in range(n_groups)]
    bjs = [fit_solver.BeamJacobian(prob.model.drives, prob.model.pivots_enu[0], prob.strokes[g],
                                   None if prob.approach is None else prob.approach[g], prob.sun[g], prob.spot[g],
                                   prob.basis[g], prob.kind) if len(g) else None for g in groups]
    eye = np.eye(n_x)
    inv_sigma = 1.0 / row_sigma

    def fun_jac(x):
        p = params_of(x[None, :])[0]
        if epoch is None:
            res, jac = bjs[0].evaluate(p)
        else:
            res, jac = np.empty((prob.k, 2)), np.empty((prob.k, 2, em.P))
            for e, (g, bj) in enumerate(zip(groups, bjs)):
                if bj is None:  # an epoch without observations: its offsets rest on their prior
                    continue
                pe = p.copy()
                if e:
                    pe[EPOCH] += x[f + nr + (e - 1) * m: f + nr + e * m] * ep_scale
                res[g], jac[g] = bj.evaluate(pe)
        blocks = [jac[:, :, free_idx].reshape(-1, f) * sig_prior * inv_sigma[:, None]]
        if age is not None:
            d_rate = -age[:, None, None] * jac[:, :, TILT] * rate_scale  # (K, 2, 2) per whitened rate
            res = res + d_rate @ x[f:f + nr]
            blocks.append(d_rate.reshape(-1, 2) * inv_sigma[:, None])
        if epoch is not None and len(groups) > 1:
            d_ep = np.zeros((prob.k, 2, (len(groups) - 1) * m))
            for e, g in enumerate(groups[1:], start=1):
                d_ep[g, :, (e - 1) * m: e * m] = jac[g][:, :, EPOCH] * ep_scale
            blocks.append(d_ep.reshape(-1, d_ep.shape[-1]) * inv_sigma[:, None])
        return np.concatenate([res.ravel() * inv_sigma, x]), np.vstack([np.hstack(blocks), eye])

    with np.errstate(divide="ignore", invalid="ignore"):
        x, r, j, converged, nfev = fit_solver.gauss_newton(fun_jac, x0, loss, f_scale)
    if not converged or not np.all(np.isfinite(x)):
        return None
    return x, j, (r[: 2 * prob.k] * row_sigma).reshape(-1, 2), True, "Gauss-Newton converged", nfev


def _solve_compiled(prob, u: Unknowns, x0, row_sigma, loss, f_scale):
    """:func:`_solve_fast` in one compiled call (:func:`.fit_kernels.solve`, the ``"beam"`` residual);
    None if it does not converge."""
    if loss not in fit_kernels.LOSSES:
        raise ValueError(f"unknown loss {loss!r}; known: {', '.join(fit_kernels.LOSSES)}")
    k = prob.k
    has_approach = prob.approach is not None
    approach = prob.approach if has_approach else np.zeros((k, 2))
    age = np.zeros(0) if u.age is None else np.asarray(u.age, dtype=float)
    epoch = np.zeros(k, dtype=np.int64) if u.epoch is None else np.asarray(u.epoch, dtype=np.int64)
    n_groups = 1 if u.epoch is None or not k else int(epoch.max()) + 1
    ep_scale = np.ones(len(EPOCH)) if u.ep_scale is None else np.asarray(u.ep_scale, dtype=float)
    f = _kernel_array  # writable C-contiguous arrays: the one signature warm() compiled, never another mid-run
    x, r, j, converged, nfev = fit_kernels.solve(
        f(x0), fit_kernels.LOSSES.index(loss), float(f_scale),
        fit_kernels.pack_drive(prob.model.drives, prob.model.pivots_enu[0]), f(prob.strokes), f(approach), has_approach,
        f(prob.sun), f(prob.spot), f(prob.basis), f(u.base), f(u.centre), f(u.free_idx, np.int64), f(u.sig_prior),
        f(1.0 / row_sigma), f(age), float(u.rate_scale), f(epoch, np.int64), n_groups, f(EPOCH, np.int64),
        f(ep_scale), fit_kernels.XTOL, fit_kernels.FTOL, fit_kernels.MAX_ITER)
    if not converged or not np.all(np.isfinite(x)):
        return None
    return x, j, (r[: 2 * k] * row_sigma).reshape(-1, 2), True, "Gauss-Newton converged", nfev


def _kernel_array(a, dtype=float) -> np.ndarray:
    """``a`` as a writable C-contiguous array of ``dtype`` (copied only when it is not one already)."""
    return np.require(np.asarray(a, dtype=dtype), dtype, ["C", "W"])


def leave_out_params(fit: FitResult, groups: Sequence[Sequence[int]]) -> np.ndarray:
    """Parameters (G, P) of ``fit`` refitted without each group of observations (indices into the
    fit's observations), by one Gauss-Newton step from the full solution. A fit with a tilt rate
    gives each group's parameters at that group's time (the mean age of its observations), which
    is what predicting the left-out observations needs.

    Without group g the gradient at the full solution x̂ is ``−J_gᵀ W_g r_g``, so the Newton step
    is ``Δx = (A − J_gᵀ V_g J_g)⁻¹ J_gᵀ W_g r_g`` with ``A = Jᵀ V J`` over every row (data and
    prior; W = ρ' and V = ρ' + 2zρ'' the robust loss's gradient and Gauss-Newton Hessian weights
    at x̂). Exact for a linear problem. This fit's models are nearly linear over the parameters'
    small range: on 12 heliostats of a benchmark campaign its leave-one-visit-out errors agreed with
    full refits to 0.003 mrad on average (worst 0.11), at 1/13 of the CPU. That is what makes a
    leave-one-visit-out verdict affordable after every visit (test
    ``test_leave_out_params_match_full_refits``).
    """
    lin = fit.linearisation
    if lin is None:
        raise ValueError("this fit carries no linearisation")
    a = lin.jacobian.T @ (lin.jacobian * lin.hessian_weights[:, None])
    out = np.repeat(fit.params[None, :], len(groups), axis=0)
    f = len(lin.free_idx)
    for g, idx in enumerate(groups):
        rows = np.concatenate([[2 * int(i), 2 * int(i) + 1] for i in idx]) if len(idx) else np.zeros(0, dtype=int)
        jg, wg, vg, rg = lin.jacobian[rows], lin.weights[rows], lin.hessian_weights[rows], lin.residual[rows]
        dx = np.linalg.solve(a - jg.T @ (jg * vg[:, None]), jg.T @ (wg * rg))
        xg = lin.x + dx
        out[g, lin.free_idx] = lin.centre + xg[:f] * lin.scale
        nr = 2 if lin.age_days is not None else 0
        if lin.age_days is not None and len(idx):  # the tilts at the group's own time
            out[g, TILT] -= float(np.mean(lin.age_days[list(idx)])) * xg[f:f + nr] * lin.tilt_rate_scale
        if lin.epoch is not None and len(idx):  # and the offsets of its epoch (a visit lies in one)
            e = int(np.bincount(lin.epoch[list(idx)]).argmax())
            if e:
                m = len(EPOCH)
                out[g, EPOCH] += xg[f + nr + (e - 1) * m: f + nr + e * m] * lin.epoch_scale
    return out


def sky_grid(elevations_deg=(10, 20, 30, 45, 60, 80), azimuth_step_deg: float = 20.0) -> np.ndarray:
    """Candidate sun vectors (C, 3) on a grid over the sky."""
    from helicalib.geometry.sun import sun_vector_from_angles

    az, el = np.meshgrid(np.arange(0.0, 360.0, azimuth_step_deg), np.asarray(elevations_deg, dtype=float))
    return sun_vector_from_angles(az.ravel(), el.ravel())


def _identifiability(fitted, prob: _Problem, u: Unknowns, params, cov_x, sigma_eff, options: FitOptions
                     ) -> Identifiability:
    free_names, free_idx, sig_prior, kind = u.free_names, u.free_idx, u.sig_prior, options.residual_kind
    candidates, aim, n_best = options.candidate_sun_enu, options.aim_enu, options.n_suggestions
    var = np.diag(cov_x)
    frac = np.clip(1.0 - var, 0.0, 1.0)
    data_fraction = {n: float(v) for n, v in zip(free_names, frac)}
    sd = np.sqrt(var)
    corr = cov_x / np.outer(sd, sd)
    rows, cols = np.nonzero(np.triu(np.abs(corr) > 0.9, k=1))  # row by row, as a double loop over a < b
    pairs = tuple((free_names[a], free_names[b], float(corr[a, b])) for a, b in zip(rows, cols))
    suggestions: list[dict] = []
    if n_best <= 0:  # no suggestions asked for (the campaign's refits)
        return _identifiability_report(free_names, data_fraction, pairs, suggestions)
    cands = sky_grid() if candidates is None else np.asarray(candidates, dtype=float).reshape(-1, 3)
    aim_pt = np.mean(prob.spot, axis=0) if aim is None else np.asarray(aim, dtype=float)
    sol = fitted.repeat(len(cands)).strokes_for_aim(cands, aim_pt)
    ok = sol.in_range
    if ok.any():
        c_sun, c_strokes = cands[ok], sol.strokes_mm[ok]
        cprob = _Problem(fitted, c_strokes, c_sun, np.broadcast_to(aim_pt, c_sun.shape), kind)
        f, h = len(free_idx), 1e-4
        sets = np.repeat(params[None, :], 2 * f, axis=0)
        sets[np.arange(f), free_idx] += h * sig_prior
        sets[f + np.arange(f), free_idx] -= h * sig_prior
        r = cprob.residuals(sets) / sigma_eff  # (2f, C, 2)
        jc = np.transpose((r[:f] - r[f:]) / (2 * h), (1, 2, 0))  # (C, 2, f)
        jcc = jc @ cov_x  # (C, 2, f)
        s = np.eye(2) + jcc @ np.transpose(jc, (0, 2, 1))
        gain = np.einsum("cij,cji->c", np.linalg.solve(s, jcc), np.transpose(jcc, (0, 2, 1)))
        from helicalib.geometry.sun import angles_from_sun_vector

        az, el = angles_from_sun_vector(c_sun)
        for i in np.argsort(-gain)[:n_best]:
            suggestions.append({"azimuth_deg": float(az[i]), "elevation_deg": float(el[i]),
                                "sun_enu": [float(v) for v in c_sun[i]], "gain": float(gain[i])})
    return _identifiability_report(free_names, data_fraction, pairs, suggestions)


def _identifiability_report(free_names, data_fraction, pairs, suggestions) -> Identifiability:
    return Identifiability(
        data_fraction=data_fraction,
        determined=tuple(n for n in free_names if data_fraction[n] >= 0.75),
        prior_dominated=tuple(n for n in free_names if data_fraction[n] < 0.25),
        correlated=pairs, suggestions=tuple(suggestions))


def beam_spread_mrad(model, covariance: np.ndarray, sun_enu: np.ndarray, aim_enu: np.ndarray) -> np.ndarray:
    """Predicted 1-σ error [mrad] of N fitted models' beams at one sun position.

    For each heliostat, the strokes its model commands for ``aim_enu`` at ``sun_enu``, and the
    spread that the fit's parameter covariance gives the angle between the beam and the direction
    from the mirror centre to the aim point: ``sqrt(trace(J Σ Jᵀ))`` with J the (2, P) Jacobian
    across the beam. Large where the observations so far say little about this part of the sky.

    Parameters
    ----------
    model : HeliostatModel, N heliostats with their fitted parameters
    covariance : (N, P, P) parameter covariance of each fit (units of each parameter)
    sun_enu : (3,) unit sun vector
    aim_enu : (3,) or (N, 3) aim points [m]

    Returns
    -------
    ndarray (N,), NaN where the aim cannot be reached inside the stroke range.
    """
    n, p = len(model), em.P
    cov = np.asarray(covariance, dtype=float).reshape(n, p, p)
    jac, ok = beam_jacobians_mrad(model, np.asarray(sun_enu, dtype=float).reshape(1, 3), aim_enu)
    var = np.einsum("nip,npq,niq->n", jac[:, 0], cov, jac[:, 0])
    return np.where(ok[:, 0], np.sqrt(np.maximum(var, 0.0)), np.nan)


def predict_strokes(result: FitResult, sun_enu: np.ndarray, aim_enu: np.ndarray):
    """Strokes from the calibrated model for sun positions (M, 3) and aim (3,) or (M, 3) → AimSolution."""
    sun = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    return result.model.repeat(len(sun)).strokes_for_aim(sun, aim_enu)
