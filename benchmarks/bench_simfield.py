"""``sim-field`` benchmark: time and peak memory to generate fields of 2000, 10 000 and 30 000 heliostats.

Each size runs ``helicalib sim-field --site 40.06,94.43,1267`` (the demo site) in its own process,
CSV and YAML written and loaded back, and reports that process's wall time, CPU time (user +
system) and peak resident memory (``getrusage`` of the child), and the heliostats per board.
Prints the figures and writes ``benchmarks/out/bench_simfield.json``.

    .venv/bin/python benchmarks/bench_simfield.py [--sizes 2000:4 10000:8 30000:8]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

OUT = Path(__file__).resolve().parent / "out" / "bench_simfield.json"
SITE = "40.06,94.43,1267"
SIZES = ("2000:4", "10000:8", "30000:8")


def run_one(n: int, targets: int, workdir: Path) -> dict:
    """One ``sim-field`` run in a child process: wall, CPU, peak memory, board counts."""
    out = workdir / f"field_{n}.yaml"
    cmd = [sys.executable, "-m", "helicalib", "sim-field", "--n", str(n), "--site", SITE, "--targets", str(targets),
           "--out", str(out)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    stdout = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"sim-field --n {n} failed (exit {proc.returncode})")
    counts = {k: int(v) for k, v in re.findall(r"'(T\d+)': (\d+)", stdout)}
    peak_mb = usage.ru_maxrss / 1024.0 if sys.platform != "darwin" else usage.ru_maxrss / 2**20
    return {"n": n, "targets": targets, "wall_s": round(wall, 2), "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
            "peak_rss_mb": round(peak_mb, 1), "board_counts": counts,
            "board_spread": max(counts.values()) - min(counts.values()) if counts else None}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=list(SIZES), help="N:TARGETS pairs (default %(default)s)")
    args = ap.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench_simfield_") as tmp:
        for spec in args.sizes:
            n, targets = (int(x) for x in spec.split(":"))
            r = run_one(n, targets, Path(tmp))
            runs.append(r)
            print(f"sim-field --n {n:>6} --targets {targets:>2}: {r['wall_s']:7.2f} s wall, {r['cpu_s']:7.2f} s CPU, "
                  f"peak {r['peak_rss_mb']:6.0f} MB, boards {min(r['board_counts'].values())}.."
                  f"{max(r['board_counts'].values())} heliostats", flush=True)
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"site": SITE, "cpus": os.cpu_count(), "machine": platform.machine(),
                               "load_average_after": load, "runs": runs}, indent=2))
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
