"""Acceptance with uncertainty: what a heliostat's fit predicts for its error over the year.

The paper's verdict (``acceptance.py``) stays the verdict of record. Beside it, a fitted model's
parameter covariance says how far its beam may be off at sun positions it has not been measured
at. For each heliostat this module predicts, over a set of sun positions (normally the year's sun
path, e.g. every 7 days every 30 min with the sun above 5°):

* ``expected_rms_mrad``: the expected RMS over the sun path of the beam's angular error, from the
  linearised parameter uncertainty ``sqrt(mean_m trace(J_m Σ J_mᵀ) + u²)``;
* ``interval_mrad``: a central interval (default 90 %) of that year-round RMS over draws of the
  parameter error from the fit's posterior ``N(0, Σ)`` (linearised beams);
* ``p_exceed``: the share of those draws whose error exceeds the limit (1.2 mrad) at one or more
  sun positions of the path.

``J_m`` (2, P) is the Jacobian of the beam's angle across the beam with respect to the error
parameters, at the strokes the model commands for the aim at sun position m (as
:func:`helicalib.calibration.fit.beam_spread_mrad`). ``u`` [mrad] is an error no parameter explains
(unmodelled effects), added in quadrature at every sun position; :func:`unexplained_mrad` estimates
it from a fit's residuals. Without it the prediction covers the parameters' uncertainty only.

Pure numpy: no I/O, deterministic for a given seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helicalib.calibration.fit_solver import beam_basis
from helicalib.geometry import error_model as em
from helicalib.geometry import optics

LIMIT_MRAD = 1.2
"""The paper's acceptance limit [mrad], the default threshold of ``p_exceed``."""
_CHUNK_ELEMENTS = 4_000_000
"""Heliostats are predicted in chunks of at most this many squared errors (draws × sun positions × 2)."""


@dataclass(frozen=True)
class YearPrediction:
    """Predicted year-round beam error of N heliostats.

    Attributes
    ----------
    expected_rms_mrad : (N,) expected RMS over the sun path [mrad]
    interval_mrad : (N, 2) central interval of the year-round RMS over posterior draws [mrad]
    p_exceed : (N,) probability that the error exceeds ``limit_mrad`` somewhere on the path
    limit_mrad : the threshold of ``p_exceed`` [mrad]
    level : the interval's probability (e.g. 0.9)
    reachable : (N,) share of the sun positions at which the model reaches the aim in range
    """

    expected_rms_mrad: np.ndarray
    interval_mrad: np.ndarray
    p_exceed: np.ndarray
    limit_mrad: float
    level: float
    reachable: np.ndarray


def beam_jacobians_mrad(model, sun_enu: np.ndarray, aim_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians (N, M, 2, P) [mrad per parameter unit] of N models' beam angles at M sun positions.

    For each heliostat and sun position, the strokes its model commands for ``aim_enu``, and the
    derivative of the angle between the beam and the direction from the mirror centre to the aim,
    in two directions across the beam (horizontal, then up), by forward differences of 1e-3 prior σ.

    Parameters
    ----------
    model : HeliostatModel of N heliostats (their fitted parameters)
    sun_enu : (M, 3) unit sun vectors
    aim_enu : (3,) or (N, 3) aim points [m, ENU]

    Returns
    -------
    (jac (N, M, 2, P), in_range (N, M) bool); jac is 0 where the aim is out of the stroke range.
    """
    n = len(model)
    sun = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    m = len(sun)
    aim = np.broadcast_to(np.asarray(aim_enu, dtype=float), (n, 3))
    # rows ordered (heliostat, sun): the model of heliostat i repeated for its M sun positions
    big = model.repeat(m)
    suns = np.tile(sun, (n, 1))
    aims = np.repeat(aim, m, axis=0)
    sol = big.strokes_for_aim(suns, aims)
    jac = beam_angle_jacobians_mrad(big, np.where(sol.in_range[:, None], sol.strokes_mm, 0.0), suns, aims)
    jac = np.where(sol.in_range[:, None, None], jac, 0.0)
    return jac.reshape(n, m, 2, em.P), sol.in_range.reshape(n, m)


def beam_angle_jacobians_mrad(model, strokes_mm: np.ndarray, sun_enu: np.ndarray, point_enu: np.ndarray,
                              approach: np.ndarray | None = None) -> np.ndarray:
    """Jacobians (K, 2, P) [mrad per parameter unit] of the angle between K beams and the directions
    from their mirror centres to ``point_enu`` (K, 3), at held strokes (K, 2) [mm] and suns (K, 3),
    in two directions across the beam (horizontal, then up); forward differences of 1e-3 prior σ.
    ``model`` has K rows (one per beam)."""
    k, p = len(model), em.P
    h = 1e-3 * em.PRIOR_SIGMA
    params = np.repeat(model.params[:, None, :], p + 1, axis=1)
    params[:, 1:, :] += np.diag(h)[None, :, :]
    wide = model.repeat(p + 1).with_params(params.reshape(-1, p))
    rep = lambda a: np.repeat(np.asarray(a, dtype=float).reshape(k, -1), p + 1, axis=0)  # noqa: E731
    origin, direction = wide.beam(rep(strokes_mm), rep(sun_enu), None if approach is None else rep(approach))
    diff = (direction - optics.unit(rep(point_enu) - origin)).reshape(k, p + 1, 3)
    basis = beam_basis(direction.reshape(k, p + 1, 3)[:, 0, :])  # (K, 2, 3)
    return 1000.0 * np.einsum("kij,kpj->kip", basis, (diff[:, 1:] - diff[:, :1]) / h[None, :, None])


@dataclass(frozen=True)
class CheckTest:
    """A check's observations against what the fit predicts for them.

    Attributes
    ----------
    residual_mrad : (K, 2) observed minus predicted beam angle, across the beam [mrad]
    band_mrad : (K,) predicted 1-σ spread of the residual's magnitude, ``sqrt(trace S)`` [mrad]
    distance2 : (K,) squared Mahalanobis distance ``rᵀ S⁻¹ r`` (χ² with 2 degrees of freedom
        when nothing changed)
    p_value : (K,) probability of a distance at least this large when nothing changed, ``exp(−d²/2)``
    outside : (K,) bool, ``p_value < alpha``: outside the predicted band
    whitened : (K, 2) ``L⁻¹ r`` with ``S = L Lᵀ``: standard normal in each component when nothing
        changed (several checks leaning the same way add up: :mod:`helicalib.campaign.operation.rules`)
    """

    residual_mrad: np.ndarray
    band_mrad: np.ndarray
    distance2: np.ndarray
    p_value: np.ndarray
    outside: np.ndarray
    whitened: np.ndarray


def check_against_fit(model, covariance: np.ndarray, strokes_mm: np.ndarray, sun_enu: np.ndarray,
                      spot_enu: np.ndarray, *, approach: np.ndarray | None = None, sigma_mrad: float = 0.3,
                      unexplained_mrad: float = 0.0, alpha: float = 1e-3) -> CheckTest:
    """Test K check observations of one heliostat against its fit (drift detection).

    The residual ``r`` (2,) is the angle between the beam the fitted model predicts for the held
    strokes and the direction from its mirror centre to the observed spot. When nothing changed,
    ``r ~ N(0, S)`` with ``S = J Σ Jᵀ + (σ² + u²/2) I``: the fit's parameter uncertainty carried to
    this beam (J the (2, P) Jacobian, Σ the covariance), the measurement noise σ of each component
    and the unexplained error u shared by the two. A drift moves ``r`` out of that band.

    Parameters
    ----------
    model : HeliostatModel of one heliostat, its fitted parameters
    covariance : (P, P) the fit's parameter covariance
    strokes_mm : (K, 2) held strokes [mm]; sun_enu (K, 3); spot_enu (K, 3) observed spot centres [m, ENU]
    approach : (K, 2), optional, each actuator's last motion (±1) for the dead bands
    sigma_mrad : measurement noise of one beam-angle component [mrad]
    unexplained_mrad : error no parameter explains [mrad] (:func:`unexplained_mrad`)
    alpha : p-value below which a check is outside the band
    """
    strokes = np.asarray(strokes_mm, dtype=float).reshape(-1, 2)
    k = len(strokes)
    sun = np.asarray(sun_enu, dtype=float).reshape(k, 3)
    spot = np.asarray(spot_enu, dtype=float).reshape(k, 3)
    app = None if approach is None else np.asarray(approach, dtype=float).reshape(k, 2)
    rows = model.repeat(k)
    origin, direction = rows.beam(strokes, sun, app)
    r = 1000.0 * np.einsum("kij,kj->ki", beam_basis(direction), direction - optics.unit(spot - origin))
    jac = beam_angle_jacobians_mrad(rows, strokes, sun, spot, app)
    cov = np.asarray(covariance, dtype=float).reshape(em.P, em.P)
    s = np.einsum("kip,pq,kjq->kij", jac, cov, jac) + (sigma_mrad**2 + 0.5 * unexplained_mrad**2) * np.eye(2)
    d2 = np.einsum("ki,kij,kj->k", r, np.linalg.inv(s), r)
    p = np.exp(-0.5 * d2)
    whitened = np.linalg.solve(np.linalg.cholesky(s), r[..., None])[..., 0]
    return CheckTest(r, np.sqrt(np.trace(s, axis1=1, axis2=2)), d2, p, p < alpha, whitened)


def year_prediction(model, covariance: np.ndarray, sun_enu: np.ndarray, aim_enu: np.ndarray,
                    unexplained_mrad: np.ndarray | float = 0.0, *, limit_mrad: float = LIMIT_MRAD,
                    level: float = 0.9, draws: int = 400, seed: int = 0) -> YearPrediction:
    """Predict N fitted heliostats' beam error over the sun positions ``sun_enu`` (module docstring).

    Parameters
    ----------
    model : HeliostatModel of N heliostats with their fitted parameters
    covariance : (N, P, P) each fit's parameter covariance (units of each parameter)
    sun_enu : (M, 3) unit sun vectors (the year's sun path)
    aim_enu : (3,) or (N, 3) aim points [m, ENU]
    unexplained_mrad : float or (N,) error no parameter explains [mrad], added in quadrature
    limit_mrad : threshold of ``p_exceed`` [mrad]
    level : probability of the central interval
    draws : posterior draws per heliostat
    seed : seed of the draws (the same seed gives the same figures)
    """
    n, p = len(model), em.P
    cov = np.asarray(covariance, dtype=float).reshape(n, p, p)
    u2 = np.broadcast_to(np.square(np.asarray(unexplained_mrad, dtype=float)), (n,))
    sun = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    aim = np.broadcast_to(np.asarray(aim_enu, dtype=float), (n, 3))
    expected, p_exceed, reach = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n)
    interval = np.full((n, 2), np.nan)
    lo, hi = 0.5 * (1.0 - level), 0.5 * (1.0 + level)
    chunk = max(1, int(_CHUNK_ELEMENTS // max(draws * len(sun) * 2, 1)))  # bounded memory for large fields
    for a in range(0, n, chunk):
        rows = np.arange(a, min(n, a + chunk))
        jac, ok = beam_jacobians_mrad(model.subset(rows), sun, aim[rows])
        reach[rows] = ok.mean(axis=1)
        # expected mean square over the reachable sun positions: trace(J Σ Jᵀ)
        tr = np.einsum("nmip,npq,nmiq->nm", jac, cov[rows], jac)
        count = ok.sum(axis=1)
        # draws of the parameter error from N(0, Σ), Σ positive semi-definite (eigen square root);
        # one generator per heliostat, so a heliostat's figures do not depend on the chunking
        z = np.stack([np.random.default_rng([seed, int(i)]).standard_normal((draws, p)) for i in rows])
        c = cov[rows]
        w, v = np.linalg.eigh(0.5 * (c + np.swapaxes(c, 1, 2)))
        root = v * np.sqrt(np.clip(w, 0.0, None))[:, None, :]        # (n, P, P): Σ = root rootᵀ
        dp = np.einsum("npq,ndq->ndp", root, z)                       # (n, D, P)
        e2 = np.sum(np.square(np.einsum("nmip,ndp->ndmi", jac, dp)), axis=-1) + u2[rows, None, None]
        e2 = np.where(ok[:, None, :], e2, np.nan)                     # (n, D, M)
        some = count > 0
        if not some.any():
            continue
        r = rows[some]
        expected[r] = np.sqrt(np.sum(np.where(ok, tr, 0.0), axis=1)[some] / count[some] + u2[r])
        rms = np.sqrt(np.nanmean(e2[some], axis=2))                   # (n', D)
        worst = np.sqrt(np.nanmax(e2[some], axis=2))
        interval[r] = np.stack([np.quantile(rms, lo, axis=1), np.quantile(rms, hi, axis=1)], axis=1)
        p_exceed[r] = np.mean(worst > limit_mrad, axis=1)
    return YearPrediction(expected, interval, p_exceed, float(limit_mrad), float(level), reach)


def unexplained_mrad(residual_rms_mrad: float, sigma_mrad: float) -> float:
    """The error no parameter explains [mrad], from a fit's in-sample residual RMS (beam-angle
    magnitude) and the measurement noise σ of one beam-angle component: ``sqrt(max(0, rms² − 2σ²))``
    (pure noise gives a magnitude of mean square 2σ²). In-sample residuals are a little smaller
    than the noise they hold, so this leans low."""
    return float(np.sqrt(max(0.0, float(residual_rms_mrad) ** 2 - 2.0 * float(sigma_mrad) ** 2)))
