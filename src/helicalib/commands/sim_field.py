"""``helicalib sim-field``: write a simulated field config (+ heliostat CSV) feasible all year."""

from __future__ import annotations

import argparse
from collections import Counter

from helicalib.commands._args import int_in, site_text

MAX_HELIOSTATS = 50000
SIGNATURE = "# written by helicalib sim-field; helicalib sim-field may overwrite this file and its CSV"
"""The first line of every FIELD.yaml sim-field writes: only such a file (and its CSV) is overwritten."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim-field", help="generate a field config with a radial-staggered layout",
                       description="Write FIELD.yaml and FIELD.csv: n tilt-roll heliostats in staggered rings on the "
                                   "pole side of the tower, each feasible (strokes in range for its target and the "
                                   "receiver) at every sun position >= 5 deg of the year, shared out evenly over "
                                   "the boards by azimuth (board counts differ by at most one). See docs/simulator.md.")
    p.add_argument("--n", type=int_in(1, MAX_HELIOSTATS), required=True,
                   help=f"number of heliostats (1..{MAX_HELIOSTATS})")
    p.add_argument("--site", required=True, type=site_text, help="LAT,LON[,ALT] in degrees (north, east positive) and metres")
    p.add_argument("--layout", default="radial-staggered", choices=["radial-staggered"], help="field layout")
    p.add_argument("--targets", type=int_in(1, 12), default=4, help="calibration boards on the tower (default 4)")
    p.add_argument("--name", default=None, help="site name")
    p.add_argument("--out", required=True, help="output YAML path (the CSV is written beside it); an existing file is "
                   "overwritten only if sim-field wrote it")
    p.set_defaults(func=run)


def run(args) -> int:
    from helicalib.commands._progress import ProgressReporter
    from helicalib.errors import ConfigError
    from helicalib.sim.field import generate_field, write_field

    try:
        parts = [float(x) for x in args.site.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (2, 3) or not -90 <= parts[0] <= 90 or not -180 <= parts[1] <= 180:
        raise ConfigError(f"--site {args.site!r}: expected LAT,LON[,ALT] with LAT in [-90, 90], LON in [-180, 180]")
    if abs(parts[0]) < 5 or abs(parts[0]) > 66:
        raise ConfigError(f"--site: latitude {parts[0]}: the generator lays a pole-side field; use 5 <= |lat| <= 66")
    if not 1 <= args.n <= MAX_HELIOSTATS:
        raise ConfigError(f"--n {args.n}: expected 1..{MAX_HELIOSTATS}")
    if not 1 <= args.targets <= 12:
        raise ConfigError(f"--targets {args.targets}: expected 1..12")
    out = _check_outputs(args.out)   # before the year's checks: a refusal costs nothing
    with ProgressReporter("sim-field", None) as bar:
        def progress(done: int, total: int, candidates: int) -> None:
            bar.update(done, f"year's stroke checks {100 * done / total:.0f} % ({done} of {total}), "
                             f"{candidates} candidate positions", total=total)

        data, rows = generate_field(args.n, parts[0], parts[1], parts[2] if len(parts) == 3 else 0.0,
                                    targets=args.targets, name=args.name, progress=progress)
    cfg = write_field(data, rows, out)
    out.write_text(f"{SIGNATURE}\n{out.read_text(encoding='utf-8')}", encoding="utf-8")
    per = Counter(h.target for h in cfg.heliostats)
    counts = {t.id: per[t.id] for t in cfg.targets}
    print(f"sim-field: wrote {args.out} and its CSV: {len(cfg.heliostats)} heliostats, tower "
          f"{cfg.tower.receiver_aim_enu_m[2]:.0f} m, targets {counts}")
    return 0


def _check_outputs(path: str):
    """FIELD.yaml and the FIELD.csv beside it: new, or both written by sim-field before; else one line."""
    from pathlib import Path

    from helicalib.errors import ConfigError
    from helicalib.outdir import check_file_output

    out = check_file_output(path, SIGNATURE, "sim-field")
    if out.suffix.lower() == ".csv":
        raise ConfigError(f"--out {path}: give the YAML file's name (the CSV is written beside it)")
    csv = out.with_suffix(".csv")
    if csv.is_dir() or (csv.exists() and not out.exists()):
        raise ConfigError(f"--out {path}: {csv} exists and was not written by helicalib sim-field; give a new file "
                          "name")
    return out
