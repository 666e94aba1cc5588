"""Error-model refit cost: time per call of the campaign's refit, reference vs fast solver (numpy and compiled).

Observations: ``tests/data/fit_observations.csv`` (a one-day simulated campaign of two demo
heliostats). For K = 5, 20 and 60 points (60 = the recorded points of both visits' sun positions
cycled, still real observations of one heliostat), the refit the campaign runs after a new point
(``verdict.refit``: soft_l1, warm start from the fit without that point, no suggestions) is timed
``--calls`` times per solver: ``reference`` (``least_squares``), ``fast`` (the Gauss-Newton in numpy,
``solver="numpy"``) and ``compiled`` (the same in numba, the default; compiled before timing);
reported: median and 90th percentile [ms] of the wall time, the mean CPU time [ms] (steadier on a
shared machine), solver evaluations, and the largest differences of
the reference and fast solvers' beams (sky grid) and parameters, and of the fast and compiled ones.

Run: ``.venv/bin/python benchmarks/bench_refit.py [--calls 200]``; writes
``benchmarks/out/bench_refit.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from helicalib.calibration import fit_kernels
from helicalib.calibration.fit import sky_grid
from helicalib.campaign import verdict
from helicalib.config import load_field_config
from helicalib.geometry import error_model as em
from helicalib.geometry.heliostat import HeliostatModel

ROOT = Path(__file__).resolve().parents[1]
KS = (5, 20, 60)
SOLVERS = {"reference": ("reference", None), "fast": ("fast", "numpy"), "compiled": ("fast", "compiled")}
"""The timed solvers: (``method``, ``solver``) of :func:`helicalib.campaign.verdict.refit`."""
HID = "H0001"


def recorded_points(hid: str) -> list:
    df = pd.read_csv(ROOT / "tests" / "data" / "fit_observations.csv")
    return [SimpleNamespace(target_id=r.target_id, visit_id=int(r.visit_id),
                            strokes_read_mm=(r.stroke_read_1_mm, r.stroke_read_2_mm), strokes_cmd_mm=None,
                            approach=(int(r.approach_1), int(r.approach_2)), sun_enu=(r.sun_e, r.sun_n, r.sun_u),
                            spot_enu_m=(r.spot_e_m, r.spot_n_m, r.spot_u_m))
            for r in df[df.heliostat_id == hid].itertuples()]


def beam_difference_mrad(a, b, aim) -> float:
    suns = sky_grid()
    sol = a.repeat(len(suns)).strokes_for_aim(suns, aim, np.ones(2))
    ok = sol.in_range
    d = [m.repeat(int(ok.sum())).beam(sol.strokes_mm[ok], suns[ok], np.ones(2))[1] for m in (a, b)]
    return 1000.0 * float(np.max(np.linalg.norm(d[0] - d[1], axis=1)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--field", default=str(ROOT / "field_config" / "demo_north.yaml"))
    ap.add_argument("--calls", type=int, default=200, help="timed refits per solver and K")
    args = ap.parse_args()
    fit_kernels.warm()  # compile time is an install's, not a refit's
    cfg = load_field_config(args.field)
    nominal = HeliostatModel.from_config(cfg, [HID])
    aim = np.asarray(cfg.target(cfg.heliostat(HID).target).center_enu_m)
    pool = recorded_points(HID)
    rows = []
    for k in KS:
        points = [pool[i % len(pool)] for i in range(k)]
        start, _fit = verdict.refit(nominal, points[:-1], nominal, method="reference")  # the model before the point
        result = {"k": k}
        models = {}
        for method, (kind, solver) in SOLVERS.items():
            times, nfev = [], []
            cpu0 = time.process_time()
            for _ in range(args.calls):
                t0 = time.perf_counter()
                model, fit = verdict.refit(nominal, points, start, method=kind, solver=solver)
                times.append(time.perf_counter() - t0)
                nfev.append(fit.nfev)
            models[method] = (model, fit)
            result[method] = {"median_ms": round(1000 * float(np.median(times)), 3),
                              "p90_ms": round(1000 * float(np.percentile(times, 90)), 3),
                              "cpu_ms": round(1000 * (time.process_time() - cpu0) / args.calls, 3),
                              "evaluations": int(np.median(nfev))}
        (ma, fa), (mb, fb), (mc, fc) = models["reference"], models["fast"], models["compiled"]
        result["compiled_speed_up"] = round(result["fast"]["median_ms"] / result["compiled"]["median_ms"], 1)
        result["compiled_max_beam_difference_mrad"] = float(f"{beam_difference_mrad(mb, mc, aim):.3g}")
        result["compiled_max_param_difference_prior_sigma"] = float(
            f"{np.max(np.abs(fb.params - fc.params) / em.PRIOR_SIGMA):.3g}")
        result["speed_up"] = round(result["reference"]["median_ms"] / result["fast"]["median_ms"], 1)
        result["max_beam_difference_mrad"] = float(f"{beam_difference_mrad(ma, mb, aim):.3g}")
        result["max_residual_difference_mrad"] = float(f"{np.max(np.abs(fa.residual_vec_mrad - fb.residual_vec_mrad)):.3g}")
        result["max_param_difference_prior_sigma"] = float(f"{np.max(np.abs(fa.params - fb.params) / em.PRIOR_SIGMA):.3g}")
        result["max_sigma_rel_difference"] = float(f"{np.max(np.abs(fa.sigma - fb.sigma) / fa.sigma):.3g}")
        rows.append(result)
    print(f"refit of {HID} after one more point (warm start), {args.calls} calls each; times in ms (wall)")
    print(f"{'K':>4} {'reference med/p90':>19} {'evals':>6} {'fast med/p90':>15} {'evals':>6} {'speed-up':>9}"
          f" {'beam diff':>10} {'param diff':>11} {'compiled med/p90':>17} {'speed-up':>9} {'beam diff':>10}")
    for r in rows:
        a, b, c = r["reference"], r["fast"], r["compiled"]
        print(f"{r['k']:>4} {a['median_ms']:>9.2f}/{a['p90_ms']:<9.2f} {a['evaluations']:>6} {b['median_ms']:>7.2f}/"
              f"{b['p90_ms']:<7.2f} {b['evaluations']:>6} {r['speed_up']:>8.1f}x {r['max_beam_difference_mrad']:>10.2g}"
              f" {r['max_param_difference_prior_sigma']:>11.2g} {c['median_ms']:>8.2f}/{c['p90_ms']:<8.2f}"
              f" {r['compiled_speed_up']:>8.1f}x {r['compiled_max_beam_difference_mrad']:>10.2g}")
    print("mean CPU ms per refit: " + "; ".join(
        f"K={r['k']}: " + ", ".join(f"{m} {r[m]['cpu_ms']:.2f}" for m in SOLVERS) for r in rows))
    dest = ROOT / "benchmarks" / "out"
    dest.mkdir(parents=True, exist_ok=True)
    out = {"heliostat": HID, "calls": args.calls, "rows": rows,
           "units": {"beam": "mrad (sky grid, max)", "param": "prior sigma (max)"}}
    (dest / "bench_refit.json").write_text(json.dumps(out, indent=2))
    print(f"wrote {dest / 'bench_refit.json'}")


if __name__ == "__main__":
    main()
