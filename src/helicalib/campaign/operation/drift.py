"""Drift evidence of a re-check: is the measured error outside what the heliostat's fit predicts?

A re-check's first placement is made with the heliostat's newest fitted model. If nothing changed
since that fit, the angle between the beam the model predicts for the held strokes and the
direction to the observed spot lies within the fit's predicted band (parameter uncertainty plus
measurement noise, :func:`helicalib.calibration.uncertainty.check_against_fit`). Far outside it,
the heliostat has changed: settled, an actuator replaced, knocked by a storm. A present error
above the acceptance limit but inside the band is a model that was never good enough there
(refine it); one outside the band is drift (recalibrate it).
"""

from __future__ import annotations

import numpy as np

from helicalib.calibration.fit import SIGMA_MRAD
from helicalib.calibration.uncertainty import check_against_fit, unexplained_mrad
from helicalib.campaign import book as books
from helicalib.campaign import verdict as verdicts

DRIFT_ALPHA = 1e-3
"""p-value below which a re-check is evidence of drift (1 check in 1000 of an unchanged heliostat)."""


def drift_evidence(nominal, model, points: list, check, *, sigma_mrad: float = SIGMA_MRAD,
                   alpha: float = DRIFT_ALPHA, prior_mean=None, tilt_rate: bool = False,
                   earlier=None) -> dict | None:
    """Test a re-check's observation ``check`` against the fit over ``points`` (module docstring).

    Parameters
    ----------
    nominal : HeliostatModel of the heliostat (one row, nominal geometry)
    model : HeliostatModel, one row: the model the check placed it with (its newest fit)
    points : the fit's observations (:func:`helicalib.campaign.basis.stored_basis`)
    check : the check's observation (strokes, sun, spot, approach)
    prior_mean : (P,), optional, the fits' prior centre (after a confirmed drift: the model before it)
    tilt_rate : the fit has a pedestal tilt rate, as the model's own fit (:func:`helicalib.campaign.verdict.refit`)
    earlier : :class:`helicalib.campaign.book.Earlier`, optional, the points from before a confirmed drift, in
        epochs of their own (as the model's own fit)

    Returns
    -------
    dict with ``residual_mrad`` (magnitude), ``band_mrad`` (1-σ), ``p_value``, ``drift`` (bool), or
    None when there is no fit to test against.
    """
    if not points or check.spot_enu_m is None:
        return None
    _model, fit = verdicts.refit(nominal, points, model, prior_mean=prior_mean, tilt_rate=tilt_rate, earlier=earlier)
    if fit is None:
        return None
    strokes, sun, spot = verdicts.point_arrays([check])
    test = check_against_fit(model, fit.covariance, strokes, sun, spot, approach=verdicts.point_approaches([check]),
                             sigma_mrad=sigma_mrad, unexplained_mrad=unexplained_mrad(fit.rms_mrad, sigma_mrad),
                             alpha=alpha)
    return {"residual_mrad": round(float(np.linalg.norm(test.residual_mrad[0])), 3),
            "band_mrad": round(float(test.band_mrad[0]), 3), "p_value": float(f"{test.p_value[0]:.3g}"),
            "drift": bool(test.outside[0]), "fit_points": books.fit_size(points, earlier),
            "whitened": [round(float(x), 4) for x in test.whitened[0]]}


def trend_p_value(whitened) -> float:
    """p-value of K checks' whitened residuals (each standard normal in 2-D when nothing changed)
    leaning the same way: their mean ``m`` gives ``K·|m|²`` ~ χ²(2), ``p = exp(−K·|m|²/2)``."""
    w = np.asarray(whitened, dtype=float).reshape(-1, 2)
    m = w.mean(axis=0)
    return float(np.exp(-0.5 * len(w) * float(m @ m)))
