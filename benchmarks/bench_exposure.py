"""Exposure control against fixed cameras: the same rendered campaign with and without exposure.

Runs :func:`helicalib.app.simulated.simulate_campaign` with rendered frames (``fidelity="render"``)
twice on one field, scenario, seed and start (default: ``simulations/fields/bench500.yaml``, the
benchmark scenario, seed 1, the September equinox): once with cameras that cannot set their
exposure (the scenario's ``camera.exposure: false``, the controller's behaviour before interface
1.1) and once with cameras that can (the controller chooses each visit's exposure and retakes a
too bright or too faint reading). Prints, per run:

* the share of readings [%] by reason: ``clipped``, ``saturated``, ``low_contrast``, ``ok`` (goal:
  clipped + low_contrast ≤ 0.5 % with exposure control);
* readings retaken at another exposure, and how many of them ended valid;
* days to 90 % / 95 % accepted, the true sky RMS over the accepted heliostats and the first-shot
  RMS (the campaign's accuracy must not drop), visits and CPU seconds.

Usage::

    .venv/bin/python benchmarks/bench_exposure.py                          # bench500, equinox, 1 day
    .venv/bin/python benchmarks/bench_exposure.py --heliostats 100 --days 1   # every 5th heliostat

Writes ``benchmarks/out/bench_exposure.json``.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from bench_campaign import ensure_field, pick_heliostats, run_one  # noqa: E402
from bench_fidelity import reasons  # noqa: E402

RETAKE_WORDS = "frames retaken at"
"""What the message of a reading taken again at another exposure says (campaign.measure.EXPOSED)."""


def retakes(db: str) -> dict[str, int]:
    """Readings taken again at another exposure, and those of them that ended valid."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        cid = con.execute("SELECT MAX(id) FROM campaigns").fetchone()[0]
        rows = con.execute("SELECT valid, message FROM observations WHERE campaign_id = ? AND iteration >= 0",
                           (cid,)).fetchall()
    finally:
        con.close()
    hit = [bool(v) for v, m in rows if m and RETAKE_WORDS in m]
    return {"readings": len(rows), "retaken": len(hit), "retaken_valid": sum(hit)}


def main(argv=None) -> int:
    from helicalib.config import load_field_config
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.sim.scenario import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--field", default=str(ROOT / "simulations" / "fields" / "bench500.yaml"))
    ap.add_argument("--scenario", default=str(ROOT / "simulations" / "scenarios" / "benchmark.yaml"),
                    help="scenario YAML, or 'none' for the default scenario")
    ap.add_argument("--heliostats", type=int, default=None, help="every k-th heliostat, this many (default all)")
    ap.add_argument("--days", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start", default="2026-09-22T00:00:00+06:18", help="plant start (default the September equinox)")
    ap.add_argument("--only", choices=("fixed", "exposure"), default=None, help="run one side only")
    ap.add_argument("--out", default=str(HERE / "out" / "bench_exposure.json"))
    args = ap.parse_args(argv)
    field = Path(args.field)
    if field.name == "bench500.yaml":
        ensure_field(field)
    cfg = load_field_config(field)
    base = load_scenario(None if args.scenario == "none" else args.scenario)
    ids = pick_heliostats(cfg, args.heliostats)
    start_s = float(to_unix_seconds([parse_time(args.start)])[0])
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for side, control in (("fixed", False), ("exposure", True)):
            if args.only not in (None, side):
                continue
            scenario = base.model_copy(update={"camera": base.camera.model_copy(update={"exposure": control})})
            r = run_one(cfg, "gaps", args.days, args.seed, scenario, ids, Path(tmp) / side, keep_frames=False,
                        start_s=start_s, fidelity="render")
            r["reasons"] = reasons(r["database"])
            r["retakes"] = retakes(r["database"])
            r["clipped_plus_low_contrast_pct"] = round(r["reasons"].get("clipped", 0.0)
                                                       + r["reasons"].get("low_contrast", 0.0), 2)
            results[side] = r
    rows = ["clipped_plus_low_contrast_pct", "days_to_90", "days_to_95", "accepted", "visits", "valid_visits",
            "true_sky_rms_accepted_mrad", "true_sky_rms_mrad", "first_shot_rms_mrad", "cpu_s"]
    sides = list(results)
    print(f"{'':34}" + "".join(f"{s:>12}" for s in sides))
    for k in rows:
        print(f"{k:34}" + "".join(f"{str(results[s].get(k)):>12}" for s in sides))
    for k in sorted({k for s in sides for k in results[s]["reasons"]}):
        print(f"{'% readings ' + k:34}" + "".join(f"{results[s]['reasons'].get(k, 0.0):>12}" for s in sides))
    for k in ("readings", "retaken", "retaken_valid"):
        print(f"{k:34}" + "".join(f"{results[s]['retakes'][k]:>12}" for s in sides))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"args": vars(args), "results": results}, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
