"""``helicalib spot-single FRAME --board-size-m W H [--json]``: an alias of
``helicalib spot FRAME --single-frame --board-size-m W H [--json]`` (same code, same output)."""

from __future__ import annotations

import argparse

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
    from helicalib.vision.single_frame import run_spot

    ns = argparse.Namespace(frames=[args.frame], single_frame=True, board_size_m=args.board_size_m, json=args.json)
    return run_spot(ns)
