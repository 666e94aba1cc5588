"""Fit the fast sensor's measurement-error model on rendered measurements; write ``fast_sensor.json``.

Runs in-process render campaigns (every frame drawn by the simulated camera and measured by the
vision, as ``helicalib simulate`` does) with the camera sensor wrapped: at each measurement the
simulator's true spot of the measured heliostat is taken at the same instant
(:meth:`helicalib.sim.fast_sensor.FastSensor.spot`). Then:

* bias: the mean of measured − true spot centre over valid measurements [m];
* spread: ``sqrt(floor² + (k·σ_spot)²)`` per axis, fitted by least squares to the squared
  residuals (outliers beyond 5 robust sigmas left out);
* threshold fraction: the one (0.10 … 0.60) whose validity verdicts by the vision's limits agree
  most often with the rendered ones on the same spots;
* cleanliness spread: the RMS relative difference of the measured and the true cleanliness.

Usage (the shipped model)::

    .venv/bin/python simulations/fit_fast_sensor.py --days 1 --seeds 1,2,3 \
        --out src/helicalib/sim/fast_sensor.json

It prints the fitted figures and the validity confusion; the JSON records what it was fitted on.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


class Recording:
    """A camera sensor that notes, at each reading, the true spot the fast sensor would start from."""

    def __init__(self, inner, fast, rows: list):
        self.inner, self.fast, self.rows = inner, fast, rows

    def before(self, ctx):
        b = self.inner.before(ctx)
        b.ambient = self.fast._ambient_wm2(float(ctx.now()))
        return b

    def after(self, ctx, before):
        reading = yield from self.inner.after(ctx, before)
        s = self.fast.spot(ctx.index)
        true_clean = float(self.fast.plant.cleanliness()[ctx.index])
        self.rows.append({"heliostat": ctx.heliostat_id, "target": self.fast.target, "reason": reading.reason,
                          "measured": reading.offset_m,
                          "true": s.uv_m.tolist(), "sigma": s.sigma_m.tolist(), "width": s.width_m.tolist(),
                          "power": s.power_w, "on_plane": s.on_plane, "ambient_before": before.ambient,
                          "ambient_after": self.fast._ambient_wm2(reading.capture_time_s), "spot": s,
                          "true_clean": true_clean, "clean": None})  # cleanliness() below fills it
        return reading

    def cleanliness(self, ctx, before, reading, held_mm, weather, sun_enu):
        value = self.inner.cleanliness(ctx, before, reading, held_mm, weather, sun_enu)
        if self.rows:
            self.rows[-1]["clean"] = value
        return value


def record(field: Path, days: float, seed: int, scenario_path: str | None, rows: list, start_s: float | None = None,
           heliostats: int | None = None) -> None:
    from helicalib.campaign.loop import CampaignRunner
    from helicalib.campaign.sensor import camera_sensors
    from helicalib.app.simulated import default_start_s
    from helicalib.config import load_field_config
    from helicalib.sim.camera import SimCamera
    from helicalib.sim.clock import VirtualClock
    from helicalib.sim.fast_sensor import FastSensor, SensorErrorModel
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import load_scenario
    from helicalib.store.sqlite import Store

    cfg = load_field_config(field)
    scenario = load_scenario(scenario_path).model_copy(update={"seed": seed})
    start = default_start_s(cfg) if start_s is None else start_s
    sim = SimulatedPlant(cfg, scenario, start_s=start)
    clock = VirtualClock(start)
    clock.on_advance(sim.advance_to)
    cams = camera_sensors(cfg, {t.id: SimCamera(sim, cfg.cameras_for(t.id)[0].id) for t in cfg.targets})
    sensors = {t: Recording(c, FastSensor(sim, t, SensorErrorModel()), rows) for t, c in cams.items()}
    with tempfile.TemporaryDirectory() as tmp:
        store = Store.open(Path(tmp) / "fit.db", durable=False)
        ids = [h.id for h in cfg.heliostats]
        if heliostats is not None and heliostats < len(ids):  # every k-th heliostat
            ids = [ids[i] for i in np.round(np.linspace(0, len(ids) - 1, heliostats)).astype(int)]
        cid = store.start_campaign(name="fit", mode="simulate", started_s=start,
                                   heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in ids])
        runner = CampaignRunner(cfg, sim, sensors, clock, store, cid, heliostat_ids=ids)
        runner.run_until(start + days * 86400.0)
        store.close()


def fit(rows: list, spec, limits, fractions=np.arange(0.20, 0.51, 0.05), scales=np.arange(0.80, 1.61, 0.05),
        no_spot_fractions=(0.3, 0.4, 0.5, 0.6, 0.7, 0.8)) -> dict:
    """The error model from the recorded rows; ``spec`` the scenario's camera, ``limits`` the vision's.

    The threshold fraction, the contrast scale and the no-spot fraction are chosen together: the
    triple whose verdicts on the recorded spots agree with the rendered ones most often (the same
    reason on the same spot); ties go to the smallest largest difference in the reasons' shares."""
    from helicalib.sim.fast_sensor import judge_spot

    valid = [r for r in rows if r["reason"] == "ok" and r["measured"] is not None]
    if len(valid) < 10:
        raise SystemExit(f"fit_fast_sensor: only {len(valid)} valid rendered measurements; run more plant days "
                         "(the campaigns start at local midnight)")
    res = np.array([np.subtract(r["measured"], r["true"]) for r in valid])
    sig = np.array([r["sigma"] for r in valid])
    med = np.median(res, axis=0)
    mad = 1.4826 * np.median(np.abs(res - med), axis=0)
    keep = np.all(np.abs(res - med) <= 5 * mad + 1e-6, axis=1)
    bias = res[keep].mean(axis=0)
    r2 = ((res[keep] - bias) ** 2).ravel()
    s2 = (sig[keep] ** 2).ravel()
    a = np.column_stack([np.ones_like(s2), s2])
    coef, *_ = np.linalg.lstsq(a, r2, rcond=None)
    floor2, k2 = max(coef[0], 1e-8), max(coef[1], 0.0)
    # threshold, contrast scale, no-spot fraction: agreement with the rendered verdicts on the same spots
    rendered = Counter(r["reason"] for r in rows)
    best = None
    for f in fractions:
        for scale in scales:
            for ns in no_spot_fractions:
                judged = [judge_spot(r["spot"], r["target"], spec, limits, float(f), r["ambient_before"],
                                     r["ambient_after"], float(scale), float(ns))[0] for r in rows]
                agree = sum(j == r["reason"] for j, r in zip(judged, rows))
                shares = Counter(judged)
                worst = max(abs(shares[k] - rendered[k]) for k in set(shares) | set(rendered))
                key = (agree, -worst)
                if best is None or key > best[1]:
                    best = ((float(f), float(scale), float(ns)), key)
    cl = [(r["clean"], r["true_clean"]) for r in valid if r["clean"] is not None]
    rel = np.array([c / t - 1.0 for c, t in cl]) if cl else np.zeros(1)
    return {"bias_m": [round(float(b), 5) for b in bias], "floor_m": round(float(np.sqrt(floor2)), 5),
            "per_sigma": round(float(np.sqrt(k2)), 5), "threshold_fraction": round(best[0][0], 3),
            "cleanliness_sigma": round(float(np.sqrt(np.mean(rel ** 2))), 5),
            "contrast_scale": round(best[0][1], 3), "no_spot_fraction": round(best[0][2], 3),
            "_agreement": best[1][0] / max(len(rows), 1), "_valid": int(len(valid)), "_kept": int(keep.sum()),
            "_residual_rms_m": [round(float(x), 5) for x in np.sqrt(np.mean((res[keep] - bias) ** 2, axis=0))]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--field", default=str(ROOT / "field_config" / "demo_north.yaml"))
    ap.add_argument("--days", type=float, default=1.0)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--scenario", default=None)
    ap.add_argument("--start", default=None, help="ISO start (default: the field's local midnight of 1 June)")
    ap.add_argument("--heliostats", type=int, default=None, help="every k-th heliostat, this many (default all)")
    ap.add_argument("--out", default=str(ROOT / "src" / "helicalib" / "sim" / "fast_sensor.json"))
    args = ap.parse_args(argv)
    from helicalib.sim.scenario import load_scenario
    from helicalib.vision.spot import SpotLimits

    from helicalib.geometry.sun import parse_time, to_unix_seconds

    start_s = float(to_unix_seconds([parse_time(args.start)])[0]) if args.start else None
    rows: list = []
    t0 = time.perf_counter()
    seeds = [int(s) for s in args.seeds.split(",")]
    for seed in seeds:
        n0 = len(rows)
        record(Path(args.field), args.days, seed, args.scenario, rows, start_s, args.heliostats)
        print(f"fit_fast_sensor: seed {seed}: {len(rows) - n0} rendered measurements "
              f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    model = fit(rows, load_scenario(args.scenario).camera, SpotLimits())
    reasons = Counter(r["reason"] for r in rows)
    out = {"note": "fitted by simulations/fit_fast_sensor.py on rendered measurements; see docs/simulator.md",
           "fitted_on": {"field": Path(args.field).name, "days": args.days, "seeds": seeds,
                         "scenario": Path(args.scenario).name if args.scenario else "default",
                         "start": args.start, "heliostats": args.heliostats, "measurements": len(rows),
                         "render_reasons": dict(reasons), "validity_agreement": round(model.pop("_agreement"), 4),
                         "valid": model.pop("_valid"), "kept": model.pop("_kept"),
                         "residual_rms_m": model.pop("_residual_rms_m")},
           "model": model}
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
