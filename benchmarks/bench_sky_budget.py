"""What holds an operated field's sky-wide error: measurement noise, or what the points cover.

Runs ``--days`` plant days of a simulated campaign and operation (the ``ranked`` rule, fast
fidelity, no injected drift) from ``--start`` on ``--field`` and keeps the database. Then it fits
every heliostat's stored valid points again, offline, four ways, and judges each against the
simulator's truth at the last observation, over the year's sun positions (the summary's
``true_sky_rms_mrad``):

* ``as run``: the points the runner's book kept (at most ``book.MAX_VISIT_POINTS`` visits),
  fitted as operation fits them (``verdict.refit`` with the tilt rate);
* ``all points``: every valid point, no cap;
* ``exact spots``: the kept points with each measured spot replaced by the heliostat's true,
  noise-free spot for the same strokes, sun, approach and time (no wind jitter, no stroke
  repeatability, no vision error): what the points' sun positions allow;
* ``exact spots, all points``;
* ``less the jitter``: the kept points' measured spots less the wind's jitter (the mean over each
  point's after frames): what is left is the stroke repeatability, the vision and anything
  systematic;
* ``exact spots + white noise``: the exact spots plus Gaussian noise of ``--white-mrad`` RMS (beam
  angle): whether the measured noise acts as white noise of its size.

The gap between ``as run`` and ``exact spots`` is the cost of the measurement noise. It also
prints that noise (measured spot against the noise-free one, as a beam angle), the part of it that
is the wind's jitter, and both by wind speed.

    .venv/bin/python benchmarks/bench_sky_budget.py --days 90
    .venv/bin/python benchmarks/bench_sky_budget.py --days 90 --check-frames 1   # checks of one frame

``--check-frames`` overrides ``operation.rules.CHECK_AFTER_FRAMES`` for the run (the build before
2026-11-26 took one frame per check). Writes ``benchmarks/out/bench_sky_budget.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sqlite3
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "out"
WIND_BINS = ((0, 2), (2, 4), (4, 6), (6, 10), (10, 30))


def operated_args(ap: argparse.ArgumentParser, days: float) -> None:
    """The options of :func:`operated_run`'s field, span and seed (the demo field from 1 June)."""
    ap.add_argument("--field", default=str(ROOT / "field_config" / "demo_north.yaml"))
    ap.add_argument("--days", type=float, default=days)
    ap.add_argument("--start", default="2026-06-01T00:00:00+06:18")
    ap.add_argument("--seed", type=int, default=1)


def operated_run(field: str, days: float, start: str, seed: int, drift_share: float, work: Path,
                 monthly_tracking: bool = True):
    """A campaign and ranked operation of ``field`` for ``days`` from ``start`` (fast fidelity, drift
    on ``drift_share``), its database under ``work``, with a progress line every 30 s. Returns
    ``(cfg, scenario, start_s, result, wall_s)``."""
    from helicalib.commands.simulate import with_drift_share
    from helicalib.config import load_field_config
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.sim.scenario import load_scenario
    from helicalib.app.simulated import SimulationOptions, simulate_campaign

    cfg = load_field_config(field)
    scenario = with_drift_share(load_scenario(None), drift_share, days)
    start_s = float(to_unix_seconds([parse_time(start)])[0])
    work.mkdir(parents=True, exist_ok=True)
    last = {"t": time.monotonic()}

    def progress(now_s: float) -> None:
        if time.monotonic() - last["t"] >= 30.0:
            last["t"] = time.monotonic()
            print(f"  day {(now_s - start_s) / 86400:.1f} of {days:g}", flush=True)

    t0 = time.perf_counter()
    result = simulate_campaign(cfg, work, SimulationOptions(days, seed=seed, scenario=scenario, start_s=start_s,
                                                            fidelity="fast", operation="ranked",
                                                            monthly_tracking=monthly_tracking), progress=progress)
    return cfg, scenario, start_s, result, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    operated_args(ap, days=90.0)
    ap.add_argument("--check-frames", type=int, default=None,
                    help="after frames per check for this run (default operation.rules.CHECK_AFTER_FRAMES)")
    ap.add_argument("--white-mrad", type=float, default=0.33,
                    help="RMS of the white noise added to the exact spots, as a beam angle (default 0.33 mrad)")
    ap.add_argument("--work", type=Path, default=None, help="keep the run here (default a folder under benchmarks/out)")
    ap.add_argument("--out", type=Path, default=OUT / "bench_sky_budget.json")
    args = ap.parse_args(argv)

    from helicalib.calibration.fit import FitOptions, FitPoints, fit_error_model
    from helicalib.campaign.operation import rules as op_rules
    from helicalib.campaign import book, verdict
    from helicalib.geometry import error_model as em
    from helicalib.geometry import optics
    from helicalib.sim.evaluate import evaluate_model
    from helicalib.sim.truth import TrueField
    from helicalib.store import Store

    if args.check_frames is not None:
        op_rules.CHECK_AFTER_FRAMES = int(args.check_frames)
    work = args.work or OUT / f"sky_budget_{args.days:g}d_{op_rules.CHECK_AFTER_FRAMES}f"
    print(f"bench_sky_budget: {args.field}, {args.days:g} days from {args.start}, ranked operation, "
          f"{op_rules.CHECK_AFTER_FRAMES} after frames per check; run in {work}", flush=True)
    cfg, scenario, start_s, result, run_wall = operated_run(args.field, args.days, args.start, args.seed, 0.0, work,
                                                             monthly_tracking=False)
    summary = result.summary
    print(f"  run: {run_wall:.0f} s wall; sky at the end {summary['true_sky_rms_mrad']} mrad, "
          f"{summary['accepted']}/{summary['heliostats']} accepted, {summary.get('checks', 0)} checks", flush=True)

    truth = TrueField(cfg, scenario.model_copy(update={"seed": args.seed}), start_s)
    store = Store.open(result.database, work / "images", readonly=True)
    try:
        campaign = store.campaigns()[-1]
        observations = list(store.observations(campaign_id=campaign.id))
    finally:
        store.close()
    t_end = max(o.capture_time_s for o in observations)
    ids = [h.id for h in cfg.heliostats]

    con = sqlite3.connect(f"file:{result.database}?mode=ro", uri=True)
    try:  # the visits that were checks (their stored "check" event), whose points average more frames
        checks = {vid: n for vid, n in con.execute(
            "SELECT json_extract(data_json, '$.visit_id'), json_extract(data_json, '$.after_frames') FROM events "
            "WHERE kind = 'check'")}
    finally:
        con.close()

    def beam_spot(i: int, o, jitter: bool) -> np.ndarray:
        """Heliostat ``i``'s true spot for observation ``o`` (no stroke repeatability); with ``jitter``
        the mean over the point's after frames (1 s apart, centred on its capture time), as measured."""
        strokes = np.asarray(o.strokes_read_mm or o.strokes_cmd_mm, dtype=float)
        approach = np.asarray(o.approach if o.approach is not None else (0, 0), dtype=float)
        frames = checks.get(o.visit_id, cfg.calibration.after_frames) if jitter else 1
        hits = []
        for k in range(frames):
            t = o.capture_time_s + k - (frames - 1) / 2.0
            beam = truth.beam(np.tile(strokes, (truth.n, 1)), np.asarray(o.sun_enu, dtype=float), t,
                              wind_ms=float(o.wind_ms or 0.0), approach=np.tile(approach, (truth.n, 1)), jitter=jitter,
                              rows=np.array([i]))
            hits.append(optics.intersect_target(beam.origin_enu, beam.direction_enu, cfg.target(o.target_id))[1][0])
        return np.mean(hits, axis=0)

    def fit(i: int, points: list, spots: np.ndarray | None) -> np.ndarray:
        strokes, sun, measured = verdict.point_arrays(points)
        t = np.array([p.capture_time_s for p in points], dtype=float)
        data = FitPoints(strokes, sun, measured if spots is None else spots, approach=verdict.point_approaches(points),
                         age_days=(t.max() - t) / 86400.0)
        return fit_error_model(truth.nominal.subset([i]), data,
                               FitOptions(loss=verdict.FIT_LOSS, n_suggestions=0)).params

    def white_noise(i: int, points: list, exact: dict) -> np.ndarray:
        """The exact spots plus Gaussian noise on the board, per component ``--white-mrad`` / √2 as a beam angle."""
        out = []
        for o in points:
            target = cfg.target(o.target_id)
            distance = float(np.linalg.norm(exact[id(o)] - truth.nominal.pivots_enu[i]))
            step = rng.normal(size=2) * args.white_mrad / math.sqrt(2.0) * 1e-3 * distance
            out.append(exact[id(o)] + step @ np.asarray(target.frame_enu, dtype=float)[:2])
        return np.array(out)

    rng = np.random.default_rng(args.seed)
    ways = ("as run", "all points", "exact spots", "exact spots, all points", "less the jitter",
            "exact spots + white noise")
    params = {w: np.zeros((truth.n, em.P)) for w in ways}
    noise, jitter, wind, rows, kept_visits, of_check = [], [], [], [], [], []
    for i, hid in enumerate(ids):
        points = sorted((o for o in observations if o.heliostat_id == hid and o.valid and o.spot_enu_m is not None
                         and all(map(math.isfinite, o.spot_enu_m))), key=lambda o: o.capture_time_s)
        if not points:
            continue
        kept = book.book_points(points)  # the book's cap, applied point by point as the runner does
        exact = {id(o): beam_spot(i, o, jitter=False) for o in points}
        shake = {}
        for o in points:
            distance = float(np.linalg.norm(np.asarray(o.spot_enu_m) - truth.nominal.pivots_enu[i]))
            shake[id(o)] = beam_spot(i, o, jitter=True) - exact[id(o)]
            noise.append(1000.0 * np.linalg.norm(np.asarray(o.spot_enu_m) - exact[id(o)]) / distance)
            jitter.append(1000.0 * np.linalg.norm(shake[id(o)]) / distance)
            wind.append(float(o.wind_ms or 0.0))
            of_check.append(o.visit_id in checks)
        params["as run"][i] = fit(i, kept, None)
        params["all points"][i] = fit(i, points, None)
        params["exact spots"][i] = fit(i, kept, np.array([exact[id(o)] for o in kept]))
        params["exact spots, all points"][i] = fit(i, points, np.array([exact[id(o)] for o in points]))
        params["less the jitter"][i] = fit(i, kept, np.array([np.asarray(o.spot_enu_m) - shake[id(o)] for o in kept]))
        params["exact spots + white noise"][i] = fit(i, kept, white_noise(i, kept, exact))
        rows.append(i)
        kept_visits.append(len({p.visit_id for p in kept}))
    noise, jitter, wind, of_check = np.array(noise), np.array(jitter), np.array(wind), np.array(of_check, dtype=bool)
    rms = lambda x: round(float(np.sqrt(np.mean(np.square(x)))), 3) if len(x) else None  # noqa: E731

    sky = {}
    for w in ways:
        ev = evaluate_model(truth, params[w], backlash="tracking", t_eval_s=t_end)
        sky[w] = round(float(np.sqrt(np.nanmean(ev.errors_mrad[rows] ** 2))), 3)
    by_wind = []
    for lo, hi in WIND_BINS:
        m = (wind >= lo) & (wind < hi)
        if m.any():
            by_wind.append({"wind_ms": [lo, hi], "points": int(m.sum()), "noise_rms_mrad": rms(noise[m]),
                            "jitter_rms_mrad": rms(jitter[m])})
    doc = {"benchmark": "sky_budget", "field": args.field, "days": args.days, "start": args.start, "seed": args.seed,
           "check_after_frames": op_rules.CHECK_AFTER_FRAMES, "heliostats": len(rows),
           "valid_points": int(len(noise)), "kept_visits_median": float(np.median(kept_visits)),
           "summary_true_sky_rms_mrad": summary["true_sky_rms_mrad"], "checks": summary.get("checks"),
           "board_time_share_after_commissioning": summary.get("board_time_share_after_commissioning"),
           "sky_rms_mrad": sky, "white_mrad": args.white_mrad, "noise_rms_mrad": rms(noise), "noise_median_mrad": round(float(np.median(noise)), 3),
           "jitter_rms_mrad": rms(jitter),
           "rest_rms_mrad": round(float(np.sqrt(max(np.mean(noise ** 2) - np.mean(jitter ** 2), 0.0))), 3),
           "by_wind": by_wind, "check_points": int(of_check.sum()), "check_noise_rms_mrad": rms(noise[of_check]),
           "check_jitter_rms_mrad": rms(jitter[of_check]), "campaign_noise_rms_mrad": rms(noise[~of_check]),
           "campaign_jitter_rms_mrad": rms(jitter[~of_check]), "run_wall_s": round(run_wall, 1), "database": str(result.database)}
    print(f"  valid points {len(noise)} on {len(rows)} heliostats (median {np.median(kept_visits):g} visits kept per fit)")
    print(f"  a point's noise (measured spot against the noise-free one, beam angle): RMS {doc['noise_rms_mrad']} "
          f"mrad, median {doc['noise_median_mrad']}; the wind's jitter {doc['jitter_rms_mrad']}, the rest "
          f"(stroke repeatability, vision) {doc['rest_rms_mrad']}")
    print(f"    checks' points: {doc['check_points']}, noise {doc['check_noise_rms_mrad']}, jitter "
          f"{doc['check_jitter_rms_mrad']} mrad; the other visits' points: noise {doc['campaign_noise_rms_mrad']}, "
          f"jitter {doc['campaign_jitter_rms_mrad']} mrad")
    for b in by_wind:
        print(f"    wind {b['wind_ms'][0]:>2}-{b['wind_ms'][1]:<2} m/s: {b['points']:>6} points, noise "
              f"{b['noise_rms_mrad']}, jitter {b['jitter_rms_mrad']} mrad")
    print("  sky-wide RMS at the end [mrad]: " + ", ".join(f"{w} {v}" for w, v in sky.items()))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
