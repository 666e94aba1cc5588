"""``helicalib demo FIELD --out DIR``: what ``make demo`` runs.

Validates the field and prints the sun's path over its site for a day (hourly, NREL SPA), written
to ``DIR/sun_path.json``. When the campaign is available it runs a simulated campaign instead.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the demo run of `make demo`")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--date", default="2026-06-21", help="day for the sun path (YYYY-MM-DD, site's UTC day)")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np
    import pandas as pd
    from rich.console import Console
    from rich.table import Table

    from helicalib.commands.validate import summarise
    from helicalib.config import load_field_config
    from helicalib.geometry.sun import sun_at_site

    console = Console()
    cfg = load_field_config(args.field)
    summary = summarise(cfg)
    console.print(f"[bold]{cfg.site.name}[/]: {summary['heliostats']} heliostats on "
                  f"{len(cfg.targets)} targets — field config valid")
    # local solar noon ≈ 12:00 − longitude/15 h UTC; sample 24 h around it
    noon_utc = pd.Timestamp(args.date, tz="UTC") + pd.Timedelta(hours=12 - cfg.site.longitude_deg / 15.0)
    times = pd.date_range(noon_utc - pd.Timedelta(hours=12), periods=25, freq="1h")
    pos = sun_at_site(cfg.site, times)
    table = Table(title=f"Sun over {cfg.site.name} on {args.date} (NREL SPA, apparent)")
    for col in ("UTC", "azimuth °", "elevation °"):
        table.add_column(col, justify="right")
    rows = []
    for t, az, el in zip(times, pos.azimuth_deg, pos.elevation_deg):
        rows.append({"time_utc": t.isoformat(), "azimuth_deg": float(az), "elevation_deg": float(el)})
        if el > -5:
            table.add_row(t.strftime("%H:%M"), f"{az:.2f}", f"{el:.2f}")
    console.print(table)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sun_path.json").write_text(json.dumps({"field": summary, "sun_path": rows}, indent=2))
    console.print(f"max elevation {np.max(pos.elevation_deg):.2f}° — written {out / 'sun_path.json'}")
    return 0
