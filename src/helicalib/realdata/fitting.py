"""Real-data (PAINT) side of ``helicalib fit``: the priors chosen for the PAINT records, the
leave-one-out driver and the reported error measures. The fitting itself is
:func:`helicalib.calibration.fit.fit_error_model` (the campaign's fitter), called by :func:`fit` with
``residual_kind="normal"``, a plain loss and these priors.

Residual of one observation: the mirror normal the model predicts for the recorded strokes minus
the normal that would have put the beam on the observed spot (``optics.aim_normal``, from the mirror
centre), two components [mrad] over the normal scatter ``sigma_meas_mrad``. Each free parameter adds
the prior residual ``p / prior_sigma``: with 6 records (12 numbers) and 13 parameters the priors decide
what the data cannot, so they are part of the method (see ``docs/realdata.md`` for the values chosen
and why).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from helicalib.calibration.fit import FitOptions, FitPoints, FitResult, fit_error_model
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel


def predicted_and_observed_normals(model: HeliostatModel, strokes_mm, sun_enu, spot_enu):
    """(predicted (K,3), observed (K,3)) normals of a one-heliostat model for K observations."""
    k = len(strokes_mm)
    rep = model.repeat(k) if len(model) == 1 else model
    n_pred = rep.normal(np.asarray(strokes_mm, dtype=float))
    n_obs = optics.observed_normal_from_spot(rep.pivots_eff_enu, optics.unit(sun_enu), np.asarray(spot_enu, float),
                                             rep.mirror_offset_m)
    return n_pred, n_obs


def normal_error_mrad(model: HeliostatModel, strokes_mm, sun_enu, spot_enu) -> np.ndarray:
    n_pred, n_obs = predicted_and_observed_normals(model, strokes_mm, sun_enu, spot_enu)
    return 1000.0 * optics.angle_between_rad(n_pred, n_obs)


def beam_error_m(model: HeliostatModel, strokes_mm, sun_enu, spot_enu, targets: Sequence) -> np.ndarray:
    """Distance [m] on each observation's target plane between the predicted and the observed spot."""
    k = len(strokes_mm)
    rep = model.repeat(k) if len(model) == 1 else model
    uv_pred = rep.spot_on_target(np.asarray(strokes_mm, float), optics.unit(sun_enu), list(targets))
    uv_obs = np.array([t.enu_to_uvw(p)[:2] for t, p in zip(targets, np.asarray(spot_enu, float))])
    return np.linalg.norm(uv_pred - uv_obs, axis=-1)


def fit(model: HeliostatModel, strokes_mm, sun_enu, spot_enu, prior_sigma: Mapping[str, float],
        sigma_meas_mrad: float = 1.0, loss: str = "linear") -> FitResult:
    """MAP fit of one heliostat with :func:`helicalib.calibration.fit.fit_error_model` (the one fitter).

    ``prior_sigma`` by name (units of each parameter; 0 = fixed at the model's value, i.e. left out of
    ``free``); ``sigma_meas_mrad`` is the scatter of one observation's *normal* error (the fitter's
    ``sigma_mrad`` is a beam-angle one, twice the normal one, so it is passed as ``2 · sigma_meas_mrad``
    with ``residual_kind="normal"``, whose residuals are the same as those of the former
    ``realdata.fitting.fit_map``); a plain (``linear``) loss, as with 6 records there is no outlier to
    down-weight.
    """
    sig = em.prior_sigma(prior_sigma)
    free = [n for n, s in zip(em.NAMES, sig) if s > 0]
    points = FitPoints(np.asarray(strokes_mm, float).reshape(-1, 2), np.asarray(sun_enu, float).reshape(-1, 3),
                       np.asarray(spot_enu, float).reshape(-1, 3))
    return fit_error_model(model, points, FitOptions(prior_sigma=dict(prior_sigma), free=free, loss=loss,
                                                     sigma_mrad=2.0 * sigma_meas_mrad, residual_kind="normal",
                                                     n_suggestions=0))


def identifiability(result: FitResult, prior_sigma: Mapping[str, float]) -> list[dict]:
    """Per parameter: posterior / prior sigma (1 = the data add nothing), the data fraction of
    ``fit_error_model``'s report, and the strongest correlation among the free parameters."""
    sig = em.prior_sigma(prior_sigma)
    cov = result.covariance
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    free = np.isin(np.array(em.NAMES), list(result.free))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    out = []
    for i, name in enumerate(em.NAMES):
        if not free[i]:
            out.append({"name": name, "free": False})
            continue
        c = np.nan_to_num(corr[i].copy())
        c[i] = 0.0
        c[~free] = 0.0
        j = int(np.argmax(np.abs(c)))
        out.append({"name": name, "free": True, "posterior_over_prior": float(sd[i] / sig[i]),
                    "data_fraction": result.identifiability.data_fraction[name],
                    "most_correlated_with": em.NAMES[j], "correlation": float(c[j])})
    return out


def leave_one_out(model: HeliostatModel, strokes_mm, sun_enu, spot_enu, targets: Sequence, **fit_kwargs) -> dict:
    """Fit on all records but one, predict the one left out; for every record in turn."""
    strokes = np.asarray(strokes_mm, dtype=float).reshape(-1, 2)
    sun = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    spot = np.asarray(spot_enu, dtype=float).reshape(-1, 3)
    k = len(strokes)
    normal, beam = np.full(k, np.nan), np.full(k, np.nan)
    for i in range(k):
        keep = np.arange(k) != i
        f = fit(model, strokes[keep], sun[keep], spot[keep], **fit_kwargs)
        normal[i] = normal_error_mrad(f.model, strokes[i:i + 1], sun[i:i + 1], spot[i:i + 1])[0]
        beam[i] = beam_error_m(f.model, strokes[i:i + 1], sun[i:i + 1], spot[i:i + 1], [targets[i]])[0]
    return {"normal_mrad": normal, "beam_m": beam}


REALDATA_PRIOR_SIGMA: dict[str, float] = {
    # angle-like terms that a heliostat's nominal parameters carry uncorrected (PAINT's nominal
    # state misses by 13 mrad on AA39 and 86 mrad on AA23): wide, so they do not bias the fit
    "stroke_offset_1_mm": 30.0,  # ≈ 90 mrad of axis angle at the 0.33 m lever
    "stroke_offset_2_mm": 30.0,
    "pedestal_tilt_e_mrad": 100.0,
    "pedestal_tilt_n_mrad": 100.0,
    "pedestal_yaw_mrad": 100.0,
    # mechanical tolerances of a built heliostat: a few mrad
    "axis_nonorthogonality_mrad": 3.0,
    "canting_1_mrad": 3.0,
    "canting_2_mrad": 3.0,
    # surveyed pivot: centimetres (a 2 cm pivot error is 0.2 mrad at 60 m: the data cannot see it)
    "pivot_de_m": 0.02,
    "pivot_dn_m": 0.02,
    "pivot_du_m": 0.02,
    # arm lengths: manufacturing tolerance 0.1 %
    "arm_scale_1": 0.001,
    "arm_scale_2": 0.001,
    # dead bands: an observations CSV records no approach direction, so the data cannot see them (fixed)
    "backlash_1_mm": 0.0,
    "backlash_2_mm": 0.0,
}
"""Priors used for the real (PAINT) records, chosen before looking at the leave-one-out figures from
the physics of the heliostat (see ``docs/realdata.md``): wide on the angle offsets and pedestal
orientation, tight on what 6 records cannot separate."""
