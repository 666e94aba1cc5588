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
* the ``clipped`` and ``low_contrast`` readings that were a heliostat's very first reading, and the
  heliostats with the most of them;
* days to 90 % / 95 % accepted, the true sky RMS over the accepted heliostats and the first-shot
  RMS (the campaign's accuracy must not drop), visits and CPU seconds.

``--spots N`` measures instead the vision's spot accuracy at the exposures the policy chooses,
against a fixed camera, on rendered frames of the demo board with known spot centres (no campaign):
N spots of random shape, size, angle and position whose peaks at the fixed (nominal) exposure span
what one fixed camera sees across a field (log-uniform 8–400 grey levels on a white board at 25,
as the simulated plant's cameras are exposed). The exposure side takes each spot at the exposure the
policy chooses from an expected peak that is off by a log-normal factor (σ 30 %, the learned gain's
and the flux model's error), then retakes a saturated or faint reading as a campaign does. Prints
the validity shares and the centre error (RMS and 95th percentile, mm on the board) over the spots
valid on both sides; JSON ``benchmarks/out/bench_exposure_spots.json``.

Usage::

    .venv/bin/python benchmarks/bench_exposure.py                          # bench500, equinox, 1 day
    .venv/bin/python benchmarks/bench_exposure.py --heliostats 100 --days 1   # every 5th heliostat
    .venv/bin/python benchmarks/bench_exposure.py --spots 400                 # spot accuracy only
    .venv/bin/python benchmarks/bench_exposure.py --only exposure --ids H00034 --keep DIR --keep-frames

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


NOMINAL_BOARD_GREY = 25.0
"""The white board at the fixed (nominal) exposure (``bench_spot.SPOT_EXPOSED``)."""
NOMINAL_PEAKS = (8.0, 400.0)
"""Spot peaks at the nominal exposure [grey levels above the board, before clipping], log-uniform."""
EXPECTATION_ERROR = 0.3
"""σ of the log of the policy's expected-peak error."""


def _render_at(target, pose, spot, exposure: float, seed: int, read_share: float):
    """Before and after frames of ``spot`` (its peak at the nominal exposure) at ``exposure`` × nominal."""
    from dataclasses import replace

    from helicalib.sim.camera import noise_scale
    from helicalib.sim.render import Lighting, render_frame

    light = Lighting(ambient=NOMINAL_BOARD_GREY * exposure, background=10.0 * exposure,
                     noise_sigma=1.5 * noise_scale(exposure, read_share))
    before = render_frame(target, pose, (), light, rng=seed)
    after = render_frame(target, pose, [replace(spot, peak=spot.peak * exposure)], light, rng=seed + 1)
    return before, after


def spot_accuracy(n: int, seed: int = 2026) -> dict:
    """The vision's centre error and validity on spots taken at a fixed exposure and at the policy's."""
    import numpy as np

    from helicalib.campaign.exposure import MAX_EXPOSURE_RETAKES, ExposurePolicy, SpotFigures
    from helicalib.sim.render import DEMO_CAMERA_ENU_M, Spot, demo_target, look_at_pose
    from helicalib.sim.scenario import CameraSpec
    from helicalib.vision.marks import find_marks
    from helicalib.vision.spot import measure_spot

    read_share = CameraSpec().read_noise_share
    target = demo_target()
    pose = look_at_pose(DEMO_CAMERA_ENU_M, target, 5200, (1280, 1024))
    rng = np.random.default_rng(seed)
    marks = find_marks(_render_at(target, pose, Spot((0.0, 0.0), (1.0, 1.0)), 1.0, seed, read_share)[0], target)
    sides = {"fixed": [], "exposure": []}
    retaken = 0
    for _ in range(n):
        peak = float(np.exp(rng.uniform(*np.log(NOMINAL_PEAKS))))
        spot = Spot(tuple(rng.uniform(-3.0, 3.0, 2)), tuple(rng.uniform(0.5, 1.6, 2)), peak=peak,
                    shape=str(rng.choice(["gaussian", "flat"])), angle_deg=float(rng.uniform(0, 180)))
        frame_seed = int(rng.integers(1 << 30))
        expected = peak * float(np.exp(rng.normal(0.0, EXPECTATION_ERROR)))
        policy = ExposurePolicy(prior_gain=1.0)  # grey per unit of "expected peak" per ms
        policy.saw_board(NOMINAL_BOARD_GREY, 1.0)
        for side, exposure in (("fixed", 1.0), ("exposure", policy.choose(expected))):
            for attempt in range(MAX_EXPOSURE_RETAKES + 1):
                before, after = _render_at(target, pose, spot, exposure, frame_seed + 17 * attempt, read_share)
                r = measure_spot(before, [after], target, marks=marks)
                if side == "fixed" or r.valid or attempt == MAX_EXPOSURE_RETAKES:
                    break
                f = r.frames[-1] if r.frames else None
                figures = SpotFigures(exposure, peak=None if f is None else f.peak,
                                      noise=None if f is None else f.noise,
                                      saturated_fraction=None if f is None or not np.isfinite(f.saturated_fraction)
                                      else f.saturated_fraction, board_grey=NOMINAL_BOARD_GREY * exposure)
                new = policy.retake_exposure_ms(r.reason, figures)
                if new is None:
                    break
                exposure, retaken = new, retaken + 1
            err = None if not r.valid else 1000.0 * float(np.linalg.norm(r.offset_m - np.asarray(spot.center_m)))
            sides[side].append((r.reason, err))
    both = [i for i in range(n) if sides["fixed"][i][1] is not None and sides["exposure"][i][1] is not None]
    out = {"spots": n, "nominal_peaks": NOMINAL_PEAKS, "expectation_error": EXPECTATION_ERROR, "retaken": retaken,
           "valid_on_both": len(both), "sides": {}}
    for side, rows in sides.items():
        reasons_ = {}
        for reason, _ in rows:
            reasons_[reason] = reasons_.get(reason, 0) + 1
        errs = np.array([rows[i][1] for i in both])
        out["sides"][side] = {"reasons_pct": {k: round(100.0 * v / n, 2) for k, v in sorted(reasons_.items())},
                              "rms_mm_on_both": round(float(np.sqrt(np.mean(errs ** 2))), 2) if both else None,
                              "p95_mm_on_both": round(float(np.percentile(errs, 95)), 2) if both else None}
    return out


def refused(db: str, reasons_: tuple[str, ...] = ("clipped", "low_contrast")) -> dict:
    """The readings refused for ``reasons_``: how many, how many of them a heliostat's very first reading,
    and the heliostats with the most of them."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        cid = con.execute("SELECT MAX(id) FROM campaigns").fetchone()[0]
        rows = con.execute("SELECT id, heliostat_id, reason FROM observations WHERE campaign_id = ? AND iteration >= 0 "
                           "ORDER BY id", (cid,)).fetchall()
    finally:
        con.close()
    seen: set[str] = set()
    first = 0
    per: dict[str, int] = {}
    for _, hid, reason in rows:
        if reason in reasons_:
            first += hid not in seen
            per[hid] = per.get(hid, 0) + 1
        seen.add(hid)
    top = sorted(per.items(), key=lambda kv: (-kv[1], kv[0]))[:5]
    return {"readings": sum(per.values()), "first_readings": first, "heliostats": len(per),
            "top": ", ".join(f"{h} {n}" for h, n in top)}


def main(argv=None) -> int:
    from helicalib.config import load_field_config
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.sim.scenario import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--field", default=str(ROOT / "simulations" / "fields" / "bench500.yaml"))
    ap.add_argument("--scenario", default=str(ROOT / "simulations" / "scenarios" / "benchmark.yaml"),
                    help="scenario YAML, or 'none' for the default scenario")
    ap.add_argument("--heliostats", type=int, default=None, help="every k-th heliostat, this many (default all)")
    ap.add_argument("--ids", default=None, help="only these heliostats (comma-separated ids)")
    ap.add_argument("--days", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start", default="2026-09-22T00:00:00+06:18", help="plant start (default the September equinox)")
    ap.add_argument("--only", choices=("fixed", "exposure"), default=None, help="run one side only")
    ap.add_argument("--spots", type=int, default=None, help="measure the spot accuracy on this many spots instead")
    ap.add_argument("--out", default=None, help="JSON (default benchmarks/out/bench_exposure[_spots].json)")
    ap.add_argument("--keep", default=None, help="keep each run's database under this directory (<side>/helicalib.db)")
    ap.add_argument("--keep-frames", action="store_true", help="with --keep: keep every reading's frames (<side>/images)")
    args = ap.parse_args(argv)
    if args.spots:
        out = spot_accuracy(args.spots, args.seed)
        print(json.dumps(out, indent=2))
        path = Path(args.out or HERE / "out" / "bench_exposure_spots.json")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"args": vars(args), **out}, indent=2))
        return 0
    args.out = args.out or str(HERE / "out" / "bench_exposure.json")
    field = Path(args.field)
    if field.name == "bench500.yaml":
        ensure_field(field)
    cfg = load_field_config(field)
    base = load_scenario(None if args.scenario == "none" else args.scenario)
    ids = args.ids.split(",") if args.ids else pick_heliostats(cfg, args.heliostats)
    start_s = float(to_unix_seconds([parse_time(args.start)])[0])
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep) if args.keep else Path(tmp)
        for side, control in (("fixed", False), ("exposure", True)):
            if args.only not in (None, side):
                continue
            scenario = base.model_copy(update={"camera": base.camera.model_copy(update={"exposure": control})})
            r = run_one(cfg, "gaps", args.days, args.seed, scenario, ids, root / side,
                        keep_frames=bool(args.keep and args.keep_frames),
                        start_s=start_s, fidelity="render")
            r["reasons"] = reasons(r["database"])
            r["retakes"] = retakes(r["database"])
            r["refused"] = refused(r["database"])
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
    for k in ("readings", "first_readings", "heliostats"):
        print(f"{'clipped+low_contrast ' + k:34}" + "".join(f"{results[s]['refused'][k]:>12}" for s in sides))
    for s_ in sides:
        print(f"clipped+low_contrast by heliostat ({s_}): {results[s_]['refused']['top']}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"args": vars(args), "results": results}, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
