"""``helicalib validate FIELD.yaml``: check a field config and print a summary of the plant."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from helicalib.commands._args import int_in


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check a field config and summarise the plant",
                       description="Validate a field config; print a summary (exit 0) or every problem, one per line (exit 1).")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--no-sweep", action="store_true",
                   help="skip the stroke-feasibility sweep (strokes for every heliostat's target over a year)")
    p.add_argument("--year", type=int_in(1900, 2200), default=2026, help="year of the stroke-feasibility sweep (default 2026)")
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
        "cameras": len(cfg.cameras),  # 0: a plant description (an import), fitted and reported but not measured
        "plant": plant_summary(cfg),
        "database": str(cfg.database_path),
    }


def plant_summary(cfg) -> dict:
    """How the SCS is reached: protocol, endpoint, the map (loaded and checked: a broken map is a
    :class:`~helicalib.errors.ConfigError` naming the file and key), the clock."""
    p = cfg.plant
    if p.protocol == "modbus":
        from helicalib.devices.regmap import register_map_of

        rmap = register_map_of(cfg)
        return {"protocol": "modbus", "scs": f"{p.scs.host}:{p.scs.port} unit {p.scs.unit}",
                "register_map": rmap.name, "clock": p.clock}
    from helicalib.devices.nodemap import load_node_map

    nmap = load_node_map(p.opcua.node_map, cfg.resolve_path)
    return {"protocol": "opcua", "scs": p.opcua.endpoint, "node_map": nmap.name,
            "security_policy": p.opcua.security_policy, "clock": p.clock}


def stroke_feasibility(cfg, year: int = 2026, min_elevation_deg: float = 5.0, every_days: int = 7,
                       every_hours: float = 0.5) -> dict:
    """Whether each heliostat's strokes for its target stay in range for all sun elevations ≥ 5° over a year.

    Sun positions every ``every_hours`` h (UTC) on every ``every_days``-th day of ``year``; aim = the
    centre of the heliostat's target. Returns plain data: per heliostat ``in_range`` and
    ``worst_margin_mm`` (smallest distance inside the stroke range over both actuators; negative =
    outside, null = unreachable), and per drive the stroke span actually used.
    """
    import pandas as pd

    from helicalib.geometry.heliostat import HeliostatModel, stroke_sweep
    from helicalib.geometry.sun import sun_at_site

    times = pd.date_range(f"{year}-01-01", f"{year}-12-31 23:00", freq=f"{round(every_hours * 60)}min", tz="UTC")
    times = times[(times.day_of_year - 1) % every_days == 0]
    sp = sun_at_site(cfg.site, times)
    up = np.asarray(sp.elevation_deg) >= min_elevation_deg
    sun = np.asarray(sp.vector_enu)[up]
    model = HeliostatModel.from_config(cfg)
    aims = np.array([cfg.target(h.target).center_enu_m for h in cfg.heliostats], dtype=float)
    sweep = stroke_sweep(model, sun, aims)
    margin = sweep["margin_mm"]  # (T, N, 2)
    worst_t = np.argmin(margin.min(axis=2), axis=0)  # (N,)
    per = {}
    for i, h in enumerate(cfg.heliostats):
        m = float(margin[:, i, :].min())
        worst_axis = int(np.argmin(margin[worst_t[i], i, :]))
        per[h.id] = {"in_range": bool(sweep["in_range"][:, i].all()),
                     "worst_margin_mm": None if not np.isfinite(m) else round(m, 1),
                     "worst_actuator": worst_axis + 1,
                     "worst_time_utc": times[up][worst_t[i]].isoformat(),
                     "out_of_range_fraction": round(float(1.0 - sweep["in_range"][:, i].mean()), 4)}
    drives = {}
    for name in cfg.drives:
        sel = np.array([h.drive == name for h in cfg.heliostats])
        if not sel.any():
            continue
        s = sweep["strokes_mm"][:, sel, :]
        d = cfg.drives[name]
        drives[name] = {"stroke_used_mm": [[round(float(np.nanmin(s[..., k])), 1), round(float(np.nanmax(s[..., k])), 1)]
                                           for k in range(2)],
                        "stroke_range_mm": [list(a.stroke_range_mm) for a in d.actuators]}
    bad = [hid for hid, v in per.items() if not v["in_range"]]
    finite = [v["worst_margin_mm"] for v in per.values() if v["worst_margin_mm"] is not None]
    return {"year": year, "sun_positions": int(up.sum()), "min_elevation_deg": min_elevation_deg,
            "every_days": every_days, "every_hours": every_hours, "feasible": not bad, "out_of_range": bad,
            "worst_margin_mm": (min(finite) if len(finite) == len(per) else None), "drives": drives,
            "heliostats": per}


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
    try:
        summary = summarise(cfg)
    except ConfigError as err:  # the plant's register or node map
        for line in err.problems:
            print(line, file=sys.stderr)
        print(f"{args.field}: {len(err.problems)} problem(s); not valid", file=sys.stderr)
        return 1
    sweep = None if getattr(args, "no_sweep", False) else stroke_feasibility(cfg, year=getattr(args, "year", 2026))
    if args.json:
        if sweep is not None:
            summary = dict(summary, stroke_feasibility=sweep)
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
    if not summary["cameras"]:
        print("cameras   none: this field can be fitted, reported and exported, not measured (run, check, simulate)")
    for name, d in summary["drives"].items():
        print(f"drive     {name} ({d['kind']}): {d['heliostats']} heliostats")
    pl = summary["plant"]
    layout = f"register map {pl['register_map']}" if pl["protocol"] == "modbus" else f"node map {pl['node_map']}"
    print(f"plant     SCS {pl['protocol']} {pl['scs']}, {layout}, clock {pl['clock']}")
    print(f"storage   {summary['database']}")
    if sweep is not None:
        _print_sweep(sweep)
    return 0


def _print_sweep(sweep: dict) -> None:
    head = (f"strokes   sun elevation >= {sweep['min_elevation_deg']:g}° over {sweep['year']} "
            f"({sweep['sun_positions']} sun positions, every {sweep['every_hours']:g} h on every {sweep['every_days']}th day): ")
    if sweep["feasible"]:
        print(head + f"all heliostats in range, worst margin {sweep['worst_margin_mm']} mm")
    else:
        print(head + f"OUT OF RANGE for {len(sweep['out_of_range'])} heliostat(s): {', '.join(sweep['out_of_range'][:10])}"
              + (" ..." if len(sweep["out_of_range"]) > 10 else ""))
    for name, d in sweep["drives"].items():
        used = "; ".join(f"actuator {k + 1} uses {u[0]}..{u[1]} of {r[0]:g}..{r[1]:g} mm"
                         for k, (u, r) in enumerate(zip(d["stroke_used_mm"], d["stroke_range_mm"])))
        print(f"strokes   drive {name}: {used}")
