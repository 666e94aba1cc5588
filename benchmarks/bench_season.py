"""How far one season's calibration carries over the year (issue 7's sky-wide goal, examined).

The campaign benchmark judges calibrated models by their true tracking error over a whole year
of sun positions. A campaign of a few days sees only that season's sun path. This script asks how
much of the year those days can pin down, apart from any planner, vision or noise: for
heliostats of the 500-heliostat benchmark field with the benchmark scenario's hidden errors, it
makes observations every ``--every-min`` minutes of ``--days`` days from a start date (sun ≥ 5°),
fits the error model (``calibration.fit.fit_error_model``, the campaign's fitter), and evaluates
the true error over the year (``sim.evaluate.evaluate_model``) and month by month.

Worlds:

* ``ideal``: the simulated heliostats have only the error model's own parameters (no gravity sag,
  backlash, drift), and the spots are exact. This gives the best any fit of this model can do with
  that season's data.
* ``real``: the scenario's unmodelled effects too (gravity sag, backlash approached in the
  tracking direction as the campaign does, drift, stroke repeatability), plus 0.2 mrad spot noise;
  evaluated with backlash as while tracking. Wind jitter is left out.
* ``real-nosag``, ``real-nobacklash``: ``real`` less gravity sag, or less backlash: what that one
  unmodelled effect costs (the most an error-model term for it could win).

Aims: ``board`` (the heliostat's own board centre, as the campaign does) or ``boards`` (the
centres of all boards in turn: more geometric diversity from one season).

Usage::

    .venv/bin/python benchmarks/bench_season.py                      # June / September / December, both worlds
    .venv/bin/python benchmarks/bench_season.py --starts 2026-06-01 --days 8 --heliostats 40

Prints a table and writes ``benchmarks/out/bench_season.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "simulations" / "fields" / "bench500.yaml"
SCENARIO = ROOT / "simulations" / "scenarios" / "benchmark.yaml"
OUT = ROOT / "benchmarks" / "out"
NOISE_MRAD = 0.2
"""Default spot noise of the real worlds, one component of the beam angle [mrad] (``--noise-mrad``)."""
WITHOUT = {"real-nosag": ("sag_mrad",), "real-nobacklash": ("backlash_mm",)}
"""Worlds ``real`` less one unmodelled effect (the most a model term for it could win)."""
WORLDS = ("ideal", "real", *WITHOUT)


def observe(truth, cfg, i: int, times: np.ndarray, aims_by_obs, world: str, rng,
            noise_mrad: float = NOISE_MRAD) -> tuple:
    """Strokes (K, 2), suns (K, 3), spots (K, 3) of heliostat ``i``: the nominal model's strokes for
    each aim, the true beam's spot on that aim's board."""
    from helicalib.geometry.heliostat import tracking_approach
    from helicalib.geometry.sun import sun_at_site

    suns = np.asarray(sun_at_site(cfg.site, times).vector_enu).reshape(-1, 3)
    later = np.asarray(sun_at_site(cfg.site, times + 300.0).vector_enu).reshape(-1, 3)
    nominal = truth.nominal.subset([i])
    strokes, spots, approaches = [], [], []
    for k, (sun, target) in enumerate(zip(suns, aims_by_obs)):
        aim = np.asarray(target.center_enu_m, dtype=float)
        s = nominal.strokes_for_aim(sun, aim).strokes_mm[0]
        every = np.tile(s, (truth.n, 1))
        approach = None
        if world.startswith("real"):  # the campaign approaches each actuator in its tracking direction
            approach = np.tile(tracking_approach(s, nominal.strokes_for_aim(later[k], aim).strokes_mm[0]), (truth.n, 1))
        beam = truth.beam(every, sun, float(times[k]), approach=approach, jitter=False,
                          stroke_noise_mm=(truth.repeat_noise_mm(np.full(truth.n, k)) if world.startswith("real")
                                           else None))
        _uv, hit, _on = truth.spots(beam, [target] * truth.n)
        spot = hit[i]
        if world.startswith("real"):
            dist = np.linalg.norm(spot - truth.nominal.pivots_enu[i])
            spot = spot + (rng.normal(size=2) * noise_mrad * 1e-3 * dist) @ target.frame_enu[:2]
        strokes.append(s)
        spots.append(spot)
        approaches.append(np.zeros(2) if approach is None else approach[i])
    return np.array(strokes), suns, np.array(spots), np.array(approaches)


def run_case(cfg, scenario, start: str, days: float, every_min: float, world: str, aims: str, rows, seed: int,
             backlash_term: bool = True, tilt_rate: bool = False, noise_mrad: float = NOISE_MRAD) -> dict:
    """One case. ``tilt_rate``: the fit is given each point's age and fits a steady pedestal tilt
    rate (as operation's fits do), and the models are judged against the heliostats as they are at
    the end of the observations (the drift's state then); otherwise at the start."""
    from helicalib.calibration.fit import FitOptions, FitPoints, fit_error_model
    from helicalib.geometry import error_model as em
    from helicalib.geometry.sun import sun_at_site, to_unix_seconds
    from helicalib.geometry.sun import year_sun_times
    from helicalib.sim.evaluate import evaluate_model
    from helicalib.sim.truth import TrueField

    t0 = float(to_unix_seconds([start])[0])
    truth = TrueField(cfg, scenario, t0)
    if world == "ideal":
        for name in ("backlash_mm", "sag_mrad", "drift_mrad_per_s", "repeatability_mm", "jitter_mrad_per_ms"):
            setattr(truth, name, np.zeros_like(np.asarray(getattr(truth, name), dtype=float)))
    for name in WITHOUT.get(world, ()):  # a real world less one unmodelled effect: what that effect costs
        setattr(truth, name, np.zeros_like(np.asarray(getattr(truth, name), dtype=float)))
    times = t0 + np.arange(0.0, days * 86400.0, every_min * 60.0)
    times = times[sun_at_site(cfg.site, times).elevation_deg >= 5.0]
    rng = np.random.default_rng(seed)
    t_eval = t0 + days * 86400.0 if tilt_rate else t0
    params = np.zeros((truth.n, em.P))
    for i in rows:
        own = cfg.target(cfg.heliostats[i].target)
        targets = [own] * len(times) if aims == "board" else [cfg.targets[k % len(cfg.targets)] for k in
                                                               range(len(times))]
        strokes, suns, spots, approach = observe(truth, cfg, i, times, targets, world, rng, noise_mrad)
        points = FitPoints(strokes, suns, spots, approach=approach if backlash_term else None,
                           age_days=(t_eval - times) / 86400.0 if tilt_rate else None)
        params[i] = fit_error_model(truth.nominal.subset([i]), points,
                                    FitOptions(loss="soft_l1")).params
    backlash = "tracking" if world.startswith("real") else "none"
    year_t, year_sun = year_sun_times(cfg.site, int(start[:4]))
    fitted = evaluate_model(truth, params, year_t, year_sun, backlash=backlash, t_eval_s=t_eval)
    exact = evaluate_model(truth, truth.params_at(t_eval), year_t, year_sun, backlash=backlash, t_eval_s=t_eval)
    rms = lambda e: round(float(np.sqrt(np.nanmean(e[rows] ** 2))), 3)  # noqa: E731
    months = (year_t - float(to_unix_seconds([f"{start[:4]}-01-01T00:00:00Z"])[0])) // (365.25 / 12 * 86400)
    by_month = [rms(fitted.errors_mrad[:, months == m]) for m in range(12)]
    own = np.abs(year_t - (t0 + days * 43200.0)) < 10 * 86400.0
    return {"start": start, "days": days, "world": world, "aims": aims,
            "model": "backlash" if backlash_term else "geometric", "tilt_rate": tilt_rate,
            "noise_mrad": noise_mrad if world.startswith("real") else 0.0, "observations_per_heliostat": int(len(times)),
            "year_rms_mrad": rms(fitted.errors_mrad), "exact_params_year_rms_mrad": rms(exact.errors_mrad),
            "own_season_rms_mrad": rms(fitted.errors_mrad[:, own]), "by_month_rms_mrad": by_month}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--starts", default="2026-06-01,2026-09-01,2026-12-01", help="comma-separated start dates (UTC)")
    ap.add_argument("--days", type=float, default=3.0, help="days of observations (default 3)")
    ap.add_argument("--every-min", type=float, default=20.0, help="minutes between observations (default 20)")
    ap.add_argument("--heliostats", type=int, default=20, help="heliostats of board T2, evenly spread (default 20)")
    ap.add_argument("--worlds", default="ideal,real", help=f"comma-separated, of {', '.join(WORLDS)}")
    ap.add_argument("--aims", default="board,boards")
    ap.add_argument("--models", default="backlash",
                    help="comma-separated, of backlash (the fit sees each observation's approach and fits the "
                         "dead bands), geometric (the 13 geometric parameters only)")
    ap.add_argument("--tilt-rate", action="store_true",
                    help="fit a steady pedestal tilt rate from the points' ages (as operation does) and judge "
                         "the models at the end of the observations; for spans of weeks and more")
    ap.add_argument("--noise-mrad", type=float, default=NOISE_MRAD,
                    help=f"spot noise of the real worlds, per beam-angle component [mrad] (default {NOISE_MRAD})")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=OUT / "bench_season.json")
    args = ap.parse_args(argv)
    from helicalib.config import load_field_config
    from helicalib.sim.scenario import load_scenario

    cfg = load_field_config(FIELD)
    scenario = load_scenario(SCENARIO).model_copy(update={"seed": args.seed})
    t2 = [k for k, h in enumerate(cfg.heliostats) if h.target == "T2"]
    rows = [t2[j] for j in np.round(np.linspace(0, len(t2) - 1, args.heliostats)).astype(int)]
    cases = []
    t_start = time.perf_counter()
    for start in [s.strip() for s in args.starts.split(",") if s.strip()]:
        for world in args.worlds.split(","):
            if world not in WORLDS:
                ap.error(f"--worlds: unknown world {world!r}; known: {', '.join(WORLDS)}")
            for aims, model in [(a, m) for a in args.aims.split(",") for m in args.models.split(",")]:
                if model not in ("backlash", "geometric"):
                    ap.error(f"--models: unknown model {model!r}; known: backlash, geometric")
                case = run_case(cfg, scenario, f"{start}T00:00:00Z" if "T" not in start else start, args.days,
                                args.every_min, world, aims, rows, args.seed, backlash_term=model == "backlash",
                                tilt_rate=args.tilt_rate, noise_mrad=args.noise_mrad)
                cases.append(case)
                print(f"{case['start'][:10]}  {world:5s}  {aims:6s}  {model:9s}  {case['observations_per_heliostat']:3d} obs  "
                      f"year {case['year_rms_mrad']:.3f}  (exact params {case['exact_params_year_rms_mrad']:.3f})  "
                      f"own season {case['own_season_rms_mrad']:.3f}  worst month "
                      f"{max(case['by_month_rms_mrad']):.3f}  months {case['by_month_rms_mrad']}", flush=True)
    doc = {"benchmark": "season", "field": str(FIELD), "scenario": str(SCENARIO), "heliostats": len(rows),
           "noise_mrad": args.noise_mrad, "cases": cases, "wall_s": round(time.perf_counter() - t_start, 1)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2))
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
