"""Year-round prediction against the simulator's truth: is the report's predicted interval calibrated?

The report predicts, for each fitted heliostat, its year-round RMS beam error with a central 90 %
interval and the probability that the error passes the acceptance limit somewhere on the year's
sun path (:mod:`helicalib.report.prediction`, :func:`helicalib.calibration.uncertainty.year_prediction`).
This benchmark runs simulated campaigns (``--fidelity fast`` by default: the rendered frames are
not the point), takes the runner's fits and the simulator's truth
(:func:`helicalib.sim.evaluate.evaluate_model`, the calibrated models against the true field at the
run's end, backlash as while tracking) and reports, per field and seed:

* ``coverage``: share of heliostats whose true year-round RMS lies inside the predicted 90 %
  interval (nominal 0.90), with ``below``/``above`` (the truth under the interval's lower end / over
  its upper end), the predicted and the true median year RMS, the mean ``p_exceed`` and the true
  share over the limit;

and ablations, one cause at a time (the same fits; only the prediction or the truth changes):

* ``as_is``: the prediction as the report makes it;
* ``no_variance_factor``: the fit's covariance without its a-posteriori variance factor;
* ``factor_on_data_only``: the factor scaling the measurement noise only, not the priors;
* ``robust_weights``: the Gauss-Newton covariance with the robust loss's Hessian weights;
* ``no_unexplained``: without the unexplained floor ``u``;
* ``noise_floor_<s>``: the data's information for a measurement noise of ``s`` mrad (not the fit's 0.3);
* truth variants (the prediction as is): ``truth_no_sag`` (the simulator's gravity sag removed from
  the truth), ``truth_no_backlash`` (backlash out of truth and model), ``truth_params_only`` (neither),
  ``truth_linear_params``: ``J · (fitted − true parameters)``, the error the covariance describes.

``--synthetic N`` instead checks the machinery on an exactly modelled case: N demo heliostats with
errors drawn from the priors (no backlash, no sag, no drift), 12 observations each with Gaussian
beam noise of 0.3 mrad (the fit's σ), either clustered as a June campaign takes them (6 visits of
2 placements over 2 days: ``june``) or spread over the year (``year``); the true year-round RMS is
the true heliostat's beam for the fitted model's strokes.

Usage::

    .venv/bin/python benchmarks/bench_prediction.py                       # demo field, seed 1, 2 days
    .venv/bin/python benchmarks/bench_prediction.py --field simulations/fields/bench500.yaml --every 5
    .venv/bin/python benchmarks/bench_prediction.py --seeds 1,2 --days 2
    .venv/bin/python benchmarks/bench_prediction.py --synthetic 200      # ≈ 10 CPU s

``--every k`` calibrates every k-th heliostat of the field (the plant keeps the whole field). Prints
a table and writes ``benchmarks/out/bench_prediction.json`` (or ``--out``). Cost (fast fidelity):
the demo field's 2 days ≈ 40 s, bench500 every 5th heliostat (100) 2 days ≈ a few minutes.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "out"
NOISE_FLOORS = (0.15, 0.1)
"""Measurement noises [mrad] of the noise-floor ablation (the fit assumes 0.3)."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--field", default=str(ROOT / "field_config" / "demo_north.yaml"))
    ap.add_argument("--days", type=float, default=2.0)
    ap.add_argument("--seeds", default="1", help="comma-separated scenario seeds (default 1)")
    ap.add_argument("--every", type=int, default=1, help="calibrate every k-th heliostat (default all)")
    ap.add_argument("--fidelity", default="fast", choices=("fast", "render"))
    ap.add_argument("--out", default=str(OUT / "bench_prediction.json"))
    ap.add_argument("--synthetic", type=int, default=0, help="check the machinery on N synthetic heliostats")
    args = ap.parse_args()
    from helicalib.config import load_field_config

    cfg = load_field_config(args.field)
    if args.synthetic:
        out = {"synthetic": {mode: synthetic(cfg, args.synthetic, mode) for mode in ("june", "year")}}
        for mode, v in out["synthetic"].items():
            print(f"synthetic {mode}: {v}", flush=True)
        path = Path(args.out).with_name("bench_prediction_synthetic.json") if args.out == str(
            OUT / "bench_prediction.json") else Path(args.out)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out, indent=1))
        print(f"wrote {path}")
        return
    ids = [h.id for h in cfg.heliostats][:: max(1, args.every)]
    runs = []
    for seed in [int(s) for s in args.seeds.split(",") if s.strip()]:
        print(f"{Path(args.field).name}: seed {seed}, {len(ids)} heliostats, {args.days:g} days, "
              f"{args.fidelity} fidelity ...", flush=True)
        runs.append(run_one(cfg, args.field, args.days, seed, ids, args.fidelity))
        _print(runs[-1])
    out = {"field": str(Path(args.field).resolve().relative_to(ROOT)), "days": args.days, "every": args.every,
           "fidelity": args.fidelity, "level": 0.9, "runs": runs, "pooled": _pooled(runs)}
    print("pooled over seeds:")
    _print({"seed": "all", **out["pooled"]})
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"wrote {args.out}")


def run_one(cfg, field: str, days: float, seed: int, ids: list[str], fidelity: str) -> dict:
    """One simulated campaign and the prediction's figures against its truth."""
    from helicalib.app.simulated import SimulationOptions, simulate_campaign

    t0 = time.perf_counter()
    last = [t0]

    def progress(*_a, **_k):
        if time.perf_counter() - last[0] > 20.0:
            last[0] = time.perf_counter()
            print(f"  ... {time.perf_counter() - t0:.0f} s", flush=True)

    with tempfile.TemporaryDirectory(prefix="bench_prediction_") as tmp:
        res = simulate_campaign(cfg, Path(tmp), SimulationOptions(days, seed=seed, fidelity=fidelity,
                                                                  heliostat_ids=ids), progress=progress)
    wall = time.perf_counter() - t0
    print(f"  campaign {wall:.0f} s; {res.summary['accepted']} accepted; evaluating ...", flush=True)
    runner = res.runner
    sim = runner.devices.plant
    end_s = sim.truth.start_s + days * 86400.0
    figures = evaluate(cfg, runner, sim.truth, end_s)
    return {"seed": seed, "campaign_wall_s": round(wall, 1), "accepted": res.summary["accepted"], **figures}


def evaluate(cfg, runner, truth, end_s: float) -> dict:
    """The figures and ablations (module docstring) for the runner's fitted heliostats."""
    from helicalib.calibration.fit import SIGMA_MRAD
    from helicalib.calibration.uncertainty import beam_jacobians_mrad, unexplained_mrad, year_prediction
    from helicalib.geometry import error_model as em
    from helicalib.geometry.sun import year_sun_times
    from helicalib.sim.evaluate import evaluate_model

    hids = [h for h in runner.state.ids if runner.state.book.h[h].fit is not None]
    fits = [runner.state.book.h[h].fit for h in hids]
    rows = np.array([cfg.heliostat_index(h) for h in hids])
    params = np.zeros((truth.n, em.P))
    params[[cfg.heliostat_index(h) for h in runner.state.ids]] = runner.calibrated_model().params
    model = truth.nominal.subset(rows).with_params(params[rows])
    year = int(np.datetime64(int(truth.start_s), "s").astype("datetime64[Y]").astype(int) + 1970)
    times, sun = year_sun_times(cfg.site, year, step_days=14.0, step_min=60.0)
    aims = np.array([cfg.target(cfg.heliostat(h).target).center_enu_m for h in hids])
    limit = float(cfg.acceptance.max_rms_mrad)
    u = np.array([unexplained_mrad(f.rms_mrad, SIGMA_MRAD) for f in fits])

    def true_errors(backlash="tracking", sag=True) -> np.ndarray:
        keep = truth.sag_mrad
        if not sag:
            truth.sag_mrad = np.zeros_like(keep)
        try:
            return evaluate_model(truth, params, times, sun, t_eval_s=end_s, backlash=backlash).errors_mrad[rows]
        finally:
            truth.sag_mrad = keep

    truths = {"truth": true_errors(), "truth_no_sag": true_errors(sag=False),
              "truth_no_backlash": true_errors(backlash="none"),
              "truth_params_only": true_errors(backlash="none", sag=False)}
    jac, ok = beam_jacobians_mrad(model, sun, aims)
    delta = params[rows] - truth.params_at(end_s)[rows]
    delta[:, [em.index(n) for n in em.BACKLASH]] = 0.0
    linear = np.sqrt(np.sum(np.einsum("nmip,np->nmi", jac, delta) ** 2, axis=-1))
    truths["truth_linear_params"] = np.where(ok, linear, np.nan)

    covs = _covariances(fits)
    predictions = {"as_is": (covs["as_is"], u), "no_unexplained": (covs["as_is"], 0.0 * u)}
    for name in ("no_variance_factor", "factor_on_data_only", "robust_weights"):
        predictions[name] = (covs[name], u)
    for s in NOISE_FLOORS:
        u_s = np.array([np.sqrt(max(0.0, f.rms_mrad**2 - 2.0 * s * s)) for f in fits])
        predictions[f"noise_floor_{s:g}"] = (_with_noise(fits, s), u_s)
    out = {"heliostats": len(hids)}
    for name, (cov, uu) in predictions.items():
        pred = year_prediction(model, cov, sun, aims, uu, draws=400, limit_mrad=limit)
        out[name] = _score(pred, truths["truth"], limit)
        if name == "as_is":
            for tname, err in truths.items():
                if tname != "truth":
                    out[tname] = _score(pred, err, limit)
    return out


SYNTH_NOISE_MRAD = 0.3
"""Beam noise of one component in the synthetic check [mrad] (the fit's ``SIGMA_MRAD``)."""


def synthetic(cfg, n: int, mode: str, seed: int = 7) -> dict:
    """Coverage of the predicted interval on ``n`` exactly modelled synthetic heliostats (module docstring)."""
    import pandas as pd

    from helicalib.calibration.fit import SIGMA_MRAD, FitPoints, fit_error_model
    from helicalib.calibration.uncertainty import unexplained_mrad, year_prediction
    from helicalib.geometry import error_model as em
    from helicalib.geometry import optics
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.geometry.sun import sun_at_site
    from helicalib.geometry.sun import year_sun_times

    rng = np.random.default_rng(seed)
    _t, year_sun = year_sun_times(cfg.site, 2026, step_days=14.0, step_min=60.0)
    t0 = pd.Timestamp("2026-06-01T00:00:00Z").timestamp() - cfg.site.longitude_deg / 15.0 * 3600.0
    geometric = [em.index(name) for name in em.GEOMETRIC]
    true_rms, preds = [], []
    for i in range(n):
        h = cfg.heliostats[i % len(cfg.heliostats)]
        model = HeliostatModel.from_config(cfg, [h.id])
        aim = np.asarray(cfg.target(h.target).center_enu_m, dtype=float)
        p = np.zeros(em.P)
        p[geometric] = rng.normal(size=len(geometric)) * em.PRIOR_SIGMA[geometric]
        plant = model.with_params(p[None, :])
        if mode == "june":  # 6 visits over 2 days, 2 placements each, 90 s apart
            visits = t0 + np.sort(rng.integers(0, 2, 6)) * 86400.0 + rng.uniform(6.0, 19.0, 6) * 3600.0
            times = np.repeat(visits, 2) + np.tile([60.0, 150.0], 6)
        else:
            times = t0 + rng.uniform(0.0, 365.0, 12) * 86400.0 + rng.uniform(7.0, 18.0, 12) * 3600.0
        pos = sun_at_site(cfg.site, times)
        sun = np.asarray(pos.vector_enu)[pos.elevation_deg > 8.0]
        held = model.repeat(len(sun)).strokes_for_aim(sun, aim).strokes_mm
        origin, beam = plant.repeat(len(sun)).beam(held, sun)
        across = optics.unit(np.cross(beam, [0.0, 0.0, 1.0]))
        z = rng.normal(size=(len(sun), 2)) * SYNTH_NOISE_MRAD * 1e-3
        beam = optics.unit(beam + z[:, :1] * across + z[:, 1:] * np.cross(across, beam))
        _uv, spot, _on = optics.intersect_target(origin, beam, cfg.target(h.target))
        fit = fit_error_model(model, FitPoints(held, sun, spot))
        preds.append(year_prediction(fit.model, fit.covariance[None], year_sun, aim,
                                     unexplained_mrad(fit.rms_mrad, SIGMA_MRAD), draws=400, seed=i))
        sol = fit.model.repeat(len(year_sun)).strokes_for_aim(year_sun, aim)
        o, d = plant.repeat(len(year_sun)).beam(sol.strokes_mm, year_sun)
        err = 1000.0 * optics.angle_between_rad(d, aim - o)
        true_rms.append(err[sol.in_range])
    lo = np.array([q.interval_mrad[0, 0] for q in preds])
    hi = np.array([q.interval_mrad[0, 1] for q in preds])
    rms = np.array([np.sqrt(np.mean(e**2)) for e in true_rms])
    return {"n": n, "coverage": round(float(np.mean((lo <= rms) & (rms <= hi))), 3),
            "below": round(float(np.mean(rms < lo)), 3), "above": round(float(np.mean(rms > hi)), 3),
            "predicted_median_mrad": round(float(np.median([q.expected_rms_mrad[0] for q in preds])), 3),
            "true_median_mrad": round(float(np.median(rms)), 3),
            "predicted_exceed": round(float(np.mean([q.p_exceed[0] for q in preds])), 3),
            "true_exceed": round(float(np.mean([e.max() > 1.2 for e in true_rms])), 3)}


def _score(pred, err: np.ndarray, limit: float) -> dict:
    with np.errstate(invalid="ignore"):
        true_rms = np.sqrt(np.nanmean(err**2, axis=1))
        exceed = np.nanmax(err, axis=1) > limit
    ok = np.isfinite(true_rms) & np.all(np.isfinite(pred.interval_mrad), axis=1)
    lo, hi, t = pred.interval_mrad[ok, 0], pred.interval_mrad[ok, 1], true_rms[ok]
    return {"n": int(ok.sum()), "inside": int(np.sum((lo <= t) & (t <= hi))), "below": int(np.sum(t < lo)),
            "above": int(np.sum(t > hi)), "coverage": round(float(np.mean((lo <= t) & (t <= hi))), 3),
            "predicted_median_mrad": round(float(np.median(pred.expected_rms_mrad[ok])), 3),
            "true_median_mrad": round(float(np.median(t)), 3),
            "predicted_exceed": round(float(np.mean(pred.p_exceed[ok])), 3),
            "true_exceed": round(float(np.mean(exceed[ok])), 3)}


def _covariances(fits) -> dict:
    """Each fit's covariance as made (``as_is``) and the covariance ablations, from its linearisation."""
    out = {k: [] for k in ("as_is", "no_variance_factor", "factor_on_data_only", "robust_weights")}
    for f in fits:
        lin = f.linearisation
        k = len(f.residual_mrad)
        j = lin.jacobian
        jd = j[: 2 * k]
        prior = np.eye(j.shape[1])
        cx = np.linalg.inv(j.T @ j)
        dof = 2 * k - float(np.trace(jd @ cx @ jd.T))
        chi2 = float(np.sum(lin.residual[: 2 * k] ** 2))
        factor = max(1.0, chi2 / dof) if dof >= 3.0 else 1.0
        hw = lin.hessian_weights[: 2 * k]
        variants = {"as_is": None, "no_variance_factor": cx, "factor_on_data_only": np.linalg.inv(jd.T @ jd / factor + prior),
                    "robust_weights": factor * np.linalg.inv((jd * hw[:, None]).T @ jd + prior)}
        for name, c in variants.items():
            out[name].append(f.covariance if c is None else _full(lin, c))
    return {k: np.stack(v) for k, v in out.items()}


def _with_noise(fits, sigma_mrad: float) -> np.ndarray:
    """Each fit's covariance had its data's noise been ``sigma_mrad`` instead of the fit's."""
    from helicalib.calibration.fit import SIGMA_MRAD

    out = []
    for f in fits:
        lin = f.linearisation
        jd = lin.jacobian[: 2 * len(f.residual_mrad)]
        c = np.linalg.inv(jd.T @ jd * (SIGMA_MRAD / sigma_mrad) ** 2 + np.eye(lin.jacobian.shape[1]))
        out.append(_full(lin, c))
    return np.stack(out)


def _full(lin, cov_x: np.ndarray) -> np.ndarray:
    """(P, P) parameter covariance from one in whitened unknowns (free parameters first)."""
    from helicalib.geometry import error_model as em

    f = len(lin.free_idx)
    cov = np.zeros((em.P, em.P))
    cov[np.ix_(lin.free_idx, lin.free_idx)] = cov_x[:f, :f] * np.outer(lin.scale, lin.scale)
    return cov


def _pooled(runs: list[dict]) -> dict:
    keys = [k for k, v in runs[0].items() if isinstance(v, dict)]
    out = {"heliostats": sum(r["heliostats"] for r in runs)}
    for k in keys:
        n = sum(r[k]["n"] for r in runs)
        out[k] = {"n": n, "coverage": round(sum(r[k]["inside"] for r in runs) / max(n, 1), 3),
                  "below": round(sum(r[k]["below"] for r in runs) / max(n, 1), 3),
                  "above": round(sum(r[k]["above"] for r in runs) / max(n, 1), 3),
                  "predicted_exceed": round(sum(r[k]["predicted_exceed"] * r[k]["n"] for r in runs) / max(n, 1), 3),
                  "true_exceed": round(sum(r[k]["true_exceed"] * r[k]["n"] for r in runs) / max(n, 1), 3)}
    return out


def _print(run: dict) -> None:
    print(f"  seed {run['seed']}: {run['heliostats']} heliostats")
    print(f"  {'variant':24s} {'coverage':>8s} {'below':>6s} {'above':>6s} {'P(exc) pred':>11s} {'true':>6s}")
    for k, v in run.items():
        if isinstance(v, dict):
            n = max(v["n"], 1)
            below = v["below"] / n if isinstance(v["below"], int) else v["below"]
            above = v["above"] / n if isinstance(v["above"], int) else v["above"]
            print(f"  {k:24s} {v['coverage']:8.3f} {below:6.3f} {above:6.3f} {v['predicted_exceed']:11.3f} "
                  f"{v['true_exceed']:6.3f}", flush=True)


if __name__ == "__main__":
    main()
