"""``helicalib import-paint DIR... --out OUTDIR``: PAINT / ARTIST calibration data → field config + observations."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-paint", help="import PAINT calibration records as a field config and observations",
                       description="Read PAINT tower-measurements.json, heliostat-properties.json, HeliOS axis/"
                                   "position CSVs and *-calibration-properties.json under DIR... and write "
                                   "OUTDIR/field.yaml (our schema, one custom drive per heliostat reproducing the "
                                   "PAINT kinematics) and OUTDIR/observations.csv.")
    p.add_argument("dirs", nargs="+", metavar="DIR", help="directories (searched recursively) or files")
    p.add_argument("--out", required=True, help="output folder: new, empty or a previous import (replaced); any "
                   "other folder is refused")
    p.add_argument("--spot", choices=["UTIS", "HeliOS"], default="UTIS",
                   help="which of the record's spot centres is the observation (default UTIS)")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=run)


_READ = ("tower-measurements.json", "heliostat-properties.json", "calibration-properties", "axis_data.csv",
         "positions.csv", "metadata.csv", "test_benchmark.csv")
"""Names (ends or parts) of the files :func:`helicalib.realdata.paint.scan` reads."""


def check_files(dirs) -> None:
    """Every PAINT file under ``dirs`` is UTF-8 and valid JSON (an object) or CSV; else a ConfigError
    naming the file, line and column (the reader itself would stop with a traceback)."""
    from helicalib.config import read_csv_rows, read_text
    from helicalib.errors import ConfigError
    from helicalib.realdata.paint import _int

    for d in map(Path, dirs):
        files = [d] if d.is_file() else sorted(p for p in d.rglob("*") if p.is_file()) if d.is_dir() else []
        for p in files:
            if not any(key in p.name for key in _READ):
                continue
            if p.suffix == ".csv":
                read_csv_rows(p)
            elif p.suffix == ".json":
                try:
                    data = json.loads(read_text(p), parse_int=_int)
                except json.JSONDecodeError as exc:
                    raise ConfigError(f"{p}: line {exc.lineno}, column {exc.colno}: not valid JSON ({exc.msg})") from None
                if not isinstance(data, dict):
                    raise ConfigError(f"{p}: (top level): expected a JSON object, got {type(data).__name__}")


def _culprit(exc: BaseException) -> str | None:
    """The PAINT file the reader was on when ``exc`` was raised (its frames' ``path``/``p``), if any."""
    found = None
    tb = exc.__traceback__
    while tb is not None:
        frame = tb.tb_frame
        if frame.f_globals.get("__name__") == "helicalib.realdata.paint":
            for name in ("path", "p", "axis_csv"):
                if isinstance(frame.f_locals.get(name), (str, Path)):
                    found = str(frame.f_locals[name])
                    break
        tb = tb.tb_next
    return found


def run(args) -> int:
    from helicalib.calibration.observations import write_observations
    from helicalib.config import clear_standby_points, parse_field_config, write_field_config
    from helicalib.errors import ConfigError
    from helicalib.outdir import prepare
    from helicalib.realdata.paint import field_config_dict, observations, scan

    check_files(args.dirs)
    try:
        imp = scan(args.dirs)
        data = field_config_dict(imp)
        rows, notes = observations(imp, args.spot)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        # the PAINT reader does not check the records' structure; name the file it was reading
        what = f"missing key {exc}" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
        where = _culprit(exc) or ", ".join(str(d) for d in args.dirs)
        raise ConfigError(f"{where}: not the PAINT layout helicalib reads ({what})") from None
    data = clear_standby_points(data)
    try:
        parse_field_config(data)  # before anything is written: field.yaml is always valid
    except ConfigError as exc:
        sources = ", ".join(str(d) for d in args.dirs)
        problems = [f"{sources}: the imported field would not be valid: {p}" for p in exc.problems]
        raise ConfigError("\n".join(problems), problems=problems) from None
    out = prepare(args.out, "import-paint", replace=True,  # only an empty folder or a previous import is replaced
                  inputs=args.dirs)
    cfg = write_field_config(data, out / "field.yaml")
    comments = [f"helicalib import-paint from {', '.join(str(d) for d in args.dirs)}",
                f"spot centre: {args.spot}; plant reference WGS84 {list(imp.tower.reference_llh)}",
                "PAINT data: CDLA-Permissive-2.0 (DLR / KIT)"]
    write_observations(out / "observations.csv", rows, comments)
    summary = {
        "field": str(out / "field.yaml"),
        "observations": str(out / "observations.csv"),
        "heliostats": {h.id: {"position_enu_m": [round(x, 3) for x in h.position_enu_m],
                              "records": sum(r.heliostat_id == h.id for r in rows)} for h in cfg.heliostats},
        "targets": [t.id for t in cfg.targets],
        "records": len(rows),
        # records, heliostats and boards left out for a value no plant can have (each named in "bad")
        "skipped": {kind: len(lines) for kind, lines in imp.bad.items()},
        "bad": [line for lines in imp.bad.values() for line in lines],
        "notes": imp.notes + notes,
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {summary['field']} ({len(cfg.heliostats)} heliostats, {len(cfg.targets)} targets) and "
              f"{summary['observations']} ({len(rows)} records)")
        for hid, h in summary["heliostats"].items():
            print(f"  {hid}: ENU {h['position_enu_m']} m, {h['records']} records")
        skipped = summary["skipped"]
        if any(skipped.values()):
            print(f"skipped for impossible values: {_count(skipped['records'], 'record')}, "
                  f"{_count(skipped['heliostats'], 'heliostat')}, {_count(skipped['targets'], 'target')}")
        for line in summary["bad"]:
            print(f"  skipped: {line}")
        for n in summary["notes"]:
            print(f"  note: {n}")
    return 0


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"
