"""Single-frame spot centres: ``helicalib spot FRAME --single-frame --board-size-m W H [--json]`` and its
alias ``helicalib spot-single FRAME --board-size-m W H [--json]`` (same code, same output).

The frame is a rectified image of the board spanning exactly W x H metres (image right = target u,
image up = target v); the centre is found by :func:`helicalib.vision.single_frame.spot_centre_single_frame`.
``helicalib spot`` adds :func:`add_arguments` to its options and hands a run to :func:`run_spot`
when :func:`wants` says so.
"""

from __future__ import annotations

import argparse
import math

from helicalib.commands._args import positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("spot-single", help="alias of 'spot FRAME --single-frame --board-size-m W H'",
                       description="Alias of 'helicalib spot FRAME --single-frame --board-size-m W H [--json]'. "
                                   "FRAME is a rectified image of the board spanning exactly W x H metres (image "
                                   "right = target u, image up = target v). Prints the spot centre in target metres "
                                   "about the board centre, and in pixels.")
    p.add_argument("frame", help="image file (grey or colour)")
    p.add_argument("--board-size-m", nargs=2, type=positive_float, required=True, metavar=("W", "H"),
                   help="the frame spans exactly W x H metres of board (width, height; both > 0)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    ns = argparse.Namespace(frames=[args.frame], single_frame=True, board_size_m=args.board_size_m, json=args.json)
    return run_spot(ns)


def add_arguments(parser) -> None:
    """Options added to ``helicalib spot``: ``--single-frame`` and ``--board-size-m W H``."""
    parser.add_argument("--single-frame", action="store_true",
                        help="one rectified board frame, no BEFORE frame: background estimated from the frame")
    parser.add_argument("--board-size-m", nargs=2, type=float, metavar=("W", "H"), default=None,
                        help="with --single-frame: the frame spans exactly W x H metres of board")


def wants(args) -> bool:
    """Whether ``helicalib spot``'s arguments ask for single-frame mode."""
    return bool(getattr(args, "single_frame", False))


def run_spot(args, target=None, camera=None) -> int:
    """``helicalib spot FRAME --single-frame --board-size-m W H [--json]``: centre of one rectified frame.

    ``target`` (from ``--target`` or ``--field/--target-id``) supplies the board size when
    ``--board-size-m`` is not given; ``camera`` is not used (the frame is rectified already)."""
    import json

    import cv2

    from helicalib.errors import ConfigError, MeasurementError
    from helicalib.vision.single_frame import spot_centre_single_frame

    if len(args.frames) != 1:
        raise ConfigError("--single-frame takes exactly one FRAME")
    size = args.board_size_m
    if size is None and target is not None:
        size = tuple(target.size_m)
    if size is None or not all(math.isfinite(float(x)) and float(x) > 0 for x in size):
        raise ConfigError(f"--board-size-m {' '.join(str(x) for x in size) if size else ''}: --single-frame needs "
                          "W H (finite, positive, metres) or a target with size_m")
    img = cv2.imread(str(args.frames[0]), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise MeasurementError(f"{args.frames[0]}: cannot read the image")
    res = spot_centre_single_frame(img, (float(size[0]), float(size[1])))
    if getattr(args, "json", False):
        print(json.dumps({"frame": str(args.frames[0]), "method": "single-frame", "board_size_m": list(size),
                          "offset_m": list(res.centre_uv_m), **res.as_dict()}, indent=2))
    else:
        u, v = res.centre_uv_m
        print(f"spot (single frame): offset (u, v) {u:+.4f} m, {v:+.4f} m; centre ({res.centre_px[0]:.2f}, "
              f"{res.centre_px[1]:.2f}) px; {res.regions} candidate region(s)")
    return 0
