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
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--spot", choices=["UTIS", "HeliOS"], default="UTIS",
                   help="which of the record's spot centres is the observation (default UTIS)")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=run)


def run(args) -> int:
    from helicalib.calibration.observations import write_observations
    from helicalib.config import write_field_config
    from helicalib.realdata.paint import field_config_dict, observations, scan

    imp = scan(args.dirs)
    out = Path(args.out)
    cfg = write_field_config(field_config_dict(imp), out / "field.yaml")
    rows, notes = observations(imp, args.spot)
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
        "notes": imp.notes + notes,
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {summary['field']} ({len(cfg.heliostats)} heliostats, {len(cfg.targets)} targets) and "
              f"{summary['observations']} ({len(rows)} records)")
        for hid, h in summary["heliostats"].items():
            print(f"  {hid}: ENU {h['position_enu_m']} m, {h['records']} records")
        for n in summary["notes"]:
            print(f"  note: {n}")
    return 0
