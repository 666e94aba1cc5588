"""Fast against render fidelity: the same simulated campaign measured by the camera + vision and by
the fast sensor, side by side.

Runs :func:`helicalib.app.simulated.simulate_campaign` twice on one field, scenario, seed and
start (default: ``simulations/fields/bench500.yaml``, the benchmark scenario, seed 1, the September
equinox), once with ``fidelity="render"`` (every frame drawn and measured) and once with
``fidelity="fast"`` (the simulator's true spot plus the fitted measurement-error model), and prints:

* days to 90 % and 95 % accepted, and their relative difference (goal: within 5 %);
* the true sky-wide RMS over the accepted heliostats (goal: within 0.05 mrad) and over all;
* the share of observations by reason (goal: each invalid reason within ±2 points);
* visits, CPU seconds, CPU per measurement.

The rendered run's cameras have a fixed exposure (the scenario's ``camera.exposure: false``), as
the fast sensor's measurement-error model was fitted on; ``--camera-exposure`` lets them take the
exposure the controller chooses (PLANT_INTERFACE 1.1; ``bench_exposure.py`` compares the two).

Usage::

    .venv/bin/python benchmarks/bench_fidelity.py                       # bench500, equinox, 2 days
    .venv/bin/python benchmarks/bench_fidelity.py --heliostats 100 --days 1
    .venv/bin/python benchmarks/bench_fidelity.py --field field_config/demo_north.yaml --days 1 \\
        --start 2026-06-01T00:00:00+06:18 --scenario none

Writes ``benchmarks/out/bench_fidelity.json``.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
import tempfile
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from bench_campaign import ensure_field, pick_heliostats, run_one  # noqa: E402


def reasons(db: str) -> dict[str, float]:
    """Share of observations [%] by reason (``ok`` included), of the newest campaign."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        cid = con.execute("SELECT MAX(id) FROM campaigns").fetchone()[0]
        rows = [r[0] for r in con.execute("SELECT reason FROM observations WHERE campaign_id = ? AND iteration >= 0",
                                          (cid,))]
    finally:
        con.close()
    n = max(len(rows), 1)
    return {k: round(100.0 * v / n, 2) for k, v in sorted(Counter(rows).items())}


def compare(render: dict, fast: dict) -> dict:
    def rel(a, b):
        return None if a is None or b is None else round(abs(b - a) / a * 100.0, 2)

    keys = sorted(set(render["reasons"]) | set(fast["reasons"]))
    return {
        "days_to_90_diff_pct": rel(render["days_to_90"], fast["days_to_90"]),
        "days_to_95_diff_pct": rel(render["days_to_95"], fast["days_to_95"]),
        "sky_accepted_diff_mrad": (None if render["true_sky_rms_accepted_mrad"] is None
                                   or fast["true_sky_rms_accepted_mrad"] is None
                                   else round(fast["true_sky_rms_accepted_mrad"] - render["true_sky_rms_accepted_mrad"], 3)),
        "reason_diff_points": {k: round(fast["reasons"].get(k, 0.0) - render["reasons"].get(k, 0.0), 2) for k in keys},
        "cpu_speedup": round(render["cpu_s"] / max(fast["cpu_s"], 1e-9), 1),
    }


def main(argv=None) -> int:
    from helicalib.config import load_field_config
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.sim.scenario import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--field", default=str(ROOT / "simulations" / "fields" / "bench500.yaml"))
    ap.add_argument("--scenario", default=str(ROOT / "simulations" / "scenarios" / "benchmark.yaml"),
                    help="scenario YAML, or 'none' for the default scenario")
    ap.add_argument("--heliostats", type=int, default=None)
    ap.add_argument("--days", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start", default="2026-09-22T00:00:00+06:18", help="plant start (default the September equinox)")
    ap.add_argument("--camera-exposure", action="store_true",
                    help="rendered cameras take the controller's exposure (default: fixed, as the fast model)")
    ap.add_argument("--out", default=str(HERE / "out" / "bench_fidelity.json"))
    args = ap.parse_args(argv)
    field = Path(args.field)
    if field.name == "bench500.yaml":
        ensure_field(field)
    cfg = load_field_config(field)
    scenario = load_scenario(None if args.scenario == "none" else args.scenario)
    scenario = scenario.model_copy(update={"camera": scenario.camera.model_copy(
        update={"exposure": bool(args.camera_exposure)})})
    ids = pick_heliostats(cfg, args.heliostats)
    start_s = float(to_unix_seconds([parse_time(args.start)])[0])
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fidelity in ("render", "fast"):
            r = run_one(cfg, "gaps", args.days, args.seed, scenario, ids, Path(tmp) / fidelity, keep_frames=False,
                        start_s=start_s, fidelity=fidelity)
            r["reasons"] = reasons(r["database"])
            results[fidelity] = r
    diff = compare(results["render"], results["fast"])
    rows = ["days_to_90", "days_to_95", "accepted", "visits", "valid_visits", "true_sky_rms_accepted_mrad",
            "true_sky_rms_mrad", "first_shot_rms_mrad", "cpu_s", "cpu_s_per_visit"]
    print(f"{'':32}{'render':>12}{'fast':>12}")
    for k in rows:
        print(f"{k:32}{str(results['render'][k]):>12}{str(results['fast'][k]):>12}")
    for k in sorted(set(results["render"]["reasons"]) | set(results["fast"]["reasons"])):
        print(f"{'% observations ' + k:32}{results['render']['reasons'].get(k, 0.0):>12}"
              f"{results['fast']['reasons'].get(k, 0.0):>12}")
    print(json.dumps(diff, indent=2))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"args": vars(args), "results": results, "comparison": diff}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
