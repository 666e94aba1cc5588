"""CPU cost of the simulated plant per clock advance, lazy and stepped, as the field grows.

For each field size N (``sim-field`` fields, made if missing) and each plant (``lazy=True``, the
default, and the stepped reference ``lazy=False``): a tracking field at 10:00 local advanced
``--advances`` times by 2 plant seconds (nothing read), then ``--moves`` visits' worth of motion:
one random heliostat moved 5 mm per actuator and its status polled every 2 s until it holds.
Then the simulator's cost per measurement of one held heliostat: its true beam (wind jitter
drawn), the fast sensor's spot, and one deterministic normal draw. Prints a table and writes JSON
(``--out``). CPU time of this process (``time.process_time``).

    .venv/bin/python benchmarks/bench_sim_plant.py --sizes 1000,10000 --fields-dir /tmp/fields
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import timeit
from pathlib import Path

import numpy as np

from helicalib.app.simulated import default_start_s
from helicalib.config import load_field_config
from helicalib.devices.registers import HeliostatState
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario

SITE = "40.063,94.426,1267"


def field(n: int, fields_dir: Path) -> Path:
    path = fields_dir / f"field{n}.yaml"
    if not path.exists():
        fields_dir.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "helicalib", "sim-field", "--n", str(n), "--targets", "8",
                        "--site", SITE, "--out", str(path)], check=True)
    return path


def measure(cfg, lazy: bool, advances: int, moves: int) -> dict[str, float]:
    start = default_start_s(cfg) + 10 * 3600
    plant = SimulatedPlant(cfg, parse_scenario({"seed": 1}), start_s=start, lazy=lazy)
    plant.advance_to(start + 10.0)
    t = time.process_time()
    for _ in range(advances):
        plant.advance_to(plant.t_s + 2.0)
    advance_ms = 1000.0 * (time.process_time() - t) / advances
    rng = np.random.default_rng(0)
    t = time.process_time()
    for _ in range(moves):
        i = int(rng.integers(plant.n))
        plant.move_to(i, np.asarray(plant.status(i).strokes_mm) + np.array([5.0, -5.0]))
        while True:
            plant.advance_to(plant.t_s + 2.0)
            if plant.status(i).state == HeliostatState.HOLDING:
                break
    move_ms = 1000.0 * (time.process_time() - t) / moves
    return {"advance_ms": round(advance_ms, 4), "advances_per_cpu_s": round(1000.0 / advance_ms),
            "move_polled_to_holding_ms": round(move_ms, 3)}


def per_measurement(cfg, repeat: int = 2000) -> dict[str, float]:
    """CPU [µs] per call of what the fast sensor computes for one measured heliostat."""
    from helicalib.sim import noise
    from helicalib.sim.fast_sensor import fast_sensors

    start = default_start_s(cfg) + 10 * 3600
    plant = SimulatedPlant(cfg, parse_scenario({"seed": 1}), start_s=start)
    i = 5
    plant.move_to(i, np.asarray(plant.status(i).strokes_mm) + np.array([10.0, 10.0]))
    plant.advance_to(start + 100.0)  # held
    sensor = fast_sensors(plant, seed=1)[cfg.heliostat(cfg.heliostats[i].id).target]
    row = np.array([[i]])
    calls = {"true_beam_of_us": lambda: plant.true_beam_of(i), "fast_sensor_spot_us": lambda: sensor.spot(i),
             "noise_normal_one_row_us": lambda: noise.normal(1, 35, np.int64(123), row, np.arange(2)[None, :])}
    out = {}
    for name, fn in calls.items():
        fn()
        best = min(timeit.Timer(fn, timer=time.process_time).repeat(number=repeat, repeat=3))
        out[name] = round(1e6 * best / repeat, 1)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,10000", help="field sizes N, comma-separated")
    ap.add_argument("--fields-dir", type=Path, default=Path("benchmarks/out/fields"))
    ap.add_argument("--advances", type=int, default=3000)
    ap.add_argument("--moves", type=int, default=1000)
    ap.add_argument("--plants", default="lazy,stepped",
                    help="plants to time per advance ('' for none: only the per-measurement costs, as a build "
                         "without the lazy plant runs them)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out/bench_sim_plant.json"))
    a = ap.parse_args(argv)
    runs = []
    for n in (int(x) for x in a.sizes.split(",")) if a.plants else ():
        cfg = load_field_config(field(n, a.fields_dir))
        for lazy in (p == "lazy" for p in a.plants.split(",") if p):
            row = {"n": n, "plant": "lazy" if lazy else "stepped", **measure(cfg, lazy, a.advances, a.moves)}
            runs.append(row)
            print(f"N={n:>6} {row['plant']:>7}: {row['advance_ms']:.3f} ms per 2 s advance "
                  f"({row['advances_per_cpu_s']} per CPU s), {row['move_polled_to_holding_ms']:.2f} ms per move "
                  "polled to HOLDING", flush=True)
    sizes = [int(x) for x in a.sizes.split(",")]
    measurement = per_measurement(load_field_config(field(sizes[-1], a.fields_dir)))
    print(f"per measurement (N={sizes[-1]}): " + ", ".join(f"{k} {v}" for k, v in measurement.items()))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"date": time.strftime("%Y-%m-%d"), "args": {k: str(v) for k, v in vars(a).items()},
                                 "runs": runs, "per_measurement": measurement}, indent=1), encoding="utf-8")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
