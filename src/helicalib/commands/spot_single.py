"""``helicalib spot-single FRAME --board-size-m W H [--json]``: spot centre from one rectified board frame."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("spot-single", help="spot centre from a single rectified board frame (no 'before' frame)",
                       description="FRAME is a rectified image of the board spanning exactly W x H metres (image "
                                   "right = target u, image up = target v). Prints the spot centre in target metres "
                                   "about the board centre, and in pixels.")
    p.add_argument("frame", help="image file (grey or colour)")
    p.add_argument("--board-size-m", nargs=2, type=float, required=True, metavar=("W", "H"))
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    import cv2

    from helicalib.errors import MeasurementError
    from helicalib.vision.single_frame import spot_centre_single_frame

    img = cv2.imread(args.frame, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise MeasurementError(f"{args.frame}: cannot read the image")
    w, h = args.board_size_m
    if w <= 0 or h <= 0:
        raise MeasurementError("--board-size-m: W and H must be positive")
    res = spot_centre_single_frame(img, (w, h))
    if args.json:
        print(json.dumps({"frame": args.frame, "board_size_m": [w, h], **res.as_dict()}, indent=2))
    else:
        u, v = res.centre_uv_m
        print(f"{args.frame}: spot centre u = {u:+.3f} m, v = {v:+.3f} m (pixel x {res.centre_px[0]:.1f}, "
              f"y {res.centre_px[1]:.1f}); {res.regions} candidate region(s), score ratio {res.score_ratio:.1f}")
    return 0
