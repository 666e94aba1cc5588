"""The campaign's verdicts on a heliostat: its refit, its acceptance, its tracking corrections.

:func:`refit` fits a heliostat's error model to the points its book holds; :func:`verdict` judges
it against the paper's acceptance; :func:`tracking_corrections` turns the calibrated models into
the stroke offsets the plant's tracking adds. Pure: the book's points and models in, models,
verdicts and arrays out.

Acceptance points and their errors (our reading of the paper's section 2.4, see docs/campaign.md):
a *point* is a valid visit (its last valid measurement: the heliostat's beam after the loop);
its *error* is how far the heliostat's model, fitted **without that visit**, puts the beam from
where it was seen (leave-one-visit-out): an honest, out-of-sample tracking error. In-sample
residuals of a 12-parameter fit to a handful of points would flatter every heliostat.
"""

from __future__ import annotations

import numpy as np

from helicalib.calibration import acceptance
from helicalib.calibration.fit import FitOptions, FitPoints, fit_error_model, leave_out_params
from helicalib.campaign.book import Book, Earlier, fit_size
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel, tracking_approach

FIT_LOSS = "soft_l1"
_BACKLASH = [em.index(n) for n in em.BACKLASH]


# ---------------------------------------------------------------------------------- fit
def refit(nominal: HeliostatModel, points: list, current: HeliostatModel, method: str = "fast",
          prior_mean: np.ndarray | None = None, tilt_rate: bool = False, earlier: Earlier | None = None,
          solver: str | None = None):
    """Refit one heliostat's error model to its valid points; returns (model, FitResult or None).

    The solver starts from ``current``'s parameters (the priors stay centred on the nominal
    heliostat, or on ``prior_mean`` (P,): after a confirmed drift, the model from before it), so a
    refit after one more point takes a few steps instead of a whole descent. ``method``: the fit's
    solver (:data:`helicalib.calibration.fit.FIT_METHODS`; the fast one by default, the same minimum
    as ``"reference"``). ``tilt_rate`` (year-round operation): the fit adds a steady pedestal tilt rate
    and fits each point with the tilts of its time (``age_days`` of
    :class:`helicalib.calibration.fit.FitPoints`, ages counted from the newest point), so points
    of past seasons stay consistent with a settling foundation; the model returned is the heliostat
    as of the newest point. ``earlier`` (after a confirmed drift, :data:`.book.EPOCHS_AFTER_DRIFT`): the
    points from before it join the fit after ``points``, each with its epoch's own tilts and zero
    offsets; the model returned is the heliostat of ``points``' epoch. ``solver``: the fast method's
    implementation (:data:`helicalib.calibration.fit.SOLVERS`; default the compiled one)."""
    if not points:
        return current, None
    epoch = None
    if earlier is not None:
        epoch = np.concatenate([np.zeros(len(points), dtype=int), earlier.epoch])
        points = list(points) + list(earlier.points)
    strokes, sun, spot = point_arrays(points)
    approach = point_approaches(points)
    start = current if np.all(np.isfinite(current.params)) else nominal
    # parameters the fit leaves fixed (the dead bands when no approach is recorded) keep the start's values
    fixed_as_nominal = np.any(approach) or np.array_equal(start.params[:, _BACKLASH], nominal.params[:, _BACKLASH])
    model = nominal if fixed_as_nominal else nominal.with_params(start.params)
    age = None
    if tilt_rate:
        t = np.array([p.capture_time_s for p in points], dtype=float)
        age = (t.max() - t) / 86400.0
    fit = fit_error_model(model, FitPoints(strokes, sun, spot, approach=approach, age_days=age, epoch=epoch),
                          FitOptions(loss=FIT_LOSS, n_suggestions=0, method=method),
                          start=start.params[0], prior_mean=prior_mean, solver=solver)
    if not np.all(np.isfinite(fit.params)):
        return current, None
    return fit.model, fit


def point_arrays(points) -> tuple:
    """The strokes held (K, 2) [mm], suns (K, 3) and spots (K, 3) [m, ENU] of ``points``."""
    strokes = np.array([p.strokes_read_mm or p.strokes_cmd_mm for p in points], dtype=float)
    sun = np.array([p.sun_enu for p in points], dtype=float)
    spot = np.array([p.spot_enu_m for p in points], dtype=float)
    return strokes, sun, spot


def point_approaches(points) -> np.ndarray:
    """Each point's approach directions (K, 2) (0 where not recorded, e.g. an older database)."""
    return np.array([p.approach if getattr(p, "approach", None) is not None else (0, 0) for p in points], dtype=float)


def fit_record(fit) -> dict:
    return dict(model="geometric-backlash-v2", params=em.as_dict(fit.params), sigma=em.as_dict(fit.sigma),
                rms_mrad=float(fit.rms_mrad), n_points=int(len(fit.residual_mrad)))


def model_from_fit(model: HeliostatModel, fit_row) -> HeliostatModel:
    return model.with_params(em.from_dict(fit_row.params)[None, :])


# ---------------------------------------------------------------------------------- acceptance
def _visit_points(points: list) -> list:
    """One acceptance point per valid visit: its last valid measurement."""
    last: dict = {}
    for p in points:
        last[p.visit_id] = p
    return list(last.values())


def loo_errors_mrad(cfg, nominal: HeliostatModel, points: list, visit_points: list,
                    start: HeliostatModel | None = None, exact: bool = False, full=None,
                    method: str = "fast", earlier: Earlier | None = None) -> np.ndarray:
    """Leave-one-visit-out prediction error [mrad] of each visit point (formula 1 on its board).

    The model without a visit comes from one Gauss-Newton step from the fit to all points
    (:func:`~helicalib.calibration.fit.leave_out_params`; ``full``: that fit when the caller has
    it, e.g. the refit after the visit's last point), or with ``exact`` from a full refit per
    visit. Refits start from ``start`` (default nominal) and use the fit's solver ``method``.
    ``earlier``: the points from before a confirmed drift, in every fit (:func:`refit`); only the
    visits of ``points`` are left out."""
    start = start if start is not None else nominal
    if not visit_points:
        return np.zeros(0)
    if not exact:
        if full is None or len(full.residual_mrad) != fit_size(points, earlier):
            _model, full = refit(nominal, points, start, method, earlier=earlier)
        if full is not None and full.linearisation is not None:
            groups = [[k for k, p in enumerate(points) if p.visit_id == vp.visit_id] for vp in visit_points]
            return _prediction_errors_mrad(cfg, nominal, leave_out_params(full, groups), visit_points)
    params = []
    for vp in visit_points:
        rest = [p for p in points if p.visit_id != vp.visit_id]
        model, _fit = refit(nominal, rest, start, method, earlier=earlier)
        params.append(model.params[0])
    return _prediction_errors_mrad(cfg, nominal, np.array(params), visit_points)


def _prediction_errors_mrad(cfg, nominal: HeliostatModel, params: np.ndarray, visit_points: list) -> np.ndarray:
    """:func:`prediction_error_mrad` of each visit point for its own parameter row of ``params``
    (G, P), in one vectorised call."""
    model = nominal.repeat(len(visit_points)).with_params(params)
    strokes, sun, spot = point_arrays(visit_points)
    targets = [cfg.target(vp.target_id) for vp in visit_points]
    uv = model.spot_on_target(strokes, sun, targets, point_approaches(visit_points))
    predicted = np.array([t.uvw_to_enu(uv[g]) for g, t in enumerate(targets)])
    return np.asarray(optics.tracking_error_exact_mrad(spot, predicted, model.pivots_enu), dtype=float)


def prediction_error_mrad(model: HeliostatModel, obs, target) -> float:
    """How far ``model`` puts the beam from where ``obs`` saw it [mrad]: the angle at the pivot
    between the observed spot and the model's spot on the same board plane.

    Not T/GRLM formula (1) (distance on the board / slant distance), which the visit loop records:
    on a board seen obliquely, formula (1) grows by up to 1/cos(incidence) along the oblique
    direction (2.9× at 70°), so heliostats that see their board at a grazing angle would fail
    acceptance for the board's obliquity, not their pointing (docs/running.md)."""
    strokes, sun, spot = point_arrays([obs])
    predicted = target.uvw_to_enu(model.spot_on_target(strokes, sun[0], target, point_approaches([obs]))[0])
    return float(optics.tracking_error_exact_mrad(spot[0], predicted, model.pivots_enu[0]))


def verdict(cfg, book: Book, hid: str, nominal: HeliostatModel | None, now_s: float,
            start: HeliostatModel | None = None):
    """The heliostat's acceptance verdict now.

    Without ``nominal``: on its coverage and the points' own first-placement errors (what the
    planner needs of a heliostat not judged yet). With it, once the coverage is met: on the
    leave-one-visit-out errors (:func:`loo_errors_mrad`); ``start``, its current model, speeds
    up their refits, which start there."""
    points = book.points(hid)
    vps = _visit_points(points)
    days = book.days(now_s)
    first = np.array([p.error_mrad if p.error_mrad is not None else np.nan for p in vps], dtype=float)
    base = acceptance.evaluate_observations(vps, cfg.acceptance, days, now_s=now_s, errors_mrad=first)
    coverage_ok = all(r.startswith("RMS") for r in base.reasons)
    if nominal is None or not coverage_ok:
        return base
    # coverage met: judge the accuracy honestly, out of sample
    errs = loo_errors_mrad(cfg, nominal, points, vps, start, full=book.h[hid].fit, earlier=book.h[hid].earlier)
    return acceptance.evaluate_observations(vps, cfg.acceptance, days, now_s=now_s, errors_mrad=errs)


# ---------------------------------------------------------------------------------- tracking
TRACKING_REFRESH_S = 900.0
"""Plant seconds between rewrites of the tracking corrections of calibrated heliostats."""


def tracking_corrections(cfg, nominal: HeliostatModel, calibrated: HeliostatModel, sun_enu,
                         sun_later_enu=None) -> np.ndarray:
    """Stroke corrections [mm] that make the plant's nominal tracking follow the calibrated models.

    The plant tracks the receiver with its nominal model plus one constant offset per actuator
    (PLANT_INTERFACE). The offset that makes it point like the calibrated model is the stroke
    difference for the receiver aim at the sun ``sun_enu`` (3,); it drifts slowly with the sun, so
    the runner rewrites it every :data:`TRACKING_REFRESH_S` for the sun half a period ahead.
    With ``sun_later_enu`` (the sun a few minutes after ``sun_enu``), the calibrated strokes
    include the models' dead bands for each actuator's tracking direction (the sign of the
    nominal strokes' change between the two suns), as the plant's tracking moves it.

    Returns
    -------
    ndarray, shape (N, 2)
        NaN rows where either model's strokes (or nominal + correction) leave the stroke range:
        write nothing for those heliostats.
    """
    aim = np.asarray(cfg.tower.receiver_aim_enu_m, dtype=float)
    nom = nominal.strokes_for_aim(sun_enu, aim)
    approach = (None if sun_later_enu is None
                else tracking_approach(nom.strokes_mm, nominal.strokes_for_aim(sun_later_enu, aim).strokes_mm))
    cal = calibrated.strokes_for_aim(sun_enu, aim, approach)
    corr = cal.strokes_mm - nom.strokes_mm
    d = nominal.drives
    tracked = nom.strokes_mm + corr
    ok = cal.in_range & nom.in_range & np.all((tracked >= d.stroke_min_mm) & (tracked <= d.stroke_max_mm), axis=1)
    return np.where(ok[:, None], corr, np.nan)
