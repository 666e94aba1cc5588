"""``helicalib aim FIELD --heliostat H --time ISO``: strokes that put a heliostat's beam on a target."""

from __future__ import annotations

import argparse
import json

from helicalib.commands._args import float_in, iso_time


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("aim", help="strokes, axis angles and normal that put a heliostat's beam on a target",
                       description="Solve the nominal heliostat model (or one with --params) for the strokes that put "
                                   "the beam of --heliostat on the centre of --target (default: its own target) at --time.")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--heliostat", required=True, help="heliostat id, e.g. H0001")
    p.add_argument("--target", default=None, help="target id (default: the heliostat's target)")
    p.add_argument("--time", required=True, type=iso_time, help="ISO 8601 instant with offset, e.g. 2026-06-21T12:00:00+08:00")
    p.add_argument("--uv", type=float_in(-1e5, 1e5), nargs=2, metavar=("U_M", "V_M"), default=(0.0, 0.0),
                   help="aim point on the target in the target frame [m] (default: the centre)")
    p.add_argument("--params", default=None,
                   help="JSON file {name: value} of error-model parameters (default: the nominal heliostat)")
    p.add_argument("--approach", type=int, nargs=2, metavar=("A1", "A2"), choices=(-1, 1), default=None,
                   help="each actuator's arrival direction (+1 extending, -1 retracting) for the dead bands "
                        "(backlash_1_mm, backlash_2_mm) of --params; default: the middle of the dead bands")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def aim(cfg, heliostat_id: str, target_id: str | None, time, uv_m=(0.0, 0.0), params: dict | None = None,
        approach=None) -> dict:
    """Plain-data aim solution for one heliostat (see ``run``)."""
    import numpy as np

    from helicalib.geometry import error_model as em
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.geometry.sun import parse_time, sun_at_site

    h = cfg.heliostat(heliostat_id)
    target = cfg.target(target_id or h.target)
    t = parse_time(time)
    sun = sun_at_site(cfg.site, t)
    row = em.from_dict(params or {})
    model = HeliostatModel.from_config(cfg, [heliostat_id], params=row[None, :])
    aim_enu = target.uvw_to_enu(np.asarray(uv_m, dtype=float))
    sol = model.strokes_for_aim(np.asarray(sun.vector_enu, dtype=float), aim_enu,
                                None if approach is None else np.asarray(approach, dtype=float))

    def num(x):
        return None if not np.isfinite(x) else float(x)

    return {
        "heliostat": heliostat_id, "target": target.id, "time_utc": t.isoformat(),
        "aim_enu_m": [float(v) for v in aim_enu],
        "sun": {"azimuth_deg": float(sun.azimuth_deg), "elevation_deg": float(sun.elevation_deg),
                "vector_enu": [float(v) for v in np.ravel(sun.vector_enu)]},
        "strokes_mm": [num(v) for v in sol.strokes_mm[0]],
        "angles_deg": [num(v) for v in np.degrees(sol.angles_rad[0])],
        "normal_enu": [float(v) for v in sol.normal_enu[0]],
        "stroke_range_mm": [[float(model.drives.stroke_min_mm[0, k]), float(model.drives.stroke_max_mm[0, k])]
                            for k in range(2)],
        "in_range": bool(sol.in_range[0]), "reachable": bool(sol.reachable[0]),
        "sun_up": bool(float(sun.elevation_deg) > 0.0),
        "params": {k: v for k, v in em.as_dict(row).items() if v != 0.0},
        "approach": None if approach is None else [int(a) for a in approach],
    }


def run(args) -> int:
    import math

    from helicalib.config import load_field_config, read_text
    from helicalib.errors import ConfigError

    cfg = load_field_config(args.field)
    params = None
    if args.params:
        try:
            params = json.loads(read_text(args.params))
            if not isinstance(params, dict):
                raise ValueError("expected a JSON object {name: value}")
            for name, value in params.items():
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ValueError(f"{name}: expected a finite number, got {str(value)[:40]!r}")
            out = aim(cfg, args.heliostat, args.target, args.time, args.uv, params, args.approach)
        except (OSError, ValueError, KeyError, OverflowError) as err:
            raise ConfigError(f"--params {args.params}: {err}") from None
    else:
        out = aim(cfg, args.heliostat, args.target, args.time, args.uv, approach=args.approach)
    if args.json:
        print(json.dumps(out))
        return 0
    s = out["sun"]
    fmt = lambda xs, f: ", ".join("n/a" if x is None else format(x, f) for x in xs)  # noqa: E731
    print(f"{out['heliostat']} → {out['target']} at {out['time_utc']}  "
          f"(sun azimuth {s['azimuth_deg']:.3f}°, elevation {s['elevation_deg']:.3f}°)")
    print(f"strokes   {fmt(out['strokes_mm'], '.2f')} mm   (range {out['stroke_range_mm'][0]} / {out['stroke_range_mm'][1]})"
          f"   {'in range' if out['in_range'] else 'OUT OF RANGE' if out['reachable'] else 'UNREACHABLE'}")
    print(f"angles    {fmt(out['angles_deg'], '.4f')} °")
    print(f"normal    ({fmt(out['normal_enu'], '.6f')}) ENU")
    if not out["sun_up"]:
        print("note      the sun is below the horizon at this time")
    return 0
