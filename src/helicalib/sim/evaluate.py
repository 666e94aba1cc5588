"""Judge a calibrated model honestly: its true pointing error over a year of sun positions.

For every sun position of the year above ``min_elevation_deg`` the *calibrated* model computes the
strokes that should put each heliostat on its aim point; the simulator's *true* heliostats
(hidden errors, gravity sag, drift at the evaluation time, and backlash as it sits while tracking:
each actuator's last motion in the direction the model's strokes move a few minutes later; no
repeatability or wind jitter, which a model cannot predict) then show where those strokes really
send the beam; the error is the angle between that beam and the direction to the aim point (T/GRLM
formula (1) on the board plane is kept alongside: on a board seen obliquely it overstates the
miss). A model with backlash parameters commands its strokes for that approach.
``backlash="none"`` leaves backlash out (the pure geometry) of the truth and of the model.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel, tracking_approach
from helicalib.geometry.sun import sun_at_site, year_sun_times

TRACKING_LEAD_S = 300.0
"""Seconds ahead at which the tracking direction of each actuator is read off the model's strokes."""


@dataclass(frozen=True)
class SkyEvaluation:
    """True tracking error of a model's strokes over the sky.

    Attributes
    ----------
    errors_mrad : (N, T) true pointing error per heliostat and sun position [mrad]: the angle
        between the true beam and the direction from the true mirror centre to the aim point; NaN
        where the model's strokes are out of range or the beam misses the target plane
    rms_mrad, p95_mrad : (N,) per heliostat over its valid sun positions [mrad]
    field_rms_mrad, field_p95_mrad : float, over all heliostats and sun positions [mrad]
    errors_formula1_mrad : (N, T) the same misses by T/GRLM formula (1) on the board plane (distance
        on the board / slant distance): larger by up to 1/cos(incidence) along the board's oblique
        direction, e.g. 2.9× at 70° from the board's normal
    field_formula1_rms_mrad : float, RMS of ``errors_formula1_mrad``
    times_s : (T,) the sun instants [UTC s]
    out_of_range_fraction : (N,) share of sun positions whose strokes the drive cannot reach
    """

    errors_mrad: np.ndarray
    rms_mrad: np.ndarray
    p95_mrad: np.ndarray
    field_rms_mrad: float
    field_p95_mrad: float
    times_s: np.ndarray
    out_of_range_fraction: np.ndarray
    errors_formula1_mrad: np.ndarray | None = None
    field_formula1_rms_mrad: float = float("nan")


def evaluate_model(truth, fitted, times_s: np.ndarray | None = None, sun_enu: np.ndarray | None = None,
                   aim_enu: np.ndarray | None = None, t_eval_s: float | None = None,
                   min_elevation_deg: float = 5.0, backlash: str = "tracking", rows=None) -> SkyEvaluation:
    """True tracking error of the strokes a calibrated model commands, over the sky.

    Parameters
    ----------
    truth : TrueField
        The simulator's hidden truth (``SimulatedPlant.truth``).
    fitted : HeliostatModel or ndarray (N, P)
        The calibrated model, or its error parameters (applied to the nominal field).
    times_s, sun_enu : (T,) [UTC s] and (T, 3), optional
        Sun positions; default :func:`~helicalib.geometry.sun.year_sun_times` of the truth's start year.
    aim_enu : (N, 3) [m], optional
        Aim points; default the centre of each heliostat's calibration target.
    t_eval_s : float, optional
        Plant time of the true geometry (drift); default the truth's start.
    backlash : "tracking" or "none"
        "tracking": each actuator has last moved in its tracking direction (the sign of the
        model's stroke change over the next :data:`TRACKING_LEAD_S`; needs ``times_s``); "none":
        no backlash.
    rows : sequence of int, optional
        Only these heliostats are evaluated (the others' rows are NaN, and the field figures are
        over these); default all.
    """
    return evaluate_models(truth, fitted, times_s, sun_enu, aim_enu, t_eval_s, min_elevation_deg,
                           (backlash,), rows)[backlash]


def evaluate_models(truth, fitted, times_s: np.ndarray | None = None, sun_enu: np.ndarray | None = None,
                    aim_enu: np.ndarray | None = None, t_eval_s: float | None = None,
                    min_elevation_deg: float = 5.0, backlash=("tracking", "none"), rows=None
                    ) -> dict[str, SkyEvaluation]:
    """:func:`evaluate_model` for several ``backlash`` settings in one pass over the sky (the
    model's strokes for each sun position are solved once for all of them); ``{backlash: SkyEvaluation}``,
    each exactly what :func:`evaluate_model` returns for it."""
    for b in backlash:
        if b not in ("tracking", "none"):
            raise ValueError(f"backlash must be 'tracking' or 'none', not {b!r}")
    model = fitted if isinstance(fitted, HeliostatModel) else truth.nominal.with_params(np.asarray(fitted, float))
    if len(model) != truth.n:
        raise ValueError(f"model has {len(model)} heliostats, the field {truth.n}")
    if sun_enu is None:
        year = int(np.datetime64(int(truth.start_s), "s").astype("datetime64[Y]").astype(int) + 1970)
        times_s, sun_enu = year_sun_times(truth.cfg.site, year, min_elevation_deg=min_elevation_deg)
    times_s = np.asarray(times_s, float)
    sun_enu = np.asarray(sun_enu, float).reshape(-1, 3)
    targets = [truth.cfg.target(h.target) for h in truth.cfg.heliostats]
    if aim_enu is None:
        aim_enu = np.array([t.center_enu_m for t in targets], dtype=float)
    aim_enu = np.asarray(aim_enu, dtype=float)
    sel = np.arange(truth.n) if rows is None else np.unique(np.asarray(rows, dtype=int))
    sub = model if rows is None else model.subset(sel)
    aims = aim_enu[sel]
    pivots = truth.nominal.pivots_enu[sel]
    # the rows of each board (the target planes the beams are intersected with), found once
    board_of = [targets[i] for i in sel]
    boards = {id(t): t for t in board_of}
    groups = [(t, np.flatnonzero([b is t for b in board_of])) for t in boards.values()]
    t_eval = truth.start_s if t_eval_s is None else float(t_eval_s)
    shape = (len(sel), len(sun_enu))
    errors = {b: np.full(shape, np.nan) for b in backlash}
    errors_f1 = {b: np.full(shape, np.nan) for b in backlash}
    outside = np.zeros(len(sel))
    sun_later = None
    if "tracking" in backlash:
        if len(times_s) != len(sun_enu):
            raise ValueError("backlash='tracking' needs the times of the sun positions (times_s)")
        sun_later = np.asarray(sun_at_site(truth.cfg.site, times_s + TRACKING_LEAD_S).vector_enu, float).reshape(-1, 3)
    dead_bands = sub.has_dead_bands
    for k, sun in enumerate(sun_enu):
        plain = sub.strokes_for_aim(sun, aims)
        for b in backlash:
            sol, approach = plain, None
            if b == "tracking":
                approach = tracking_approach(plain.strokes_mm, sub.strokes_for_aim(sun_later[k], aims).strokes_mm)
                if dead_bands:  # the model's own dead bands, for that arrival
                    sol = sub.strokes_for_aim(sun, aims, approach)
            strokes = np.zeros((truth.n, 2))
            strokes[sel] = np.where(sol.in_range[:, None], sol.strokes_mm, 0.0)
            full_approach = None
            if approach is not None:
                full_approach = np.zeros((truth.n, 2))
                full_approach[sel] = approach
            beam = truth.beam(strokes, sun, t_eval, approach=full_approach, jitter=False, rows=sel)
            hit = np.full((len(sel), 3), np.nan)
            for target, g in groups:
                hit[g] = optics.intersect_target(beam.origin_enu[g], beam.direction_enu[g], target)[1]
            angle = 1000.0 * optics.angle_between_rad(beam.direction_enu, aims - beam.origin_enu)
            err = np.where(np.all(np.isfinite(hit), axis=-1), angle, np.nan)
            errors[b][:, k] = np.where(sol.in_range, err, np.nan)
            errors_f1[b][:, k] = np.where(sol.in_range, optics.tracking_error_mrad(hit, aims, pivots), np.nan)
        outside += ~plain.in_range
    return {b: _evaluation(truth.n, sel, errors[b], errors_f1[b], times_s, outside / max(len(sun_enu), 1))
            for b in backlash}


def _evaluation(n: int, sel: np.ndarray, errs: np.ndarray, errs_f1: np.ndarray, times_s: np.ndarray,
                outside: np.ndarray) -> SkyEvaluation:
    """The evaluated rows ``sel``' errors (k, T) as a :class:`SkyEvaluation` of all ``n`` heliostats."""
    errors = np.full((n, errs.shape[1]), np.nan)
    errors[sel] = errs
    errors_f1 = np.full((n, errs.shape[1]), np.nan)
    errors_f1[sel] = errs_f1
    out = np.zeros(n)
    out[sel] = outside
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a heliostat with no valid sun position: NaN
        rms = np.sqrt(np.nanmean(errors**2, axis=1))
        p95 = np.nanpercentile(errors, 95, axis=1)
    flat = errs[np.isfinite(errs)]
    flat_f1 = errs_f1[np.isfinite(errs_f1)]
    return SkyEvaluation(
        errors_mrad=errors, rms_mrad=rms, p95_mrad=p95,
        field_rms_mrad=float(np.sqrt(np.mean(flat**2))) if flat.size else float("nan"),
        field_p95_mrad=float(np.percentile(flat, 95)) if flat.size else float("nan"),
        times_s=times_s, out_of_range_fraction=out,
        errors_formula1_mrad=errors_f1,
        field_formula1_rms_mrad=float(np.sqrt(np.mean(flat_f1**2))) if flat_f1.size else float("nan"),
    )
