"""Real seconds ``helicalib probe`` takes against a simulated plant of N heliostats on loopback.

For each N (``--sizes``; the default register map,
PLANT_INTERFACE.md's, addresses at most 2016 heliostats) writes a field with ``sim-field`` (4 boards, Dunhuang), serves it with the
simulated plant's Modbus TCP server and HTTP cameras on 127.0.0.1 (plant time at 60×), and runs
``helicalib probe FIELD --json`` in-process: the wall time of the whole probe, the heliostat reads
per second, the exit status and the counts of the checks. The simulated plant's server composes
each register block from its state (a real SCS answers from memory), so the figures bound a real
plant's probe from above on the same link.

Usage::

    .venv/bin/python benchmarks/bench_probe.py
    .venv/bin/python benchmarks/bench_probe.py --sizes 1000,10000

Writes ``benchmarks/out/bench_probe.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def probe_once(n: int, tmp: Path) -> dict:
    import yaml

    from helicalib.app.simulated import default_start_s
    from helicalib.cli import main
    from helicalib.config import load_field_config
    from helicalib.sim.clock import RateClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario
    from helicalib.sim.server import PlantServer

    field = tmp / f"field{n}.yaml"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["sim-field", "--n", str(n), "--site", "40.063,94.426,1267", "--out", str(field)]) == 0
    cfg = load_field_config(field)
    start = default_start_s(cfg) + 9 * 3600
    sim = SimulatedPlant(cfg, Scenario(seed=1), start_s=start, rate=60.0)
    with PlantServer(sim, RateClock(start, 60.0, time.monotonic, time.sleep), modbus_port=0, camera_port=0) as server:
        data = yaml.safe_load(field.read_text())
        data["plant"]["scs"]["port"] = server.modbus_port
        for cam in data["cameras"]:
            cam["url"] = server.camera_url(cam["id"])
        field.write_text(yaml.safe_dump(data, sort_keys=False))
        out = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(out):
            code = main(["probe", str(field), "--json"])
        took = time.perf_counter() - t0
    if code not in (0, 1):  # a field the map cannot address (PLANT_INTERFACE 1 ends near 2000 heliostats)
        return {"heliostats": n, "cameras": len(cfg.cameras), "exit_status": code, "wall_s": round(took, 3),
                "heliostat_reads_per_s": None, "checks": 0, "rows_shown": 0, "summary": None}
    doc = json.loads(out.getvalue())
    return {"heliostats": n, "cameras": len(cfg.cameras), "exit_status": code, "wall_s": round(took, 3),
            "heliostat_reads_per_s": round(n / took, 1), "checks": doc["summary"]["checks"],
            "rows_shown": len(doc["checks"]), "summary": doc["summary"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="40,1000,2000", help="comma-separated heliostat counts")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(s) for s in args.sizes.split(",")):
            row = probe_once(n, Path(tmp))
            rows.append(row)
            if row["summary"] is None:
                print(f"{n:6d} heliostats: probe refused the field (exit {row['exit_status']})", flush=True)
                continue
            print(f"{n:6d} heliostats, {row['cameras']} cameras: probe {row['wall_s']:.2f} s "
                  f"({row['heliostat_reads_per_s']:.0f} heliostats/s), exit {row['exit_status']}, "
                  f"{row['checks']} checks, {row['rows_shown']} rows shown", flush=True)
    out = HERE / "out" / "bench_probe.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"date": time.strftime("%Y-%m-%d"), "python": sys.version.split()[0], "rows": rows},
                              indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
