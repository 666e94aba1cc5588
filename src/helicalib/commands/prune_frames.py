"""``helicalib prune-frames DB --keep-last N``: bounded disk for a long-running database."""

from __future__ import annotations

import argparse
import json

from helicalib.commands._args import add_database, campaign_id, nonnegative_int


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("prune-frames", help="delete old frames, keep every observation",
                       description="Keep the frames of each heliostat's newest N observations and of every "
                                   "rejected one; delete the other frame files and clear their paths in the "
                                   "database (every observation row stays). Takes the database's owner lock: "
                                   "refused while a campaign runs on it. See docs/campaign.md (Storage).")
    add_database(p)
    p.add_argument("--keep-last", type=nonnegative_int, required=True, metavar="N",
                   help="observations with frames kept per heliostat, newest first")
    p.add_argument("--drop-rejected", action="store_true",
                   help="also delete the frames of rejected (not valid) observations beyond the newest N "
                        "(default: they are all kept)")
    p.add_argument("--campaign", type=campaign_id, default=None, help="only this campaign (default every campaign)")
    p.add_argument("--images", default=None, help="frames directory (default: images beside the database)")
    p.add_argument("--dry-run", action="store_true", help="count what would be deleted; change nothing")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from helicalib.commands._progress import ProgressReporter
    from helicalib.store.retention import retain_frames
    from helicalib.store.sqlite import Store, existing_database

    path = existing_database(args.db)
    if args.dry_run:
        store = Store.open(path, args.images, readonly=True)
    else:
        store = Store.open(path, args.images, owner="prune-frames")
    bars: list = []  # progress on stderr once thousands of files go (a plant's first pruning: minutes)

    def progress(done: int, total: int) -> None:
        if not bars:
            bars.append(ProgressReporter("prune-frames", total, transient=args.json).__enter__())
        bars[0].update(done, f"{done} of {total} frame files deleted")

    try:
        result = retain_frames(store, args.keep_last, keep_invalid=not args.drop_rejected,
                               campaign_id=args.campaign, dry_run=args.dry_run, progress=progress)
    finally:
        store.close()
        for bar in bars:
            bar.close()
    if args.json:
        print(json.dumps({"dry_run": args.dry_run, "keep_last": args.keep_last, **result.as_dict()}))
    else:
        verb = "would delete" if args.dry_run else "deleted"
        print(f"{verb} {result.files} frame files ({result.bytes / 1e6:.1f} MB) of {result.observations} "
              f"observations; {result.kept_files} frame files kept")
    return 0
