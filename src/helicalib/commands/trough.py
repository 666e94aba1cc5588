"""``helicalib trough``: parabolic-trough facet alignment by the theoretical-overlay photographic method.

Sub-commands: ``overlay`` (theoretical tube edges per facet, overlay PNG, and tilt estimates from
a photo), ``render`` (a ray-traced synthetic photo with chosen facet tilts, to try the method) and
``gauge`` (the centre camera's distance from the boresight gauge, Ren et al. eq. 11).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from helicalib.commands._args import finite_float, int_in, nonnegative_float, nonnegative_int, positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("trough", help="parabolic-trough facet alignment (theoretical overlay photographic method)",
                       description="Where the receiver tube should appear in each facet's reflection, against where it does.")
    tsub = p.add_subparsers(dest="trough_command", metavar="SUBCOMMAND")
    p.set_defaults(func=_dispatch(p), trough_func=None)

    o = tsub.add_parser("overlay", help="theoretical edges (JSON + PNG); with --image, per-facet tilts",
                        description="Theoretical tube edges per facet as JSON and an overlay PNG; given a photo, "
                                    "the detected edges and each facet's tilt about the collector axis [mrad].")
    o.add_argument("--collector", required=True, help="COLLECTOR.yaml")
    o.add_argument("--camera", required=True, help="CAMERA.yaml")
    o.add_argument("--image", help="photo (PNG/JPEG, any colour; converted to grey) taken by that camera")
    o.add_argument("--out", required=True, help="output directory (created)")
    o.add_argument("--json", action="store_true", help="print the result JSON on stdout instead of a table")
    o.set_defaults(trough_func=run_overlay)

    r = tsub.add_parser("render", help="ray-traced synthetic photo with chosen facet tilts",
                        description="Ray-trace the camera's photo of the collector, each facet tilted as given.")
    r.add_argument("--collector", required=True, help="COLLECTOR.yaml")
    r.add_argument("--camera", required=True, help="CAMERA.yaml")
    r.add_argument("--tilt", action="append", default=[], metavar="FACET=MRAD",
                   help="facet tilt about +X, e.g. --tilt R2C3=1.5 (repeatable) [mrad]")
    r.add_argument("--supersample", type=int_in(1, 8), default=3, help="samples per pixel along each axis (default 3)")
    r.add_argument("--noise", type=nonnegative_float, default=0.0, help="Gaussian noise [grey levels] (default 0)")
    r.add_argument("--seed", type=nonnegative_int, default=0, help="noise seed")
    r.add_argument("--out", required=True, help="PNG file to write")
    r.set_defaults(trough_func=run_render)

    g = tsub.add_parser("gauge", help="centre camera distance from the boresight gauge width (eq. 11)",
                        description="'Three points in a line': the distance OPc at which the gauge's colour "
                                    "boundaries and the tube's edges line up, or the gauge width for a distance.")
    g.add_argument("--collector", required=True, help="COLLECTOR.yaml (focal length, tube radius)")
    what = g.add_mutually_exclusive_group(required=True)
    what.add_argument("--gauge-width-mm", type=positive_float, help="d: distance between the gauge's colour boundaries [mm]")
    what.add_argument("--distance-mm", type=positive_float, help="OPc: camera distance from the vertex [mm] (gives d)")
    g.add_argument("--gauge-z-mm", type=finite_float, default=0.0, help="gauge height on the axis [mm] (default 0: vertex)")
    g.set_defaults(trough_func=run_gauge)


def _dispatch(parser: argparse.ArgumentParser):
    def run(args) -> int:
        if args.trough_func is None:
            parser.print_help()
            return 2
        return args.trough_func(args)

    return run


def _parse_tilts(items: list[str]) -> dict[str, float]:
    from helicalib.errors import ConfigError

    out: dict[str, float] = {}
    for item in items:
        fid, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            tilt = float(value)
            if not math.isfinite(tilt):
                raise ValueError
            out[fid.strip().upper()] = tilt
        except ValueError:
            raise ConfigError(f"--tilt {item!r}: expected FACET=MRAD with a finite MRAD, e.g. R2C3=1.5") from None
    return out


def run_render(args) -> int:
    import cv2

    from helicalib.errors import ConfigError
    from helicalib.trough.config import load_camera, load_collector
    from helicalib.trough.render import render_collector

    collector, camera = load_collector(args.collector), load_camera(args.camera)
    if not 1 <= args.supersample <= 8:
        raise ConfigError(f"--supersample {args.supersample}: expected 1..8")
    try:
        img = render_collector(collector, camera.pinhole(), _parse_tilts(args.tilt), supersample=args.supersample,
                               noise_grey=args.noise, seed=args.seed)
    except KeyError as err:
        raise ConfigError(f"--tilt: {err.args[0]}") from None
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), img):
        raise ConfigError(f"--out {out}: cannot write the PNG")
    print(f"wrote {out} ({img.shape[1]}×{img.shape[0]} px)")
    return 0


def run_overlay(args) -> int:
    import cv2

    from helicalib.errors import ConfigError, MeasurementError
    from helicalib.trough.config import load_camera, load_collector
    from helicalib.trough.draw import draw_overlay
    from helicalib.trough.results import analyse, to_json

    collector, camera_cfg = load_collector(args.collector), load_camera(args.camera)
    camera = camera_cfg.pinhole()
    photo = None
    if args.image:
        if not Path(args.image).is_file():
            raise MeasurementError(f"{args.image}: file not found")
        photo = cv2.imread(str(args.image), cv2.IMREAD_GRAYSCALE)
        if photo is None:
            raise MeasurementError(f"{args.image}: not a readable image")
    a = analyse(collector, camera, photo)
    result = to_json(a)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "overlay.json").write_text(json.dumps(result, indent=1) + "\n")
    pic = draw_overlay(a.overlay, camera.image_size_px, photo, a.detection, a.estimate)
    if not cv2.imwrite(str(out / "overlay.png"), pic):
        raise ConfigError(f"--out {out}: cannot write overlay.png")
    if args.json:
        print(json.dumps(result))
        return 0
    shown = [f for f in result["facets"] if f["visible"]]
    print(f"{len(shown)} of {len(result['facets'])} facets show the tube from camera at "
          f"{result['camera_position_mm']} mm; wrote {out / 'overlay.json'} and {out / 'overlay.png'}")
    for f in shown:
        b, e = f["theory"]["B_lower"], f["theory"]["E_upper"]
        line = f"  {f['id']}: B y={b['y_mm']:.1f} mm  E y={e['y_mm']:.1f} mm"
        if "tilt" in f:
            t = f["tilt"]
            tilt = "—" if t["tilt_mrad"] is None else f"{t['tilt_mrad']:+.2f} mrad"
            line += f"  tilt {tilt}  {t['verdict']}"
        print(line)
    return 0


def run_gauge(args) -> int:
    from helicalib.trough.config import load_collector
    from helicalib.trough.paper import boresight_distance_mm, boresight_gauge_width_mm

    c = load_collector(args.collector)
    f, r = c.focal_length_mm, c.tube_radius_mm
    if args.gauge_width_mm is not None:
        d = args.gauge_width_mm
        dist = boresight_distance_mm(d, f, r, args.gauge_z_mm)
        print(f"gauge width d = {d:g} mm  →  centre camera at OPc = {dist:.1f} mm from the vertex")
    else:
        dist = args.distance_mm
        d = boresight_gauge_width_mm(dist, f, r, args.gauge_z_mm)
        print(f"centre camera at OPc = {dist:g} mm  →  gauge width d = {d:.3f} mm")
    step = boresight_distance_mm(d + 0.05, f, r, args.gauge_z_mm) - boresight_distance_mm(d - 0.05, f, r, args.gauge_z_mm)
    print(f"sensitivity: 1 mm more gauge width moves the camera {step / 0.1:+.0f} mm along the axis")
    return 0
