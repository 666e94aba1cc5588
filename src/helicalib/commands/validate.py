"""``helicalib validate FIELD.yaml``: check a field config and print a summary of the plant."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check a field config and summarise the plant",
                       description="Validate a field config; print a summary (exit 0) or every problem, one per line (exit 1).")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def summarise(cfg) -> dict:
    """Plain-data summary of a validated field config: site, counts and slant ranges."""
    pos = cfg.heliostat_positions_enu_m()
    per_target = {}
    for t in cfg.targets:
        sel = np.array([h.target == t.id for h in cfg.heliostats])
        dist = np.linalg.norm(pos[sel] - np.asarray(t.center_enu_m), axis=1) if sel.any() else np.array([])
        per_target[t.id] = {
            "heliostats": int(sel.sum()),
            "cameras": [c.id for c in cfg.cameras_for(t.id)],
            "slant_range_m": None if dist.size == 0 else
            {"min": round(float(dist.min()), 1), "mean": round(float(dist.mean()), 1), "max": round(float(dist.max()), 1)},
        }
    per_drive = {name: sum(h.drive == name for h in cfg.heliostats) for name in cfg.drives}
    ground = np.linalg.norm(pos[:, :2], axis=1)
    s = cfg.site
    return {
        "file": str(cfg.source),
        "site": {"name": s.name, "latitude_deg": s.latitude_deg, "longitude_deg": s.longitude_deg,
                 "altitude_m": s.altitude_m, "pressure_hpa": round(s.pressure_hpa_effective, 1),
                 "temperature_c": s.temperature_c},
        "heliostats": len(cfg.heliostats),
        "ground_distance_to_tower_m": {"min": round(float(ground.min()), 1), "max": round(float(ground.max()), 1)},
        "targets": per_target,
        "drives": {name: {"kind": cfg.drives[name].kind, "heliostats": n} for name, n in per_drive.items()},
        "plant": {"scs": f"{cfg.plant.scs.host}:{cfg.plant.scs.port}", "clock": cfg.plant.clock},
        "database": str(cfg.database_path),
    }


def run(args) -> int:
    from helicalib.config import load_field_config
    from helicalib.errors import ConfigError

    try:
        cfg = load_field_config(args.field)
    except ConfigError as err:
        for line in err.problems:
            print(line, file=sys.stderr)
        print(f"{args.field}: {len(err.problems)} problem(s); not valid", file=sys.stderr)
        return 1
    summary = summarise(cfg)
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    s = summary["site"]
    print(f"{summary['file']}: valid")
    print(f"site      {s['name']}  {s['latitude_deg']:.4f}°, {s['longitude_deg']:.4f}°, {s['altitude_m']:.0f} m, "
          f"{s['pressure_hpa']} hPa, {s['temperature_c']} °C")
    g = summary["ground_distance_to_tower_m"]
    print(f"field     {summary['heliostats']} heliostats, {g['min']}-{g['max']} m from the tower")
    for tid, t in summary["targets"].items():
        r = t["slant_range_m"]
        rng = "no heliostats" if r is None else f"slant range {r['min']}-{r['max']} m (mean {r['mean']})"
        cams = ", ".join(t["cameras"]) or "NO CAMERA"
        print(f"target    {tid}: {t['heliostats']} heliostats, camera {cams}, {rng}")
    for name, d in summary["drives"].items():
        print(f"drive     {name} ({d['kind']}): {d['heliostats']} heliostats")
    print(f"plant     SCS {summary['plant']['scs']}, clock {summary['plant']['clock']}")
    print(f"storage   {summary['database']}")
    return 0
