"""Spots cut by the board's rim: validity and centre error with and without the core threshold.

Renders spots of known centre on the demo board (12 m, the demo camera's steep upward view,
1280×1024) exposed as the simulated plant's cameras are (the white board at 25 grey levels, spot
peaks 60–180, ``bench_spot.SPOT_EXPOSED``), placed near and across the board's rim (centres
uniform over ±``--reach`` m, default 7 m, on a board of ±6 m) and of every size from small to
board-sized (Gaussian σ 0.4–2.5 m, flat-topped semi-axes 0.8–5 m, aspect up to 1.6, any angle).
Each pair of frames is measured three times by :func:`helicalib.vision.spot.measure_spot`:
``today`` with neither rim rule (``core_shares=()``, ``max_mirror_slope=None``: a spot over the rim
is ``clipped``), ``core`` with the core thresholds only (:data:`helicalib.vision.spot.CORE_SHARES`:
a spot over the rim whose core keeps off the rim is measured on its core), ``mirror`` with the
default limits (besides, a spot over the rim whose every core reaches it is measured by the
symmetry of its visible part, :mod:`helicalib.vision.mirror`). Prints:

* the share of spots by reason on each side;
* the centre error [mm on the board] (RMS, 95th percentile) of the spots valid today
  (``valid_today``), of those valid only with the core rule (``newly_valid``) and of those valid
  only with the symmetry rule (``mirror_valid``), overall and by the centre's distance from the board
  centre (the larger of |u|, |v|), and the error's component toward the board centre (a cut skirt
  would pull the centre inward);
* whether every spot valid today measured the same centre bit for bit on every side.

``--kind beam`` renders instead the spots the simulated plant's cameras render (``sim/camera.py``):
a mirror's footprint (3.5–5 m sides) blurred by a Gaussian (σ 0.5–1.1 m, 3.9 mrad at 130–280 m),
axis-aligned on the board: flat-topped with soft edges, as the far heliostats of ``bench500`` are.

``--kind board`` renders spots that fill the board instead, through the simulated plant's renderer
(``sim.camera.BoardRenderer``) on board T4 of ``simulations/fields/bench500.yaml`` seen by its camera,
as a near heliostat of ``bench500`` throws them at a high sun: a 9.5–11 m footprint blurred by 0.63 m,
centred within ±2 m of the board centre, 0–3 other heliostats' beams (8–10 m, anywhere within ±9 m)
on the board in both frames, the exposure 1.8–3.2 times the nominal one (the spot's peak near 170).
Each pair is measured without the board-filling rule (``max_below_share`` 1: ``fills_board`` never)
and with it (the default limits); prints the reasons, the error of the valid readings and how many
valid readings lie more than 0.1 / 0.5 m off, by the centre's distance from the board centre.

    .venv/bin/python benchmarks/bench_clipped.py [--spots N] [--seed S] [--reach M] [--kind mixed|beam|board]

Writes ``benchmarks/out/bench_clipped.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import erf

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_spot import SPOT_EXPOSED, SPOT_EXPOSED_PEAK  # noqa: E402

from helicalib.sim.render import DEMO_CAMERA_ENU_M, Spot, demo_target, look_at_pose, render_frame  # noqa: E402
from helicalib.vision.marks import find_marks  # noqa: E402
from helicalib.vision.spot import SpotLimits, measure_spot  # noqa: E402

OUT = HERE / "out" / "bench_clipped.json"
DISTANCE_BINS_M = (0.0, 3.0, 4.0, 5.0, 6.0, 99.0)
"""Bins of the spot centre's distance from the board centre, max(|u|, |v|) [m]."""


@dataclass(frozen=True)
class BeamSpot:
    """A box of ``width_m`` (u, v) blurred by a Gaussian of ``sigma_m``, ``peak`` grey levels at its
    centre: the simulated plant's spot (``sim.camera.spot_flux_window``), for ``sim.render``."""

    center_m: tuple[float, float]
    width_m: tuple[float, float]
    sigma_m: float
    peak: float

    @property
    def size_m(self) -> tuple[float, float]:
        return self.width_m

    shape = "beam"

    def _profile(self, x, c: float, w: float):
        s = self.sigma_m * np.sqrt(2.0)
        return 0.5 * (erf((x - c + w / 2) / s) - erf((x - c - w / 2) / s))

    def irradiance(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        top = self._profile(0.0, 0.0, self.width_m[0]) * self._profile(0.0, 0.0, self.width_m[1])
        return self.peak / top * self._profile(u, self.center_m[0], self.width_m[0]) \
            * self._profile(v, self.center_m[1], self.width_m[1])


def random_beam(rng: np.random.Generator, reach_m: float) -> BeamSpot:
    """A simulated plant's spot anywhere within ±``reach_m`` of the board centre."""
    return BeamSpot(tuple(rng.uniform(-reach_m, reach_m, 2)), tuple(rng.uniform(3.5, 5.0, 2)),
                    float(rng.uniform(0.5, 1.1)), float(rng.uniform(*SPOT_EXPOSED_PEAK)))


def random_spot(rng: np.random.Generator, reach_m: float) -> Spot:
    """A spot anywhere within ±``reach_m`` of the board centre, small to board-sized."""
    shape = str(rng.choice(["gaussian", "flat"]))
    a = float(np.exp(rng.uniform(np.log(0.4), np.log(2.5)))) if shape == "gaussian" \
        else float(np.exp(rng.uniform(np.log(0.8), np.log(5.0))))
    size = (a, a / float(rng.uniform(1.0, 1.6)))
    return Spot(tuple(rng.uniform(-reach_m, reach_m, 2)), size, peak=float(rng.uniform(*SPOT_EXPOSED_PEAK)),
                shape=shape, angle_deg=float(rng.uniform(0.0, 180.0)))


def _stats(err: np.ndarray) -> dict:
    if len(err) == 0:
        return {"n": 0, "rms_mm": None, "p95_mm": None}
    return {"n": int(len(err)), "rms_mm": round(float(np.sqrt(np.mean(err ** 2))), 2),
            "p95_mm": round(float(np.percentile(err, 95)), 2)}


def run(n: int, seed: int = 2026, reach_m: float = 7.0, kind: str = "mixed") -> dict:
    """Measure ``n`` random spots (``kind`` "mixed" or "beam") with and without the rim rules; the
    figures as a dict."""
    target = demo_target()
    pose = look_at_pose(DEMO_CAMERA_ENU_M, target, 5200, (1280, 1024))
    rng = np.random.default_rng(seed)
    marks = find_marks(render_frame(target, pose, (), SPOT_EXPOSED, rng=seed), target)
    today = SpotLimits(core_shares=(), max_mirror_slope=None)
    core, mirror = SpotLimits(max_mirror_slope=None), SpotLimits()
    rows = []
    for _ in range(n):
        spot = random_spot(rng, reach_m) if kind == "mixed" else random_beam(rng, reach_m)
        s = int(rng.integers(1 << 30))
        before = render_frame(target, pose, (), SPOT_EXPOSED, rng=s)
        after = render_frame(target, pose, [spot], SPOT_EXPOSED, rng=s + 1)
        a, b, c = (measure_spot(before, [after], target, marks=marks, limits=lim) for lim in (today, core, mirror))
        truth = np.asarray(spot.center_m, dtype=float)
        row = {"spot": {"center_m": list(spot.center_m), "size_m": list(spot.size_m), "shape": spot.shape,
                        "peak": round(spot.peak, 1)},
               "today": a.reason, "core": b.reason, "mirror": c.reason, "distance_m": float(np.max(np.abs(truth)))}
        if c.valid:
            d = c.offset_m - truth
            row["err_mm"] = 1000.0 * float(np.linalg.norm(d))
            inward = -truth / max(1e-9, float(np.linalg.norm(truth)))
            row["inward_mm"] = 1000.0 * float(d @ inward)
            row["core_share"] = c.frames[0].core_share
            row["mirror_slope"] = c.frames[0].mirror_slope
        if a.valid:
            row["same"] = all(bool(np.array_equal(a.offset_m, x.offset_m) and a.threshold == x.threshold
                                   and a.spot_area_px == x.spot_area_px and a.message == x.message) for x in (b, c))
        rows.append(row)
    out = summarise(rows, n, seed, reach_m)
    out["kind"] = kind
    return out


def summarise(rows: list[dict], n: int, seed: int, reach_m: float) -> dict:
    """Shares by reason, errors of both groups overall and by distance, the bit-for-bit check."""
    out: dict = {"spots": n, "seed": seed, "reach_m": reach_m, "reasons_pct": {}}
    for side in ("today", "core", "mirror"):
        counts: dict[str, int] = {}
        for r in rows:
            counts[r[side]] = counts.get(r[side], 0) + 1
        out["reasons_pct"][side] = {k: round(100.0 * v / n, 2) for k, v in sorted(counts.items())}
    both = [r for r in rows if r["today"] == "ok" and r["core"] == "ok" and r["mirror"] == "ok"]
    new = [r for r in rows if r["today"] == "clipped" and r["core"] == "ok" and r["mirror"] == "ok"]
    sym = [r for r in rows if r["core"] == "clipped" and r["mirror"] == "ok"]
    out["unchanged_bit_for_bit"] = f"{sum(r['same'] for r in both)} of {len(both)}"
    out["newly_valid_core_shares"] = {str(k): sum(r.get("core_share") == k for r in new)
                                      for k in sorted({r.get("core_share") for r in new})}
    out["mirror_valid_slopes"] = sorted(round(r["mirror_slope"], 2) for r in sym)
    out["still_clipped_peak_on_board"] = sum(r["mirror"] == "clipped" and r["distance_m"] < 6.0 for r in rows)
    groups = {"valid_today": both, "newly_valid": new, "mirror_valid": sym}
    out["error"] = {g: _stats(np.array([r["err_mm"] for r in rs])) for g, rs in groups.items()}
    out["inward_mean_mm"] = {g: round(float(np.mean([r["inward_mm"] for r in rs])), 2) if rs else None
                             for g, rs in groups.items()}
    out["by_distance"] = []
    for lo, hi in zip(DISTANCE_BINS_M[:-1], DISTANCE_BINS_M[1:]):
        row = {"distance_m": [lo, hi]}
        for g, rs in groups.items():
            row[g] = _stats(np.array([r["err_mm"] for r in rs if lo <= r["distance_m"] < hi]))
        out["by_distance"].append(row)
    out["rows"] = rows
    return out


BOARD_DNI_WM2 = 927.5
BOARD_SPOT_POWER_W = 14400.0
"""H00034's spot on ``bench500``'s board T4 at noon of the September equinox (its beam's power)."""


def _beams(rows):
    """``(uv, power, width, sigma)`` arrays of ``sim.camera.BoardRenderer.render`` from (centre, power,
    square footprint side, sigma) rows."""
    return (np.array([r[0] for r in rows], float), np.array([r[1] for r in rows], float),
            np.array([[r[2], r[2]] for r in rows], float), np.array([[r[3], r[3]] for r in rows], float))


def run_board(n: int, seed: int = 2026) -> dict:
    """Board-filling spots (``--kind board``) with and without the board-filling rule; the figures."""
    from helicalib.config import load_field_config
    from helicalib.sim.camera import BoardRenderer
    from helicalib.sim.scenario import CameraSpec, Optics

    cfg = load_field_config(HERE.parent / "simulations" / "fields" / "bench500.yaml")
    target = cfg.target("T4")
    camera = next(c for c in cfg.cameras if c.target == "T4")
    renderer = BoardRenderer(camera, target, CameraSpec(), Optics(), seed=seed)
    rng = np.random.default_rng(seed)
    sides = {"without": SpotLimits(max_below_share=1.0), "with": SpotLimits()}
    rows = []
    for _ in range(n):
        others = [(tuple(rng.uniform(-9.0, 9.0, 2)), 14500.0, float(rng.uniform(8.0, 10.0)), 0.6)
                  for _ in range(int(rng.integers(0, 4)))]
        centre = rng.uniform(-2.0, 2.0, 2)
        side, exposure = float(rng.uniform(9.5, 11.0)), float(rng.uniform(1.8, 3.2))
        before = renderer.render(_beams(others) if others else None, BOARD_DNI_WM2, True, exposure)
        after = renderer.render(_beams(others + [(tuple(centre), BOARD_SPOT_POWER_W, side, 0.63)]), BOARD_DNI_WM2,
                                True, exposure)
        marks = find_marks(before, target, camera)
        row = {"center_m": centre.round(3).tolist(), "side_m": round(side, 2), "others": len(others),
               "distance_m": float(np.max(np.abs(centre)))}
        for name, lim in sides.items():
            res = measure_spot(before, [after], target, camera, marks=marks, limits=lim)
            row[name] = res.reason
            if res.valid:
                row[name + "_err_mm"] = 1000.0 * float(np.linalg.norm(res.offset_m - centre))
        rows.append(row)
    out: dict = {"spots": n, "seed": seed, "kind": "board", "reasons_pct": {}, "error": {}, "off": {}, "by_distance": []}
    for name in sides:
        counts: dict[str, int] = {}
        for r in rows:
            counts[r[name]] = counts.get(r[name], 0) + 1
        out["reasons_pct"][name] = {k: round(100.0 * v / n, 2) for k, v in sorted(counts.items())}
        err = np.array([r[name + "_err_mm"] for r in rows if name + "_err_mm" in r])
        out["error"][name] = _stats(err)
        out["off"][name] = {"over_0.1_m": int(np.sum(err > 100.0)), "over_0.5_m": int(np.sum(err > 500.0))}
    for lo, hi in ((0.0, 1.0), (1.0, 2.0)):
        row = {"distance_m": [lo, hi]}
        for name in sides:
            err = np.array([r[name + "_err_mm"] for r in rows if name + "_err_mm" in r and lo <= r["distance_m"] < hi])
            row[name] = {**_stats(err), "over_0.1_m": int(np.sum(err > 100.0))}
        out["by_distance"].append(row)
    out["refused_by_the_rule"] = sum(r["with"] == "fills_board" for r in rows)
    out["refused_were"] = {k: sum(r["with"] == "fills_board" and r["without"] == k for r in rows)
                           for k in sorted({r["without"] for r in rows if r["with"] == "fills_board"})}
    out["rows"] = rows
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spots", type=int, default=600)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--reach", type=float, default=7.0, help="spot centres within ± this [m] of the board centre")
    ap.add_argument("--kind", choices=("mixed", "beam", "board"), default="mixed",
                    help="mixed Gaussian and flat-topped spots, the simulated plant's (box blurred by a Gaussian), "
                         "or board-filling ones on bench500's board T4 with other beams")
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    out = run_board(args.spots, args.seed) if args.kind == "board" else run(args.spots, args.seed, args.reach, args.kind)
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}, indent=2))
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
