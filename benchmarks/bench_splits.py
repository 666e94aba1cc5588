"""Benchmark splits (issue 21): out-of-sample error of the fit per PAINT split, beside leave-one-out.

For each heliostat's observations: the error model is fitted (``helicalib fit``'s ``fit_report``, the
priors ``REALDATA_PRIOR_SIGMA``) on the train part of each split (``calibration/splits.py``: azimuth,
solstice, balanced, high-variance; test share 0.3) and the normal error of the test part is reported
(RMS, mrad), beside leave-one-out over all observations. ``balanced`` draws at random: it is run for
``--seeds`` seeds and reported as the mean (min-max) over them.

Data:

* the real Jülich records (PAINT / ARTIST samples under ``REALDATA``, default ``../shared/realdata``):
  AA23 (10 records) and AA39 (6); for AA23 also PAINT's own published split (``test_benchmark.csv``:
  3 train, 7 validation + test);
* simulated campaigns (``helicalib simulate --fidelity fast`` on the demo field, same seed = same
  hidden errors): one campaign of ``--days`` days from 2026-06-01, and three such campaigns from
  2026-03-01, 2026-06-01 and 2026-12-01 taken together (a crew that came back each season).

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_splits.py [--realdata ../shared/realdata] [--days 3]
        [--heliostats H0003,H0010,H0021,H0033] [--seeds 5]

Prints a table and writes ``benchmarks/out/bench_splits.json``.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from helicalib.calibration.observations import read_observations, write_observations
from helicalib.calibration.splits import DEFAULT_TEST_SHARE, SPLITS, Split
from helicalib.commands.fit import FitReportOptions, fit_report, split_report
from helicalib.config import load_field_config, write_field_config
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.realdata import paint
from helicalib.realdata.fitting import REALDATA_PRIOR_SIGMA
from helicalib.store.sqlite import Store

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "out"
FIELD = ROOT / "field_config" / "demo_north.yaml"
STARTS = ("2026-03-01T00:00:00+08:00", "2026-06-01T00:00:00+08:00", "2026-12-01T00:00:00+08:00")


def evaluate(cfg, rows, hid: str, seeds: int, test_share: float, extra: dict[str, Split] | None = None) -> dict:
    """LOO and every split's out-of-sample RMS for one heliostat's rows (balanced over ``seeds`` seeds)."""
    priors = dict(REALDATA_PRIOR_SIGMA)
    rep = fit_report(cfg, rows, hid, FitReportOptions(priors, 1.0, True, tuple(s for s in SPLITS if s != "balanced"),
                                               test_share, 0))
    out = {"records": len(rows), "in_sample_normal_mrad_rms": float(np.sqrt(np.mean(np.square(rep["in_sample_normal_mrad"])))),
           "loo_normal_mrad_rms": rep["loo_normal_mrad_rms"], "loo_normal_mrad_mean": rep["loo_normal_mrad_mean"],
           "splits": {k: {"test_normal_mrad_rms": v["test_normal_mrad_rms"], "train": v["train"], "test": v["test"],
                          "test_record_ids": v["test_record_ids"]} for k, v in rep["splits"].items()}}
    balanced = [fit_report(cfg, rows, hid, FitReportOptions(priors, 1.0, False, ("balanced",), test_share, seed))["splits"]["balanced"]
                for seed in range(seeds)]
    b = np.array([x["test_normal_mrad_rms"] for x in balanced])
    out["splits"]["balanced"] = {"test_normal_mrad_rms": float(b.mean()), "min": float(b.min()), "max": float(b.max()),
                                 "per_seed": b.tolist(), "train": balanced[0]["train"], "test": balanced[0]["test"]}
    for name, split in (extra or {}).items():
        model = HeliostatModel.from_config(cfg, [hid])
        arrays = [np.array([getattr(r, f) for r in rows], dtype=float) for f in ("strokes_mm", "sun_enu", "spot_enu_m")]
        sp = split_report(model, *arrays, [cfg.target(r.target_id) for r in rows], split, FitReportOptions(priors, 1.0),
                          [r.record_id for r in rows])
        out["splits"][name] = {"test_normal_mrad_rms": sp["test_normal_mrad_rms"], "train": sp["train"],
                               "test": sp["test"], "test_record_ids": sp["test_record_ids"]}
    return out


def real_data(root: Path, seeds: int, test_share: float) -> dict:
    imp = paint.scan([root / "ARTIST", root / "PAINT"])
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        cfg = write_field_config(paint.field_config_dict(imp), Path(tmp) / "field.yaml")
        rows, _ = paint.observations(imp, "UTIS")
        write_observations(Path(tmp) / "obs.csv", rows)
        rows = read_observations(Path(tmp) / "obs.csv")
    bench_csv = root / "PAINT" / "tests" / "data" / "test_data" / "test_benchmark.csv"
    for hid in ("AA23", "AA39"):
        hr = [r for r in rows if r.heliostat_id == hid]
        extra = {}
        if hid == "AA23" and bench_csv.is_file():
            with open(bench_csv, newline="") as f:
                train_ids = {r["Id"] for r in csv.DictReader(f) if r["Split"] == "train"}
            train = np.array([i for i, r in enumerate(hr) if r.record_id in train_ids])
            test = np.array([i for i, r in enumerate(hr) if r.record_id not in train_ids])
            extra["paint-published"] = Split("paint-published", train, test)
        res[hid] = evaluate(cfg, hr, hid, seeds, test_share, extra)
    return res


def simulate(days: float, heliostats: str, start: str, out: Path, seed: int) -> Path:
    cmd = [sys.executable, "-m", "helicalib", "simulate", str(FIELD), "--days", str(days), "--seed", str(seed),
           "--heliostats", heliostats, "--fidelity", "fast", "--start", start, "--out", str(out), "--json"]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return out / "helicalib.db"


def campaign_rows(db: Path, tmp: Path) -> list:
    with Store.open(db, readonly=True) as store:
        store.export_fit_csv(tmp / f"{db.parent.name}.csv")
    return read_observations(tmp / f"{db.parent.name}.csv")


def simulated(days: float, heliostats: str, seeds: int, test_share: float, seed: int) -> dict:
    cfg = load_field_config(FIELD)
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        season_rows = {}
        for start in STARTS:
            t0 = time.monotonic()
            db = simulate(days, heliostats, start, tmp / start[:10], seed)
            season_rows[start[:10]] = campaign_rows(db, tmp)
            print(f"  simulated {days:g} days from {start[:10]}: {len(season_rows[start[:10]])} observations "
                  f"({time.monotonic() - t0:.0f} s)", file=sys.stderr)
        for name, rows in (("june", season_rows["2026-06-01"]),
                           ("three-seasons", [r for rs in season_rows.values() for r in rs])):
            res[name] = {}
            for hid in heliostats.split(","):
                hr = [r for r in rows if r.heliostat_id == hid]
                if len(hr) >= 6:
                    res[name][hid] = evaluate(cfg, hr, hid, seeds, test_share)
    return res


def _row(label: str, r: dict, width: int = 24) -> str:
    cols = [f"{r['splits'][k]['test_normal_mrad_rms']:8.2f}" for k in SPLITS]
    pub = r["splits"].get("paint-published")
    b = r["splits"]["balanced"]
    return (f"{label:{width}s} {r['records']:3d} {r['in_sample_normal_mrad_rms']:7.2f} {r['loo_normal_mrad_rms']:7.2f} "
            + " ".join(cols) + f"  ({b['min']:.2f}-{b['max']:.2f})"
            + (f"  PAINT's own split: {pub['test_normal_mrad_rms']:.2f}" if pub else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--realdata", default=str(ROOT.parent / "shared" / "realdata"), help="PAINT/ARTIST data root")
    ap.add_argument("--days", type=float, default=3.0, help="days per simulated campaign (default 3)")
    ap.add_argument("--heliostats", default="H0003,H0010,H0021,H0033", help="simulated heliostats")
    ap.add_argument("--seeds", type=int, default=5, help="seeds of the balanced split (default 5)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the simulated plant (default 1)")
    ap.add_argument("--test-share", type=float, default=DEFAULT_TEST_SHARE)
    ap.add_argument("--no-sim", action="store_true", help="real data only")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    result = {"date": "2026-11-25", "test_share": args.test_share, "balanced_seeds": args.seeds,
              "priors": "REALDATA_PRIOR_SIGMA", "metric": "normal error RMS over the test part [mrad]"}
    real = Path(args.realdata)
    if real.is_dir():
        result["real"] = real_data(real, args.seeds, args.test_share)
    else:
        print(f"no real data at {real}; skipped", file=sys.stderr)
    if not args.no_sim:
        result["simulated"] = simulated(args.days, args.heliostats, args.seeds, args.test_share, args.seed)
        result["simulated_days_per_campaign"] = args.days
    result["wall_s"] = round(time.monotonic() - t0, 1)

    head = (f"{'data / heliostat':24s} {'n':>3s} {'in-smp':>7s} {'LOO':>7s} " + " ".join(f"{k[:8]:>8s}" for k in SPLITS)
            + "  (balanced min-max)")
    print(f"normal error RMS [mrad], test share {args.test_share}; splits: fit on train, error on test")
    print(head)
    for hid, r in result.get("real", {}).items():
        print(_row(f"Jülich {hid}", r))
    for name, per in result.get("simulated", {}).items():
        for hid, r in per.items():
            print(_row(f"sim {name} {hid}", r))
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_splits.json").write_text(json.dumps(result, indent=2))
    print(f"wrote {OUT / 'bench_splits.json'} ({result['wall_s']} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
