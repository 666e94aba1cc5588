"""``helicalib export-paint DB --out DIR``: a campaign's calibration records in PAINT's layout (for ARTIST
and the PAINT tools), with a STAC catalogue; ``helicalib import-paint DIR`` reads them back."""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from helicalib.commands._args import add_database, campaign_id, positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export-paint", help="write a campaign's calibration records in PAINT's layout",
                       description="Write the valid observations of a campaign database in PAINT's layout: "
                                   "tower-measurements.json, per heliostat Properties/<id>-heliostat-properties.json "
                                   "(linkage) and Calibration/<record>-calibration-properties.json (motor positions, "
                                   "target, spot centre, sun azimuth/elevation in PAINT's convention) with the "
                                   "record's frames, and a STAC catalogue (catalog.json, relative links). "
                                   "helicalib import-paint reads the export back.")
    add_database(p)
    p.add_argument("--out", required=True, help="output folder: new, empty or a previous export (replaced); any "
                   "other folder is refused")
    p.add_argument("--field", help="field config YAML (default: the one the campaign was started with)")
    p.add_argument("--campaign", type=campaign_id, help="campaign id (default: the newest in the database)")
    p.add_argument("--increment", type=positive_float, metavar="STEPS_PER_M",
                   help="motor steps per metre of actuator length (default 1000: one step = one mm of stroke, "
                        "the field config's unit; docs/realdata.md)")
    p.add_argument("--images", metavar="DIR", help="the database's frames directory (default: images beside it)")
    p.add_argument("--no-frames", action="store_true", help="do not copy the frames")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=run)


def campaign_rows(store, campaign_id: int, spot_method: str):
    """The campaign's valid observations as fit rows (:meth:`Store.export_fit_csv`'s selection and columns)
    and their frame files by record id, all in memory (the export itself streams: :func:`heliostat_batches`)."""
    from helicalib.calibration.observations import read_observations

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "observations.csv"
        store.export_fit_csv(path, campaign_id=campaign_id, spot_method=spot_method)
        rows = read_observations(path)
    frames = frame_files(store, store.observations(campaign_id=campaign_id, valid=True))
    return rows, frames


def frame_files(store, observations) -> dict:
    """Record id → :class:`~helicalib.realdata.paint_export.Frames` of ``observations``: only a file inside
    the database's images folder is copied out (a frame path is the database's word)."""
    from helicalib.realdata.paint_export import Frames

    images = store.images_dir.resolve()

    def inside(rel: str | None) -> Path | None:
        if not rel:
            return None
        path = (images / rel).resolve()
        return path if path.is_relative_to(images) and path.is_file() else None

    return {str(o.id): Frames(inside(o.after_frame_path), inside(o.before_frame_path)) for o in observations}


def heliostat_batches(store, campaign_id: int, spot_method: str, chunk: int = 5000):
    """(heliostat id, fit rows, frames by record id) heliostat by heliostat in id order, read in chunks of
    ``chunk`` rows (:mod:`helicalib.store.stream`): the same rows as :func:`campaign_rows`, never all at once."""
    from helicalib.store.stream import fit_row, iter_heliostat_observations

    for hid, observations in iter_heliostat_observations(store, campaign_id, chunk=chunk, valid=True):
        pairs = [(o, row) for o in observations if (row := fit_row(o, spot_method)) is not None]
        if pairs:
            yield hid, [row for _o, row in pairs], frame_files(store, [o for o, _row in pairs])


def run(args) -> int:
    from helicalib.commands._progress import ProgressReporter
    from helicalib.config import load_field_config
    from helicalib.errors import ConfigError
    from helicalib.outdir import prepare
    from helicalib.realdata.paint_export import DEFAULT_INCREMENT_STEPS_PER_M, PaintWriter
    from helicalib.store.sqlite import Store, existing_database

    db = existing_database(args.db)
    store = Store.open(db, args.images, readonly=True)
    try:
        campaigns = store.campaigns()
        if not campaigns:
            raise ConfigError(f"{args.db}: no campaign in this database")
        campaign = store.campaign(args.campaign) if args.campaign is not None else campaigns[-1]
        field = args.field or campaign.config_path
        if not field:
            raise ConfigError(f"{args.db}: campaign {campaign.id} records no field config; give --field")
        if not Path(field).is_file():
            raise ConfigError(f"{field}: field config of campaign {campaign.id} not found; give --field")
        cfg = load_field_config(field)
        total = store.count_observations(campaign_id=campaign.id, valid=True)
        if not total:
            raise ConfigError(f"{args.db}: campaign {campaign.id} has no valid observation to export")
        out = prepare(args.out, "export-paint", replace=True,   # only an empty folder or a previous export is replaced
                      inputs=(db, field, args.images))
        writer = PaintWriter(cfg, out, increment_steps_per_m=args.increment or DEFAULT_INCREMENT_STEPS_PER_M,
                             description=f"helicalib campaign {campaign.id} ({campaign.name}) of {args.db}")
        done = 0
        with ProgressReporter("export-paint", total, transient=args.json) as bar:
            for hid, rows, frames in heliostat_batches(store, campaign.id, cfg.calibration.spot_method):
                writer.write_heliostat(hid, rows, None if args.no_frames else frames)
                done += len(rows)
                bar.update(done, f"{done} of {total} valid observations, {len(writer.counts)} heliostats")
    finally:
        store.close()
    if not writer.records:
        raise ConfigError(f"{args.db}: campaign {campaign.id} has no located valid observation to export")
    summary = writer.finish()
    summary.update({"database": str(args.db), "campaign": campaign.id, "field": str(field)})
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {summary['records']} records of {len(summary['heliostats'])} heliostats "
              f"({summary['frames']} with frames) to {summary['out']}; catalogue {summary['catalog']}")
        if len(summary["heliostats"]) <= 50:
            for hid, n in summary["heliostats"].items():
                print(f"  {hid}: {n} records")
    return 0
