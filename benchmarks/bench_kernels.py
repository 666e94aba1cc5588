"""Compiled geometry kernels against the numpy reference: time per call on one heliostat, the
crossover field size, and the cost of compiling (cold) or loading (warm) the kernels.

For each geometry function the campaign calls on a one-heliostat model (``HeliostatModel``'s
``strokes_for_aim``, ``normal``, ``angles``, ``beam``, ``spot_on_target``, ``normal_to_strokes``;
``drives``' linkage, normal and rotation functions; ``optics.aim_normal``) it times the numpy path
(``reference=True``) and the kernel path, best of ``--repeats`` runs of ``--calls`` calls each (the
best run is the least disturbed on a shared machine). Then, for ``strokes_for_aim`` and ``normal``,
both paths on models of N heliostats (``--sizes``), the kernel forced past ``kernels.MAX_ROWS``, to
show where numpy's vectorisation catches up. Last, ``kernels.warm()`` in fresh processes: with an
empty cache directory (compile) and again with it filled (load), ``NUMBA_CACHE_DIR`` pointing at a
temporary directory so the installed cache is left alone.

Usage::

    .venv/bin/python benchmarks/bench_kernels.py
    .venv/bin/python benchmarks/bench_kernels.py --calls 2000 --sizes 1,4,16,64,256,1024

Prints a table and writes ``benchmarks/out/bench_kernels.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
OUT = HERE / "out"

from helicalib.config import load_field_config  # noqa: E402
from helicalib.geometry import drives as dr  # noqa: E402
from helicalib.geometry import error_model as em  # noqa: E402
from helicalib.geometry import kernels, optics  # noqa: E402
from helicalib.geometry.heliostat import HeliostatModel  # noqa: E402
from helicalib.geometry.sun import sun_vector_from_angles  # noqa: E402

FIELD = ROOT / "simulations" / "fields" / "bench500.yaml"


def per_call_us(fn, calls: int, repeats: int) -> float:
    """Best of ``repeats`` runs of ``calls`` calls: µs per call."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - t0) / calls)
    return 1e6 * best


def one_heliostat_cases(model: HeliostatModel, sun: np.ndarray, aim: np.ndarray, target) -> dict:
    """name → callable(reference: bool) for each wired function on one heliostat."""
    sol = model.strokes_for_aim(sun, aim, reference=True)
    s, n, a = sol.strokes_mm, sol.normal_enu, sol.angles_rad
    app = np.array([1.0, -1.0])
    eff = model.drives_eff
    return {
        "HeliostatModel.strokes_for_aim": lambda r: model.strokes_for_aim(sun, aim, app, reference=r),
        "HeliostatModel.normal": lambda r: model.normal(s, app, reference=r),
        "HeliostatModel.angles": lambda r: model.angles(s, app, reference=r),
        "HeliostatModel.beam": lambda r: model.beam(s, sun, app, reference=r),
        "HeliostatModel.spot_on_target": lambda r: model.spot_on_target(s, sun, target, app, reference=r),
        "HeliostatModel.normal_to_strokes": lambda r: model.normal_to_strokes(n, app, reference=r),
        "drives.strokes_to_angles": lambda r: dr.strokes_to_angles(eff, s, reference=r),
        "drives.angles_to_strokes": lambda r: dr.angles_to_strokes(eff, a, reference=r),
        "drives.angles_to_normal": lambda r: dr.angles_to_normal(eff, a, reference=r),
        "drives.normal_to_angles": lambda r: dr.normal_to_angles(eff, n, reference=r),
        "drives.rotate": lambda r: dr.rotate(eff.axis1_enu, a[:, 0], eff.normal0_enu, reference=r),
        "optics.aim_normal": lambda r: optics.aim_normal(model.pivots_eff_enu[0], sun, aim,
                                                         float(eff.mirror_offset_m[0]), reference=r),
    }


def crossover(full: HeliostatModel, sun: np.ndarray, sizes: list[int], calls: int, repeats: int) -> list[dict]:
    """Per-heliostat time of both paths for N heliostats (the kernels forced above MAX_ROWS)."""
    rows = []
    limit = kernels.MAX_ROWS
    kernels.MAX_ROWS = 10 ** 9
    try:
        for n in sizes:
            model = full.subset(np.arange(n) % len(full))
            aims = np.tile(np.array([0.0, 9.0, 120.0]), (n, 1))
            strokes = model.strokes_for_aim(sun, aims, reference=True).strokes_mm
            k = max(1, calls // n)
            row = {"n": n}
            for name, fn in (("strokes_for_aim", lambda r: model.strokes_for_aim(sun, aims, reference=r)),
                             ("normal", lambda r: model.normal(strokes, reference=r))):
                row[f"{name}_numpy_us"] = per_call_us(lambda: fn(True), k, repeats)
                row[f"{name}_kernel_us"] = per_call_us(lambda: fn(False), k, repeats)
            rows.append(row)
    finally:
        kernels.MAX_ROWS = limit
    return rows


def warm_seconds() -> dict:
    """``kernels.warm()`` in a fresh process: into an empty cache (compile), then from it (load)."""
    code = "import time; t=time.perf_counter(); from helicalib.geometry import kernels; i=time.perf_counter()-t; " \
           "w=kernels.warm(); print(i, w['seconds'])"
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for label in ("cold", "warm"):
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            imp, w = (float(x) for x in res.stdout.split())
            out[label] = {"import_s": imp, "warm_s": w, "process_s": time.perf_counter() - t0}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000, help="calls per timed run (default %(default)s)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs, the best kept (default %(default)s)")
    ap.add_argument("--sizes", default="1,2,4,8,16,32,64,128,256,1024,4096")
    ap.add_argument("--out", default=str(OUT / "bench_kernels.json"))
    args = ap.parse_args()
    kernels.warm()
    cfg = load_field_config(FIELD)
    rng = np.random.default_rng(1)
    full = HeliostatModel.from_config(cfg)
    full = full.with_params(rng.normal(size=(len(full), em.P)) * em.PRIOR_SIGMA)
    sun = sun_vector_from_angles(150.0, 40.0)
    h = cfg.heliostats[0]
    target = cfg.target(h.target)
    one = full.subset([0])
    table = []
    for name, fn in one_heliostat_cases(one, sun, np.array(target.center_enu_m), target).items():
        t_np = per_call_us(lambda: fn(True), args.calls, args.repeats)
        t_k = per_call_us(lambda: fn(False), args.calls, args.repeats)
        table.append({"function": name, "numpy_us": t_np, "kernel_us": t_k, "speedup": t_np / t_k})
    print(f"{'one heliostat':<36}{'numpy µs':>10}{'kernel µs':>11}{'speed-up':>10}")
    for r in table:
        print(f"{r['function']:<36}{r['numpy_us']:>10.1f}{r['kernel_us']:>11.2f}{r['speedup']:>9.0f}×")
    sizes = [int(x) for x in args.sizes.split(",")]
    cross = crossover(full, sun, sizes, args.calls, args.repeats)
    print(f"\n{'N':>6}{'aim numpy µs/hel':>18}{'aim kernel':>12}{'normal numpy':>14}{'normal kernel':>15}")
    for r in cross:
        n = r["n"]
        print(f"{n:>6}{r['strokes_for_aim_numpy_us'] / n:>18.2f}{r['strokes_for_aim_kernel_us'] / n:>12.2f}"
              f"{r['normal_numpy_us'] / n:>14.2f}{r['normal_kernel_us'] / n:>15.2f}")
    warm = warm_seconds()
    for label, w in warm.items():
        print(f"\nkernels.warm() {label}: import {w['import_s']:.2f} s, warm {w['warm_s']:.2f} s, "
              f"process {w['process_s']:.2f} s", end="")
    print(f"\nMAX_ROWS = {kernels.MAX_ROWS} (kernels below it)")
    result = {"date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "machine": platform.machine(),
              "cpus": os.cpu_count(), "python": platform.python_version(), "load_average": os.getloadavg(),
              "calls": args.calls, "repeats": args.repeats, "max_rows": kernels.MAX_ROWS,
              "one_heliostat": table, "crossover": cross, "warm": warm}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
