"""``helicalib report DB --out DIR``: the campaign's HTML report, its plots and report.json."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_database, campaign_id


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="write a campaign's HTML report, plots and report.json",
                       description="A self-contained HTML report of one campaign (the newest by default): field "
                                   "map, progress, pass rates (paper figs. 6-8), T/GRLM figure 3 and clause 8.2, and "
                                   "one sheet per heliostat; report.json holds the same figures. See docs/report.md.")
    add_database(p)
    p.add_argument("--out", required=True, help="output folder (index.html, report.json, plots, heliostats/): new, "
                   "empty or a previous report (replaced); any other folder is refused")
    p.add_argument("--campaign", type=campaign_id, default=None, help="campaign id (default: the newest)")
    p.add_argument("--field", default=None, help="field config to use instead of the one the campaign recorded")
    p.add_argument("--images", default=None, help="frames directory (default: images beside the database)")
    p.add_argument("--no-frames", action="store_true", help="do not draw each heliostat's latest frames (faster)")
    p.add_argument("--plots", choices=("auto", "all", "attention"), default="auto",
                   help="which heliostat sheets get the full drawn plots: all, only those needing attention (not "
                        "accepted, no verdict; the others show a small inline chart), or auto (all on fields of at "
                        "most 500 heliostats)")
    p.add_argument("--predictions", action="store_true", help="compute the year-round prediction on any field (by "
                   "default only on fields of at most 500 heliostats: it fits every heliostat again)")
    p.add_argument("--jobs", type=int, default=None, help="processes drawing the heliostat sheets (default: CPUs, max 4)")
    p.add_argument("--timezone", default=None, help="the site's clock shown beside UTC: an IANA zone (Asia/Shanghai) or "
                   "an offset (+08:00); default: local mean solar time from the site's longitude")
    p.add_argument("--json", action="store_true", help="print report.json's summary and status on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    import time

    from helicalib.outdir import prepare
    from helicalib.report.build import build_report

    t0 = time.perf_counter()
    db = _check_inputs(args)                              # before the folder is touched
    out = prepare(args.out, "report", replace=True,       # only an empty folder or a previous report is replaced
                  inputs=(db, args.field, args.images))
    from helicalib.commands._progress import ProgressReporter

    with ProgressReporter("report", None, transient=args.json) as bar:
        index = build_report(db, out, args.campaign, field_config=args.field, images_dir=args.images,
                             frames=not args.no_frames, jobs=args.jobs, timezone=args.timezone, plots=args.plots,
                             predictions=True if args.predictions else None,
                             progress=lambda done, total, what: bar.update(done, f"{done} of {total} {what}", total))
    rep = json.loads((index.parent / "report.json").read_text())
    if args.json:
        print(json.dumps({"index": str(index), "status": rep["status"], "summary": rep["summary"],
                          "tracking_test": rep["tracking_test"]["field"]["verdict"]}, indent=2, ensure_ascii=False))
        return 0
    s = rep["summary"]
    print(f"{index}  ({s['heliostats']} heliostats, {s['accepted']} accepted, {s['visits']} visits; "
          f"built in {time.perf_counter() - t0:.1f} s)")
    st = rep["status"]
    for m in st.get("actions", st["messages"]):
        print(f"  ! {m}")
    for m in st.get("information", []):
        print(f"  - {m}")
    return 0


def _check_inputs(args):
    """The database file, the campaign asked for and the field config given: refused in one line
    before anything is written. Returns the database's path."""
    from pathlib import Path

    from helicalib.errors import ConfigError
    from helicalib.store.sqlite import Store, existing_database

    db = existing_database(args.db)
    if args.field is not None and not Path(args.field).is_file():
        raise ConfigError(f"--field {args.field}: file not found")
    if args.campaign is not None:
        store = Store.open(db, args.images, readonly=True)
        try:
            store.campaign(args.campaign)
        finally:
            store.close()
    return db
