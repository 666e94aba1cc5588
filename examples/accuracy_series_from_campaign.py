"""Write a ``helicalib accuracy`` series (SERIES.csv) from a simulated campaign's observations.

    .venv/bin/python examples/accuracy_series_from_campaign.py OUT/observations.csv FIELD.yaml SERIES.csv
                     [--after-hours 24]

Every valid first shot of a visit (iteration 0: the heliostat sent to its own board's centre by
the model the campaign had then, the spot measured by the camera) becomes one row of the tracking
test: ``time`` (UTC), ``heliostat``, ``wind_ms`` and the spot centre ``u_m, v_m`` on the board,
from the observation's spot position (``spot_e_m, spot_n_m, spot_u_m``) in the board's frame.
Visits on a borrowed board are left out (the test measures against the heliostat's own target),
and so are the first ``--after-hours`` of the campaign, while the models are still being learnt.

``examples/accuracy_series.csv`` was made so, from the second day of a windy simulated campaign on
the demo field (wind 1-10 m/s, so that the 4 and 8 m/s bins of clause 8.2 fill)::

    helicalib simulate field_config/demo_north.yaml --days 2 --scenario simulations/scenarios/windy.yaml \
        --refine --out windy_out
    .venv/bin/python examples/accuracy_series_from_campaign.py windy_out/observations.csv \
        field_config/demo_north.yaml examples/accuracy_series.csv
"""

from __future__ import annotations

import argparse
import csv
from datetime import datetime, timezone

import numpy as np

from helicalib.config import load_field_config


def series_rows(observations_csv, field_yaml, after_hours: float = 24.0) -> list[dict]:
    cfg = load_field_config(field_yaml)
    with open(observations_csv, newline="") as fh:
        obs = list(csv.DictReader(fh))
    if not obs:
        return []
    t0 = min(float(o["capture_time_s"]) for o in obs)
    rows = []
    for o in obs:
        t = float(o["capture_time_s"])
        hid = o["heliostat_id"]
        own = cfg.heliostat(hid).target
        if o["valid"] != "True" or o["iteration"] != "0" or o["target_id"] != own or t < t0 + 3600.0 * after_hours:
            continue
        target = cfg.target(own)
        u, v, _ = target.enu_to_uvw(np.array([float(o["spot_e_m"]), float(o["spot_n_m"]), float(o["spot_u_m"])]))
        rows.append({"time": datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="seconds"),
                     "heliostat": hid, "wind_ms": f"{float(o['wind_ms']):.2f}", "u_m": f"{u:.4f}", "v_m": f"{v:.4f}"})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("observations", help="observations.csv of a campaign (helicalib simulate/demo --out DIR)")
    ap.add_argument("field", help="the campaign's field config")
    ap.add_argument("out", help="SERIES.csv to write")
    ap.add_argument("--after-hours", type=float, default=24.0, help="leave out the campaign's first hours (24)")
    args = ap.parse_args()
    rows = series_rows(args.observations, args.field, args.after_hours)
    with open(args.out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["time", "heliostat", "wind_ms", "u_m", "v_m"])
        w.writeheader()
        w.writerows(rows)
    print(f"{args.out}: {len(rows)} measurements of {len({r['heliostat'] for r in rows})} heliostats")


if __name__ == "__main__":
    main()
