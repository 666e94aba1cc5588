"""Write ``fit_observations.csv``: the valid observations of a short simulated campaign (two demo
heliostats, one plant day, round robin, seed 1), for the fit's equivalence tests.

Run from the repository root: ``.venv/bin/python tests/data/make_fit_observations.py``.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
COLUMNS = ["heliostat_id", "target_id", "visit_id", "iteration", "stroke_cmd_1_mm", "stroke_cmd_2_mm",
           "stroke_read_1_mm", "stroke_read_2_mm", "approach_1", "approach_2", "sun_e", "sun_n", "sun_u",
           "spot_e_m", "spot_n_m", "spot_u_m"]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "helicalib", "simulate", str(ROOT / "field_config" / "demo_north.yaml"),
                        "--days", "1", "--seed", "1", "--planner", "round-robin", "--heliostats", "H0001,H0017",
                        "--out", tmp], check=True)
        obs = pd.read_csv(Path(tmp) / "observations.csv")
    obs = obs[obs["valid"].astype(str) == "True"].dropna(subset=["spot_e_m", "spot_n_m", "spot_u_m"])
    obs[COLUMNS].to_csv(HERE / "fit_observations.csv", index=False, float_format="%.12g")
    print(f"wrote {HERE / 'fit_observations.csv'} ({len(obs)} observations)")


if __name__ == "__main__":
    main()
