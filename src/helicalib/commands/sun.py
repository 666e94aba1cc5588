"""``helicalib sun``: the apparent topocentric sun position (NREL SPA) for a site and instant."""

from __future__ import annotations

import argparse
import json

from helicalib.commands._args import finite_float, float_in, iso_time


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sun", help="sun azimuth/elevation and ENU vector (NREL SPA)",
                       description="Apparent topocentric sun position by NREL SPA. --time needs a zone offset.")
    p.add_argument("--lat", type=float_in(-90.0, 90.0), required=True, help="latitude [deg, north positive]")
    p.add_argument("--lon", type=float_in(-180.0, 180.0), required=True, help="longitude [deg, east positive]")
    p.add_argument("--time", required=True, help="ISO 8601 instant with offset, e.g. 2026-06-21T12:00:00+08:00")
    p.add_argument("--altitude-m", type=float_in(-1000.0, 10000.0), default=0.0, help="site altitude [m] (default 0)")
    p.add_argument("--pressure-hpa", type=float_in(0.0, 2000.0, open_lo=True), default=None, help="air pressure [hPa] (default: standard atmosphere at the altitude)")
    p.add_argument("--temperature-c", type=float_in(-100.0, 100.0), default=12.0, help="air temperature [°C] (default 12)")
    p.add_argument("--delta-t-s", type=finite_float, default=None, help="TT-UT1 [s] (default: pvlib's estimate for the date)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args) -> int:
    from helicalib.errors import ConfigError
    from helicalib.geometry.sun import parse_time, sun_position

    if not -90 <= args.lat <= 90:
        raise ConfigError(f"--lat {args.lat}: latitude must lie in [-90, 90]")
    if not -180 <= args.lon <= 180:
        raise ConfigError(f"--lon {args.lon}: longitude must lie in [-180, 180]")
    try:
        iso_time(args.time)  # an instant with offset in the years the sun code can represent
    except argparse.ArgumentTypeError as err:
        raise ConfigError(f"--time: {err}") from None
    t = parse_time(args.time)
    pos = sun_position(t, args.lat, args.lon, args.altitude_m, args.pressure_hpa, args.temperature_c, args.delta_t_s)
    out = {
        "time_utc": t.isoformat(),
        "azimuth_deg": float(pos.azimuth_deg),
        "elevation_deg": float(pos.elevation_deg),
        "zenith_deg": float(pos.zenith_deg),
        "vector_enu": [float(x) for x in pos.vector_enu],
    }
    if args.json:
        print(json.dumps(out))
    else:
        v = out["vector_enu"]
        print(f"{out['time_utc']}  azimuth {out['azimuth_deg']:.5f}°  elevation {out['elevation_deg']:.5f}°  "
              f"zenith {out['zenith_deg']:.5f}°  vector ENU ({v[0]:.6f}, {v[1]:.6f}, {v[2]:.6f})")
    return 0
