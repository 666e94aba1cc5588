"""The book's visit cap against drift: one operated run with the caps set, per drifted heliostat.

Runs the campaign and ranked operation on ``--field`` for ``--days`` from ``--start`` (fast
fidelity, drift on ``--drift-share`` of the heliostats, as ``bench_year.py``'s ``ranked`` policy),
with ``book.MAX_VISIT_POINTS`` set to ``--cap`` and ``book.MAX_VISIT_POINTS_AFTER_DRIFT`` to
``--cap-after-drift`` (and with ``--no-epochs``, ``book.EPOCHS_AFTER_DRIFT`` off: the points
before a drift leave the fits, as until version 2026-11-27). Prints the summary's figures and, for each heliostat with an injected drift,
its model's sky-wide error at the end (the simulator's truth at the last instant, over the year's sun
positions), the drift confirmations, and the same book refitted offline on its points after the
drift's end only (what a fit that saw the drift stop would have), and refitted on all its located
points thinned together to ``--cap`` with each drift epoch's own tilts and zero offsets
(``FitPoints.epoch`` of the fit; epochs from the run's drift confirmations, no prior centre; the runner's
own epoch fits keep the newest epoch under ``--cap-after-drift``). Keeps the run under ``--work``
and writes JSON (default ``benchmarks/out/bench_cap.json``).

    .venv/bin/python benchmarks/bench_cap.py --days 210 --cap 240 --cap-after-drift 30
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "out"


def main(argv=None) -> int:
    from helicalib.campaign import basis, book, verdict

    from bench_sky_budget import operated_args, operated_run

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    operated_args(ap, days=210.0)
    ap.add_argument("--drift-share", type=float, default=0.2)
    ap.add_argument("--cap", type=int, default=book.MAX_VISIT_POINTS)
    ap.add_argument("--cap-after-drift", type=int, default=book.MAX_VISIT_POINTS_AFTER_DRIFT)
    ap.add_argument("--no-epochs", action="store_true", help="drop the points before a drift from the fits")
    ap.add_argument("--work", type=Path, default=None, help="keep the run here (default under benchmarks/out)")
    ap.add_argument("--out", type=Path, default=OUT / "bench_cap.json")
    args = ap.parse_args(argv)

    book.MAX_VISIT_POINTS, book.MAX_VISIT_POINTS_AFTER_DRIFT = args.cap, args.cap_after_drift
    book.EPOCHS_AFTER_DRIFT = not args.no_epochs
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.sim.evaluate import evaluate_model
    from helicalib.sim.truth import TrueField
    from helicalib.store import Store

    work = args.work or OUT / f"cap_{args.cap}_{args.cap_after_drift}_{args.days:g}d"
    print(f"bench_cap: {args.field}, {args.days:g} days from {args.start}, drift on {args.drift_share:g}, "
          f"cap {args.cap} visits, {args.cap_after_drift} after a drift, "
          f"{'no epochs' if args.no_epochs else 'an epoch per drift'}; run in {work}", flush=True)
    cfg, scenario, start_s, result, wall = operated_run(args.field, args.days, args.start, args.seed,
                                                        args.drift_share, work)
    s, runner = result.summary, result.runner
    ids = [h.id for h in cfg.heliostats]
    params = np.array([runner.state.models[h].params[0] for h in ids])
    truth = TrueField(cfg, scenario.model_copy(update={"seed": args.seed}), start_s)
    t_end = runner.devices.clock.now_s()

    def sky(rows_params: np.ndarray) -> np.ndarray:
        ev = evaluate_model(truth, rows_params, backlash="tracking", t_eval_s=t_end)
        return np.sqrt(np.nanmean(ev.errors_mrad ** 2, axis=1))

    per = sky(params)
    day = lambda t: round((t - start_s) / 86400.0, 1)  # noqa: E731
    nominal = HeliostatModel.from_config(cfg, ids)
    drifted = []
    store = Store.open(result.database, work / "images", readonly=True)
    try:
        for e in truth.drift_events:
            i = ids.index(e.heliostat_id)
            points, centre, _earlier = basis.stored_basis(store, runner.campaign_id, e.heliostat_id)
            row = {"heliostat": e.heliostat_id, "kind": e.kind, "start_day": day(e.start_s), "end_day": day(e.end_s),
                   "sky_mrad": round(float(per[i]), 3), "book_visits": len({p.visit_id for p in points}),
                   "confirmed": [[day(d["since_s"]), day(d["confirmed_s"])] for d in runner.ops.drifts
                                 if d["heliostat_id"] == e.heliostat_id],
                   "after_end_sky_mrad": None}
            after = [p for p in points if p.capture_time_s >= e.end_s + 86400.0]
            if after and len(after) < len(points):
                one = nominal.subset([i])
                model, _fit = verdict.refit(one, after, one if centre is None else one.with_params(centre[None, :]),
                                           prior_mean=centre, tilt_rate=runner.ops.tilt_rate_of(e.heliostat_id))
                p2 = params.copy()
                p2[i] = model.params[0]
                row["after_end_sky_mrad"] = round(float(sky(p2)[i]), 3)
            row["epochs_sky_mrad"] = _epochs_sky(store, runner, nominal.subset([i]), e.heliostat_id, args.cap,
                                                 lambda p: sky(np.where(np.arange(len(ids))[:, None] == i, p, params))[i])
            drifted.append(row)
    finally:
        store.close()
    doc = {"benchmark": "cap", "field": args.field, "days": args.days, "start": args.start, "seed": args.seed,
           "cap": args.cap, "cap_after_drift": args.cap_after_drift, "epochs": not args.no_epochs, "wall_s": round(wall, 1),
           **{k: s.get(k) for k in ("true_sky_rms_mrad", "true_sky_rms_undrifted_mrad", "monthly_plant_tracking_rms_mrad",
                                    "accepted", "heliostats", "drifted", "drift_detected", "drift_false_alarms",
                                    "drift_median_days_to_fix", "board_time_share_after_commissioning", "checks")},
           "drifted_heliostats": drifted}
    print(f"  {wall:.0f} s wall; sky at the end {doc['true_sky_rms_mrad']} mrad (without injected drift "
          f"{doc['true_sky_rms_undrifted_mrad']}); monthly plant tracking {doc['monthly_plant_tracking_rms_mrad']}; "
          f"{doc['accepted']}/{doc['heliostats']} accepted; drifts found {doc['drift_detected']} of {doc['drifted']} "
          f"({doc['drift_false_alarms']} false), median {doc['drift_median_days_to_fix']} days to fix")
    for r in drifted:
        print(f"  {r['heliostat']} {r['kind']} days {r['start_day']}-{r['end_day']}: sky {r['sky_mrad']} mrad, "
              f"{r['book_visits']} visits in its book, confirmed (since, on) {r['confirmed']}; refitted on its "
              f"points after the drift's end only: {r['after_end_sky_mrad']}; on all its points with an "
              f"epoch per confirmation: {r['epochs_sky_mrad']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2))
    print(f"wrote {args.out}")
    return 0


def _epochs_sky(store, runner, nominal, hid: str, cap: int, sky_of) -> float | None:
    """The sky-wide error [mrad] (``sky_of(params)``) of ``hid``'s refit on all its located points
    (thinned to ``cap`` visits) with each epoch between the run's drift confirmations fitted with its
    own tilts and zero offsets, and the steady tilt rate if the run fitted one."""
    import math

    from helicalib.calibration.fit import FitOptions, FitPoints, fit_error_model
    from helicalib.campaign import book, verdict

    sinces = sorted(float(d["since_s"]) for d in runner.ops.drifts if d["heliostat_id"] == hid)
    points = book.book_points(store.observations(campaign_id=runner.campaign_id, heliostat_id=hid), -math.inf, cap)
    if not sinces or not points:
        return None
    t = np.array([p.capture_time_s for p in points])
    epoch = np.array([sum(s > tt for s in sinces) for tt in t])  # 0: since the newest confirmation
    strokes, sun, spot = verdict.point_arrays(points)
    age = (t.max() - t) / 86400.0 if runner.ops.tilt_rate else None
    fit = fit_error_model(nominal, FitPoints(strokes, sun, spot, approach=verdict.point_approaches(points), age_days=age,
                                             epoch=epoch),
                          FitOptions(loss=verdict.FIT_LOSS, n_suggestions=0))
    return round(float(sky_of(fit.params)), 3)


if __name__ == "__main__":
    raise SystemExit(main())
