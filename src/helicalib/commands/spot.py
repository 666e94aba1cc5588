"""``helicalib spot``: the spot centre on a target board from a before frame and after frames.

    helicalib spot BEFORE.png AFTER.png [AFTER ...] --target TARGET.yaml [--method grlm-centroid] [--json]
    helicalib spot BEFORE.png AFTER.png --field FIELD.yaml --target-id T1 [--camera-id C1] [--overlay OUT.png]
    helicalib spot FRAME --single-frame --board-size-m W H [--json]      (one rectified board frame, no BEFORE)

Exit status: 0 valid measurement, 3 measured but invalid (the reason is printed), 1 user error.

Single-frame mode (``--single-frame``, ``--board-size-m``) is :mod:`helicalib.commands.spot_single`'s.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from helicalib.commands import spot_single
from helicalib.commands._args import fraction, positive_float

EXIT_INVALID = 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("spot", help="spot centre on a target board (T/GRLM annex A) from before/after frames",
                       description="Measure the heliostat spot centre on a target board from a 'before' frame "
                                   "(no beam) and one or more 'after' frames (beam on), per T/GRLM 02-2014 annex A, "
                                   "on a metric grid of the board. Exit 0 valid, 3 invalid measurement, 1 error.")
    p.add_argument("frames", nargs="+", metavar="FRAME", help="BEFORE then AFTER [AFTER ...] (PNG or JPEG)")
    p.add_argument("--target", type=Path, help="YAML file with one target entry (as under 'targets:')")
    p.add_argument("--field", type=Path, help="field config YAML (use with --target-id)")
    p.add_argument("--target-id", help="target id in --field")
    p.add_argument("--camera-id", help="camera in --field for its intrinsics/distortion (default: the target's)")
    p.add_argument("--method", choices=["grlm", "grlm-centroid", "centroid"], default=None,
                   help="centring method (default: calibration.spot_method of --field, else grlm-centroid)")
    p.add_argument("--cells-per-m", type=positive_float, default=None, help="board grid resolution [cells/m] (default: auto)")
    p.add_argument("--max-jitter-m", type=positive_float, default=None, help="jitter limit over after frames [m] (default 0.10)")
    p.add_argument("--max-saturated", type=fraction, default=None,
                   help="largest saturated fraction of the spot (default 0.10)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--overlay", type=Path, help="write the after frame with marks, board, window and centre drawn")
    spot_single.add_arguments(p)
    p.set_defaults(func=run)


def load_target_file(path: Path, need_marks: bool = True):
    """A Target from a YAML file holding one target entry (bare, in a one-item list, or under ``targets:``)."""
    from pydantic import ValidationError

    from helicalib.config import Target, read_yaml, validation_error
    from helicalib.errors import ConfigError

    data = read_yaml(path)
    prefix = ""
    if isinstance(data, dict) and "targets" in data:
        data, prefix = data["targets"], "targets"
    if isinstance(data, list):
        if len(data) != 1:
            raise ConfigError(f"{path}: {prefix or '(top level)'}: expected exactly one target entry, got {len(data)}")
        data, prefix = data[0], f"{prefix}[0]"
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a target entry (id, center_enu_m, normal_enu, size_m, marks)")
    try:
        target = Target.model_validate(data)
    except ValidationError as exc:
        raise validation_error(exc, path, prefix=prefix) from None
    if need_marks and target.marks is None:
        raise ConfigError(f"{path}: {prefix + '.' if prefix else ''}marks: the target needs its marks to be measured")
    return target


def resolve_target(args, need_marks: bool = True):
    """(target, camera, default_method) from ``--target`` or ``--field/--target-id``.

    ``need_marks=False`` (single-frame mode) accepts boards without marks (e.g. imported ones)."""
    from helicalib.errors import ConfigError

    if (args.target is None) == (args.field is None):
        raise ConfigError("give either --target TARGET.yaml or --field FIELD.yaml --target-id ID")
    if args.target is not None:
        return load_target_file(args.target, need_marks), None, "grlm-centroid"
    from helicalib.config import load_field_config

    field = load_field_config(args.field)
    if not args.target_id:
        ids = ", ".join(t.id for t in field.targets)
        raise ConfigError(f"--field needs --target-id (one of {ids})")
    target = field.target(args.target_id)
    if need_marks and target.marks is None:
        raise ConfigError(f"{args.field}: target {target.id} has no marks")
    cams = field.cameras_for(target.id)
    camera = None
    if args.camera_id:
        matches = [c for c in field.cameras if c.id == args.camera_id]
        if not matches:
            raise ConfigError(f"{args.field}: cameras: no camera '{args.camera_id}'")
        camera = matches[0]
    elif cams:
        camera = cams[0]
    return target, camera, field.calibration.spot_method


def read_frames(paths):
    """Frames as uint8 arrays, or a ``bad_frame`` SpotResult naming the unusable file."""
    from helicalib.errors import MeasurementError
    from helicalib.vision.frames import read_frame
    from helicalib.vision.spot import SpotResult

    frames = []
    for p in paths:
        try:
            frames.append(read_frame(p))
        except MeasurementError as exc:
            return None, SpotResult(False, "bad_frame", f"{exc}.")
    return frames, None


def print_result(result, args, extra: dict | None = None) -> int:
    """Print the result (JSON or text); returns the exit status."""
    out = result.to_json()
    if extra:
        out.update(extra)
    if args.json:
        print(json.dumps(out))
    else:
        state = "valid" if result.valid else f"INVALID ({result.reason})"
        print(f"spot: {state}: {result.message}")
        if result.offset_m is not None:
            print(f"  offset (u, v)      {result.offset_m[0]:+.4f} m, {result.offset_m[1]:+.4f} m")
            print(f"  spot centre        ({result.spot_center_px[0]:.2f}, {result.spot_center_px[1]:.2f}) px")
        if result.target_center_px is not None:
            print(f"  target centre      ({result.target_center_px[0]:.2f}, {result.target_center_px[1]:.2f}) px")
        if result.spot_area_px is not None:
            print(f"  area S             {result.spot_area_px:.0f} cells ({out['spot_area_m2']} m²), threshold "
                  f"{result.threshold:.1f}")
        if result.jitter_m is not None:
            print(f"  jitter             {result.jitter_m * 1000:.1f} mm RMS")
    return 0 if result.valid else EXIT_INVALID


def run(args) -> int:
    from helicalib.errors import ConfigError
    from helicalib.vision.spot import SpotLimits, measure_spot

    if spot_single.wants(args):
        # single-frame mode: a rectified frame of the board; a target (--target or --field/--target-id) is
        # optional (it may supply the board size) and needs no marks
        target = camera = None
        if args.target is not None or args.field is not None:
            target, camera, _ = resolve_target(args, need_marks=False)
        return int(spot_single.run_spot(args, target, camera))
    target, camera, default_method = resolve_target(args)
    if len(args.frames) < 2:
        raise ConfigError("give a BEFORE frame and at least one AFTER frame")
    method = args.method or default_method
    frames, bad = read_frames(args.frames)
    if bad is not None:
        bad = type(bad)(**{**bad.__dict__, "method": method})
        return print_result(bad, args)
    limits = SpotLimits(**{k: v for k, v in (("max_jitter_m", args.max_jitter_m),
                                             ("max_saturated_fraction", args.max_saturated)) if v is not None})
    result = measure_spot(frames[0], frames[1:], target, camera, method=method, limits=limits,
                          cells_per_m=args.cells_per_m)
    extra = {"target": target.id, "before": str(args.frames[0]), "afters": [str(p) for p in args.frames[1:]]}
    if args.overlay is not None:
        from helicalib.vision.overlay import draw_overlay
        from helicalib.vision.frames import write_png

        write_png(args.overlay, draw_overlay(frames[1], result, target))
        extra["overlay"] = str(args.overlay)
    return print_result(result, args, extra)
