"""The figures of a simulated campaign, judged against the simulator's truth.

:func:`summarise` is the summary :func:`~helicalib.app.simulated.simulate_campaign` returns (and
``helicalib simulate`` prints and writes): acceptance, visits, first-shot errors, the calibrated
models against the true geometry over a year of sun, the fits' year-round predictions against the
truth (:func:`predicted_against_truth`) and the plant's true tracking with the corrections written
(:func:`plant_tracking_errors`); :func:`operation_summary` adds year-round operation's drift and
board-time figures; :class:`MonthlyTracking` the plant's true tracking per 30 days.
"""

from __future__ import annotations

import math

import numpy as np

from helicalib.campaign.loop import CampaignRunner
from helicalib.store.sqlite import Store

MONTH_DAYS = 30.0
"""A month of the monthly figures [plant days]."""
MONTHLY_STEP_S = 1800.0
"""Sampling step of the plant's true tracking for the monthly figures [s] (sun above the low band)."""


class MonthlyTracking:
    """The plant's true tracking of the receiver (:func:`plant_tracking_errors`), sampled each plant
    day with the runner's models at the day's end, and its RMS per :data:`MONTH_DAYS` from the start."""

    def __init__(self, cfg, sim, runner: CampaignRunner, start_s: float):
        self.cfg, self.sim, self.runner, self.start_s = cfg, sim, runner, start_s
        self.rows = [cfg.heliostat_index(h) for h in runner.state.ids]
        drifting = {e.heliostat_id for e in sim.truth.drift_events}
        self.steady = np.array([h not in drifting for h in runner.state.ids])  # of rows: no injected drift
        self.sq: dict[int, list[float]] = {}  # month -> [sum of squares, count]
        self.sq_steady: dict[int, list[float]] = {}

    def sample(self, t0_s: float, t1_s: float) -> None:
        if t1_s <= t0_s:
            return
        params = np.zeros((len(self.cfg.heliostats), self.runner.state.nominal.params.shape[1]))
        params[self.rows] = self.runner.calibrated_model().params
        errs = plant_tracking_errors(self.cfg, self.sim.truth, params, self.rows, t0_s, t1_s,
                                     self.runner.state.sun_table, step_s=MONTHLY_STEP_S)
        month = int((t0_s - self.start_s) // (MONTH_DAYS * 86400.0))
        steady = np.tile(self.steady, errs.size // max(len(self.rows), 1))
        for sq, e in ((self.sq, errs), (self.sq_steady, errs[steady] if steady.size == errs.size else errs[:0])):
            e = e[np.isfinite(e)]
            acc = sq.setdefault(month, [0.0, 0])
            acc[0] += float(np.sum(e**2))
            acc[1] += int(e.size)

    def rms_by_month(self, steady_only: bool = False) -> list[float | None]:
        """RMS per month over the campaign's heliostats (``steady_only``: those without an injected drift)."""
        sq = self.sq_steady if steady_only else self.sq
        if not sq:
            return []
        return [round(float(np.sqrt(sq[m][0] / sq[m][1])), 3) if m in sq and sq[m][1] else None
                for m in range(max(sq) + 1)]


def operation_summary(cfg, runner: CampaignRunner, sim, store: Store, campaign_id: int, start_s: float,
                      end_s: float) -> dict:
    """Year-round operation's figures against the simulator's truth.

    * ``drift_detected``: heliostats of the campaign with an injected drift (truth) whose drift was
      confirmed after it began; ``drift_false_alarms``: confirmations without one (or before it);
    * ``drift_median_days_to_fix``: median over the drifted heliostats of the days from the drift's
      start to their acceptance after the confirmation (the verdict of record, whose limit is 1.2 mrad);
      one not yet accepted again counts as never (None when half of them are not);
    * ``board_time_share_after_commissioning``: the boards' time in visits after commissioning (the
      first time 95 % of the heliostats were accepted), over the boards' time with the sun above the
      low band since then (None when never commissioned);
    * ``checks``: operation checks started.
    """
    from helicalib.campaign.operation import rules as op_rules

    ids = set(runner.state.ids)
    truth = {e.heliostat_id: e for e in sim.truth.drift_events if e.start_s < end_s and e.heliostat_id in ids}
    detected, false_alarms, days = set(), 0, []
    for d in runner.ops.drifts:
        e = truth.get(d["heliostat_id"])
        if e is not None and d["confirmed_s"] >= e.start_s:
            detected.add(d["heliostat_id"])
        else:
            false_alarms += 1
    for hid, e in truth.items():
        fixed = [d.get("fixed_s") for d in runner.ops.drifts
                 if d["heliostat_id"] == hid and d["confirmed_s"] >= e.start_s and d.get("fixed_s") is not None]
        days.append(op_rules.days_to_fix(e.start_s, min(fixed) if fixed else None))
    median = float(np.median(days)) if days else None
    commissioned = commissioning_time(store, campaign_id, len(runner.state.ids))
    share = None
    if commissioned is not None and commissioned < end_s:
        busy = sum(min(v.ended_s if v.ended_s is not None else end_s, end_s) - max(v.started_s, commissioned)
                   for v in store.visits(campaign_id=campaign_id)
                   if (v.ended_s if v.ended_s is not None else end_s) > commissioned)
        open_s = _operating_hours(cfg, commissioned, end_s) * 3600.0 * len(cfg.targets)
        share = round(busy / open_s, 4) if open_s > 0 else None
    return {"drift_detected": len(detected), "drift_false_alarms": false_alarms,
            "drift_median_days_to_fix": None if median is None or not math.isfinite(median) else round(median, 2),
            "drift_days_to_fix": [None if not math.isfinite(x) else round(x, 2) for x in days],
            "commissioned_day": None if commissioned is None else round((commissioned - start_s) / 86400.0, 3),
            "board_time_share_after_commissioning": share, "checks": runner.ops.checks}


COMMISSIONED_SHARE = 0.95
"""Share of the heliostats accepted at which commissioning counts as done (the operation figures)."""


def commissioning_time(store: Store, campaign_id: int, n_heliostats: int) -> float | None:
    """Plant time at which :data:`COMMISSIONED_SHARE` of the heliostats were first accepted at once."""
    need = math.ceil(COMMISSIONED_SHARE * n_heliostats)
    state: dict[str, bool] = {}
    count = 0
    for v in sorted(store.verdicts(campaign_id=campaign_id), key=lambda v: (v.time_s, v.id)):
        was = state.get(v.heliostat_id, False)
        state[v.heliostat_id] = bool(v.accepted)
        count += int(bool(v.accepted)) - int(was)
        if count >= need:
            return float(v.time_s)
    return None


def summarise(cfg, runner: CampaignRunner, sim, start_s: float, end_s: float) -> dict:
    """The campaign's figures; ``true_sky_rms_mrad`` is the simulator's truth for the calibrated models
    over a year of sun positions, against the true geometry at ``end_s`` (after any drift)."""
    from helicalib.sim.evaluate import evaluate_models

    stats = runner.state.stats
    ids = runner.state.ids
    accepted = runner.accepted()
    hours = _operating_hours(cfg, start_s, end_s) - stats.stowed_s / 3600.0
    # first placements of the last 24 h of visits, by heliostats that already had a fitted model
    last_t = max((t for t, _e, _m in stats.first_errors), default=end_s)
    window = [(e, m) for t, e, m in stats.first_errors if t >= last_t - 86400.0 and e is not None]
    last_day = [e for e, m in window if m]
    rms = lambda x: round(float(np.sqrt(np.mean(np.square(x)))), 3) if x else None  # noqa: E731
    all_ids = [h.id for h in cfg.heliostats]
    params = np.zeros((len(all_ids), runner.state.nominal.params.shape[1]))
    rows = [cfg.heliostat_index(hid) for hid in ids]
    params[rows] = runner.calibrated_model().params

    accepted_rows = [cfg.heliostat_index(hid) for hid in accepted]

    # against the true geometry at the run's end: drift (slow, and the scenario's events) included;
    # both backlash settings in one pass over the sky, over the campaign's heliostats only
    evaluations = evaluate_models(sim.truth, params, backlash=("tracking", "none"), t_eval_s=end_s, rows=rows)
    # heliostats with an injected drift event that began during the run
    drifted_ids = {e.heliostat_id for e in sim.truth.drift_events if e.start_s < end_s}

    def sky_of(backlash: str) -> dict:
        ev = evaluations[backlash]
        with np.errstate(invalid="ignore"):
            errs = ev.errors_mrad[rows]
            flat = errs[np.isfinite(errs)]
            ok = ev.errors_mrad[accepted_rows]
            ok = ok[np.isfinite(ok)]
            f1 = ev.errors_formula1_mrad[rows]
            f1 = f1[np.isfinite(f1)]
            f1_ok = ev.errors_formula1_mrad[accepted_rows]
            f1_ok = f1_ok[np.isfinite(f1_ok)]
        steady = errs[[i for i, hid in enumerate(ids) if hid not in drifted_ids]]
        steady = steady[np.isfinite(steady)]
        return {"rms_mrad": float(np.sqrt(np.mean(flat**2))) if flat.size else float("nan"),
                "undrifted_rms_mrad": float(np.sqrt(np.mean(steady**2))) if steady.size else None,
                "p95_mrad": float(np.percentile(flat, 95)) if flat.size else float("nan"),
                "accepted_rms_mrad": float(np.sqrt(np.mean(ok**2))) if ok.size else None,
                "formula1_rms_mrad": float(np.sqrt(np.mean(f1**2))) if f1.size else float("nan"),
                "formula1_accepted_rms_mrad": float(np.sqrt(np.mean(f1_ok**2))) if f1_ok.size else None}

    sky, geometry = sky_of("tracking"), sky_of("none")
    predicted = predicted_against_truth(cfg, runner, sim, params, evaluations["tracking"])
    day0 = max(start_s, end_s - 86400.0)
    tracking = plant_tracking_truth(cfg, sim.truth, params, rows, day0, day0 + 86400.0, runner.state.sun_table)
    untracked = plant_tracking_truth(cfg, sim.truth, np.zeros_like(params), rows, day0, day0 + 86400.0,
                                     runner.state.sun_table)
    return {
        "heliostats": len(ids),
        "accepted": len(accepted),
        "acceptance_rate": round(len(accepted) / max(len(ids), 1), 4),
        "visits": stats.visits,
        "valid_visits": stats.valid_visits,
        "visits_per_target_hour": round(stats.visits / max(hours * len(cfg.targets), 1e-9), 3),
        "spots_per_board": runner.state.spots_per_board, "shared_visits": stats.shared_visits,
        "peak_visits_on_a_board": stats.peak_on_board,
        "mean_iterations": round(float(np.mean(stats.iterations)), 3) if stats.iterations else None,
        "first_shot_rms_mrad": rms(last_day),
        "first_shot_median_mrad": round(float(np.median(last_day)), 3) if last_day else None,
        "first_shot_rms_all_mrad": rms([e for e, _m in window]),
        "true_sky_rms_mrad": round(float(sky["rms_mrad"]), 3),
        "true_sky_p95_mrad": round(float(sky["p95_mrad"]), 3),
        "true_sky_rms_undrifted_mrad": (None if sky["undrifted_rms_mrad"] is None
                                        else round(sky["undrifted_rms_mrad"], 3)),
        "true_sky_rms_no_backlash_mrad": round(float(geometry["rms_mrad"]), 3),
        "true_sky_rms_accepted_mrad": (None if sky["accepted_rms_mrad"] is None
                                       else round(sky["accepted_rms_mrad"], 3)),
        "true_sky_rms_formula1_mrad": round(float(sky["formula1_rms_mrad"]), 3),
        "true_sky_rms_formula1_accepted_mrad": (None if sky["formula1_accepted_rms_mrad"] is None
                                                else round(sky["formula1_accepted_rms_mrad"], 3)),
        **predicted,
        "true_tracking_rms_mrad": round(tracking["rms_mrad"], 3),
        "true_tracking_p95_mrad": round(tracking["p95_mrad"], 3),
        "true_tracking_uncorrected_rms_mrad": round(untracked["rms_mrad"], 3),
        "gated_hours": round(stats.gated_s / 3600.0, 2),
        "stowed_hours": round(stats.stowed_s / 3600.0, 2),
        "days": round((end_s - start_s) / 86400.0, 3),
        "outcomes": dict(stats.outcomes),
        # the scenario's injected drift events of the campaign's heliostats that began during the run
        "drifted": len(drifted := [e for e in sim.truth.drift_events if e.start_s < end_s and e.heliostat_id in ids]),
        "drift_events": [e.to_dict() for e in drifted],
    }


PREDICTION_SAMPLE = 500
"""At most this many fitted heliostats (evenly spaced) enter the summary's year-round prediction figures."""


def predicted_against_truth(cfg, runner: CampaignRunner, sim, params: np.ndarray, ev) -> dict:
    """The fits' year-round predictions (:mod:`helicalib.calibration.uncertainty`) against the
    simulator's truth ``ev`` (:func:`~helicalib.sim.evaluate.evaluate_model`, the calibrated
    models over the year): how often the true year-round RMS lies inside the predicted 90 %
    interval, and the predicted against the true share of heliostats that exceed the acceptance
    limit (``acceptance.max_rms_mrad``, 1.2 mrad) somewhere on the year's path. Over at most :data:`PREDICTION_SAMPLE` fitted heliostats; the sun path
    every 14 days, every hour, sun above 5°."""
    from helicalib.calibration.fit import SIGMA_MRAD
    from helicalib.calibration.uncertainty import unexplained_mrad, year_prediction
    from helicalib.geometry.sun import year_sun_times

    fitted = [hid for hid in runner.state.ids if runner.state.book.h[hid].fit is not None]
    keys = ("predicted_year_rms_median_mrad", "predicted_interval_coverage", "predicted_exceed_share",
            "true_exceed_share", "predicted_heliostats")
    if not fitted:
        return dict.fromkeys(keys)
    pick = np.unique(np.linspace(0, len(fitted) - 1, min(len(fitted), PREDICTION_SAMPLE)).round().astype(int))
    hids = [fitted[i] for i in pick]
    rows = np.array([cfg.heliostat_index(h) for h in hids])
    fits = [runner.state.book.h[h].fit for h in hids]
    model = sim.truth.nominal.subset(rows).with_params(params[rows])
    year = int(np.datetime64(int(sim.truth.start_s), "s").astype("datetime64[Y]").astype(int) + 1970)
    _t, sun = year_sun_times(cfg.site, year, step_days=14.0, step_min=60.0)
    aims = np.array([cfg.target(cfg.heliostat(h).target).center_enu_m for h in hids])
    limit = float(cfg.acceptance.max_rms_mrad)  # the field's acceptance limit, 1.2 mrad by default
    pred = year_prediction(model, np.stack([f.covariance for f in fits]), sun, aims,
                           np.array([unexplained_mrad(f.rms_mrad, SIGMA_MRAD) for f in fits]), draws=200,
                           limit_mrad=limit)
    err = ev.errors_mrad[rows]
    seen = np.isfinite(err).any(axis=1)
    with np.errstate(invalid="ignore"):
        true_rms = np.full(len(rows), np.nan)
        true_rms[seen] = np.sqrt(np.nanmean(err[seen] ** 2, axis=1))
        true_exceed = np.zeros(len(rows), dtype=bool)
        true_exceed[seen] = np.nanmax(err[seen], axis=1) > limit
    ok = np.isfinite(true_rms) & np.all(np.isfinite(pred.interval_mrad), axis=1)
    inside = (pred.interval_mrad[ok, 0] <= true_rms[ok]) & (true_rms[ok] <= pred.interval_mrad[ok, 1])
    r = lambda x: None if not np.isfinite(x) else round(float(x), 3)  # noqa: E731
    return {"predicted_year_rms_median_mrad": r(np.median(pred.expected_rms_mrad[ok])) if ok.any() else None,
            "predicted_interval_coverage": r(np.mean(inside)) if ok.any() else None,
            "predicted_exceed_share": r(np.mean(pred.p_exceed[ok])) if ok.any() else None,
            "true_exceed_share": r(np.mean(true_exceed[ok])) if ok.any() else None,
            "predicted_heliostats": int(ok.sum())}


def _operating_hours(cfg, start_s: float, end_s: float) -> float:
    """Hours with the sun above the low band's lower edge between start and end."""
    from helicalib.geometry.sun import sun_at_site

    t = np.arange(start_s, end_s, 300.0)
    if t.size == 0:
        return 0.0
    el = sun_at_site(cfg.site, t).elevation_deg
    return float(np.count_nonzero(el >= cfg.acceptance.low_band_deg[0]) * 300.0 / 3600.0)


def plant_tracking_truth(cfg, truth, params: np.ndarray, rows, t0_s: float, t1_s: float, sun_table,
                         step_s: float = 300.0) -> dict:
    """RMS and 95th percentile of :func:`plant_tracking_errors` [mrad]."""
    flat = plant_tracking_errors(cfg, truth, params, rows, t0_s, t1_s, sun_table, step_s)
    return {"rms_mrad": float(np.sqrt(np.mean(flat**2))) if flat.size else float("nan"),
            "p95_mrad": float(np.percentile(flat, 95)) if flat.size else float("nan")}


def plant_tracking_errors(cfg, truth, params: np.ndarray, rows, t0_s: float, t1_s: float, sun_table,
                          step_s: float = 300.0) -> np.ndarray:
    """True error of the PLANT's own tracking of the receiver over ``[t0_s, t1_s)`` (simulator truth).

    The plant tracks with its nominal model plus the corrections helicalib writes: for each
    heliostat with calibrated ``params`` (N, P), the offset rewritten every
    :data:`~helicalib.campaign.verdict.TRACKING_REFRESH_S` for the sun half a period ahead (as the
    runner does); zero params give the uncorrected plant. Error: the angle between the true beam
    and the direction from the true mirror centre to the receiver aim [mrad], every ``step_s`` with
    the sun above the low band, over the heliostats ``rows``, with backlash as it sits while tracking.
    """
    from helicalib.campaign.verdict import TRACKING_REFRESH_S, tracking_corrections
    from helicalib.geometry import optics
    from helicalib.geometry.heliostat import tracking_approach
    from helicalib.sim.evaluate import TRACKING_LEAD_S

    rows = np.asarray(rows, dtype=int)
    nominal = truth.nominal.subset(rows)  # row by row independent: only the heliostats asked for
    calibrated = nominal.with_params(np.asarray(params, dtype=float)[rows])
    aim = np.asarray(cfg.tower.receiver_aim_enu_m, dtype=float)
    errs = []
    held: dict[float, np.ndarray] = {}  # the corrections of one refresh period serve each of its steps
    strokes, approach_all = np.zeros((truth.n, 2)), np.zeros((truth.n, 2))  # the field's rows, for truth.beam
    for t in np.arange(t0_s, t1_s, step_s):
        sun = sun_table.vector_enu(t)
        if np.degrees(np.arcsin(sun[2])) < cfg.acceptance.low_band_deg[0]:
            continue
        t_ref = t0_s + np.floor((t - t0_s) / TRACKING_REFRESH_S) * TRACKING_REFRESH_S + TRACKING_REFRESH_S / 2
        corr = held.get(float(t_ref))
        if corr is None:
            held.clear()
            corr = held[float(t_ref)] = np.nan_to_num(tracking_corrections(
                cfg, nominal, calibrated, sun_table.vector_enu(t_ref), sun_table.vector_enu(t_ref + TRACKING_LEAD_S)))
        nom = nominal.strokes_for_aim(sun, aim)
        if not np.all(nom.in_range):
            continue
        # backlash as it sits while tracking: each actuator last moved the way its strokes go next
        approach_all[rows] = tracking_approach(
            nom.strokes_mm, nominal.strokes_for_aim(sun_table.vector_enu(t + TRACKING_LEAD_S), aim).strokes_mm)
        strokes[rows] = nom.strokes_mm + corr
        beam = truth.beam(strokes, sun, t, approach=approach_all, jitter=False, rows=rows)
        want = optics.unit(aim - beam.origin_enu)
        errs.append(1000.0 * optics.angle_between_rad(beam.direction_enu, want))
    return np.concatenate(errs) if errs else np.array([])
