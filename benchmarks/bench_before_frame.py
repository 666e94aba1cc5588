"""Readings refused because another beam lay on the board in the before frame, with and without
taking the before frame again (``campaign.measure.retake_before``).

Runs :func:`helicalib.app.simulated.simulate_campaign` on each case twice, with the same field,
seed and start: once as the campaign runs (``retake``: up to ``MAX_BEFORE_RETAKES`` new before
frames) and once with ``MAX_BEFORE_RETAKES = 0`` (``no-retake``: the reading refused at once, as
before 2026-11-28). For each it counts the placements (observations with iteration ≥ 0), those
refused for another beam in the before frame (reason ``ambient_change`` saying "another beam"),
those whose before frame was taken again (their message says so) and how many of them came out
valid, the readings by reason, accepted heliostats, visits and the plant hours the retakes cost
(the beam to standby and the wait, measured as the extra plant time of the visits that retook).

Cases (``--cases``; default all, each modest: a shared 2-core machine):

* ``cylinder``: ``simulations/fields/dots_cylinder.yaml``, 1 day, rendered frames (the previous
  holder's beam crosses the board on its way back to tracking);
* ``demo-auto``: ``field_config/demo_north.yaml``, ``--spots-per-board auto`` (beams take turns),
  ``--demo-hours`` of plant time from 08:00, rendered frames;
* ``cylinder-fast``: the cylinder's day with the fast sensor (it models the other beams alike).

Usage::

    .venv/bin/python benchmarks/bench_before_frame.py
    .venv/bin/python benchmarks/bench_before_frame.py --cases cylinder --modes retake

Writes ``benchmarks/out/bench_before_frame.json`` (rows of cases not run this time are kept).
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
CASES = {
    "cylinder": dict(field="simulations/fields/dots_cylinder.yaml", days=1.0, fidelity="render", spots=1),
    "demo-auto": dict(field="field_config/demo_north.yaml", days=None, fidelity="render", spots="auto"),
    "cylinder-fast": dict(field="simulations/fields/dots_cylinder.yaml", days=1.0, fidelity="fast", spots=1),
}
MODES = ("no-retake", "retake")


def count(db: Path) -> dict:
    """The newest campaign's placements by what happened to their before frame."""
    from helicalib.campaign.measure import RETAKEN

    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        cid = con.execute("SELECT MAX(id) FROM campaigns").fetchone()[0]
        rows = con.execute("SELECT valid, reason, message FROM observations WHERE campaign_id = ? AND iteration >= 0",
                           (cid,)).fetchall()
    finally:
        con.close()
    n = len(rows)
    beam = sum(1 for v, r, m in rows if not v and r == "ambient_change" and "another beam" in m)
    retaken = [(v, r) for v, r, m in rows if RETAKEN in m]
    return {
        "readings": n,
        "refused_another_beam": beam,
        "refused_another_beam_pct": round(100.0 * beam / max(n, 1), 2),
        "retaken": len(retaken),
        "retaken_valid": sum(1 for v, _ in retaken if v),
        "retaken_by_reason": dict(Counter(r for _, r in retaken)),
        "valid": sum(1 for v, _r, _m in rows if v),
        "by_reason": dict(sorted(Counter(r for _v, r, _m in rows).items())),
    }


def run_case(name: str, mode: str, args) -> dict:
    from helicalib.campaign import measure
    from helicalib.config import load_field_config
    from helicalib.app.simulated import SimulationOptions, default_start_s, simulate_campaign

    spec = CASES[name]
    cfg = load_field_config(ROOT / spec["field"])
    days = spec["days"] if spec["days"] is not None else args.demo_hours / 24.0
    start = default_start_s(cfg) + (8 * 3600.0 if spec["days"] is None else 0.0)
    keep = measure.MAX_BEFORE_RETAKES
    measure.MAX_BEFORE_RETAKES = 0 if mode == "no-retake" else keep
    out = Path(tempfile.mkdtemp(prefix=f"bench_before_{name}_{mode}_"))
    t0, c0 = time.time(), time.process_time()
    try:
        res = simulate_campaign(cfg, out, SimulationOptions(days=days, seed=args.seed, start_s=start,
                                                            fidelity=spec["fidelity"], spots_per_board=spec["spots"]))
    finally:
        measure.MAX_BEFORE_RETAKES = keep
    summary = res.summary if hasattr(res, "summary") else res
    row = {"case": name, "mode": mode, "field": spec["field"], "days": round(days, 3), "fidelity": spec["fidelity"],
           "spots_per_board": spec["spots"], "seed": args.seed,
           "wall_s": round(time.time() - t0, 1), "cpu_s": round(time.process_time() - c0, 1), **count(out / "helicalib.db")}
    for key in ("heliostats", "accepted", "visits", "valid_visits", "visits_per_target_hour", "true_sky_rms_accepted_mrad"):
        value = summary.get(key) if isinstance(summary, dict) else getattr(summary, key, None)
        if value is not None:
            row[key] = value
    print(f"{name:14s} {mode:10s} readings {row['readings']:5d}  refused for another beam {row['refused_another_beam']:3d} "
          f"({row['refused_another_beam_pct']:.2f} %)  retaken {row['retaken']:3d} (valid {row['retaken_valid']})  "
          f"valid {row['valid']}  accepted {row.get('accepted')}  visits {row.get('visits')}  "
          f"wall {row['wall_s']:.0f} s", flush=True)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated: {', '.join(CASES)}")
    ap.add_argument("--modes", default=",".join(MODES), help="comma-separated: no-retake, retake")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--demo-hours", type=float, default=6.0, help="plant hours of the demo-auto case (from 08:00)")
    ap.add_argument("--out", default=str(HERE / "out" / "bench_before_frame.json"))
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "src"))
    rows = [run_case(c, m, args) for c in args.cases.split(",") for m in args.modes.split(",")]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    done = {(r["case"], r["mode"]) for r in rows}  # rows of other cases from an earlier run are kept
    kept = json.loads(out.read_text(encoding="utf-8")).get("rows", []) if out.exists() else []
    rows = [r for r in kept if (r.get("case"), r.get("mode")) not in done] + rows
    out.write_text(json.dumps({"rows": rows}, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
