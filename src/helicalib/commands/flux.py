"""``helicalib flux BEFORE AFTER``: flux density map of a heliostat's spot, and its cleanliness.

Finds the board marks in the before frame, corrects both frames as FLUX.yaml says (Zhang & Wang),
and prints peak flux, power on the board and the flux-weighted centre; ``--plot`` writes the 3-D
surface and colour map, ``--json`` one JSON object. With ``--field``, ``--heliostat``, ``--time``
and ``--dni-wm2`` it also estimates the mirror's cleanliness (``cleanliness:`` in FLUX.yaml).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from helicalib.commands._args import float_in, iso_time, positive_float


MAX_GRID_CELLS = 25e6
"""Most cells the flux map's board grid may have (a 5000 x 5000 grid takes 200 MB per float map)."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("flux", help="flux density map, power and cleanliness from a before/after frame pair",
                       description="Flux density map of a heliostat's spot on a target board (Zhang & Wang): "
                                   "camera corrections, E = Fe*G on a metric board grid, peak, power, centre.")
    p.add_argument("before", help="frame without the beam (PNG/JPEG)")
    p.add_argument("after", help="frame with the beam")
    p.add_argument("--target", help="TARGET.yaml holding one entry of 'targets:' (and optionally one of 'cameras:'), "
                                    "or with --field the target id")
    p.add_argument("--field", help="field config YAML (then --target-id, or --target, names the target)")
    p.add_argument("--target-id", help="target id in --field")
    p.add_argument("--camera-id", help="camera in --field (default: FLUX.yaml 'camera', else the target's only camera)")
    p.add_argument("--calibration", required=True, help="FLUX.yaml: Fe, correction files, component errors")
    p.add_argument("--heliostat", help="heliostat id in --field: incidence angle and cleanliness geometry")
    p.add_argument("--incidence-deg", type=float_in(0.0, 90.0, open_hi=True), help="beam incidence on the board [deg] (else from --heliostat)")
    p.add_argument("--time", type=iso_time, help="capture instant, ISO 8601 with offset (cleanliness: sun position)")
    p.add_argument("--dni-wm2", type=positive_float, help="DNI at the capture time [W/m²] (cleanliness)")
    p.add_argument("--intercept", type=float_in(0.0, 1.0, open_lo=True), default=1.0, help="fraction of the beam on the board (default 1)")
    p.add_argument("--exposure-ms", type=positive_float, default=None,
                   help="the frames' exposure [ms] (an observation's exposure_ms): Fe is scaled from the "
                        "FLUX.yaml's exposure_ms to it (default: the frames were taken at FLUX.yaml's exposure)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", help="write the 3-D surface and colour map to this PNG")
    p.set_defaults(func=run)


def _load_target_file(path: str):
    """TARGET.yaml → (Target, Camera | None); errors name the file and key path."""
    from pydantic import ValidationError

    from helicalib.config import Camera, Target, read_yaml, validation_error
    from helicalib.errors import ConfigError

    p = Path(path)
    data = read_yaml(p)
    if not isinstance(data, dict) or not isinstance(data.get("targets"), list) or len(data["targets"]) != 1:
        raise ConfigError(f"{p}: targets: expected a list holding exactly one target")
    extra = set(data) - {"targets", "cameras"}
    if extra:
        raise ConfigError(f"{p}: {sorted(extra)[0]}: unknown key (a TARGET.yaml holds 'targets' and optionally 'cameras')")
    cams = data.get("cameras") or []
    if not isinstance(cams, list) or len(cams) > 1:
        raise ConfigError(f"{p}: cameras: expected a list of at most one camera")
    def validated(model, value, section):
        try:
            return model.model_validate(value)
        except ValidationError as exc:
            raise validation_error(exc, p, prefix=section) from None

    target = validated(Target, data["targets"][0], "targets[0]")
    camera = validated(Camera, cams[0], "cameras[0]") if cams else None
    return target, camera


def _resolve(args):
    """(target, camera, field config or None) from the command line."""
    from helicalib.config import load_field_config
    from helicalib.errors import ConfigError

    if args.field:
        cfg = load_field_config(args.field)
        tid = args.target_id or args.target
        if not tid:
            raise ConfigError("--field needs --target-id (the board's id in the field config)")
        target = cfg.target(tid)
        cams = cfg.cameras_for(target.id)
        return target, cams, cfg
    if not args.target:
        raise ConfigError("give --target TARGET.yaml, or --field FIELD.yaml --target-id ID")
    target, camera = _load_target_file(args.target)
    return target, (() if camera is None else (camera,)), None


def _pick_camera(cams, wanted):
    from helicalib.errors import ConfigError

    if wanted:
        for c in cams:
            if c.id == wanted:
                return c
        raise ConfigError(f"camera '{wanted}' does not watch this target (cameras: {', '.join(c.id for c in cams) or 'none'})")
    return cams[0] if len(cams) == 1 else None


def _read(path: str) -> np.ndarray:
    from helicalib.vision.frames import read_frame

    return read_frame(path)


def run(args) -> int:
    from helicalib.errors import ConfigError, MeasurementError
    from helicalib.flux.calibration import system_error
    from helicalib.flux.config import load_correction_data, load_flux_calibration
    from helicalib.flux.corrections import incidence_angle_deg, view_angles_deg
    from helicalib.flux.grid import board_grid
    from helicalib.flux.measure import auto_cell_m, measure_flux
    from helicalib.flux.visit import MAX_EDGE_FRACTION
    from helicalib.vision.marks import find_marks

    fc = load_flux_calibration(args.calibration)
    if args.exposure_ms is not None and fc.exposure_ms is None:
        raise ConfigError(f"--exposure-ms {args.exposure_ms:g}: {args.calibration} has no exposure_ms (the exposure "
                          "at which its Fe holds), so Fe cannot be scaled to the frames' exposure")
    exposure_scale = 1.0 if args.exposure_ms is None else fc.exposure_ms / args.exposure_ms
    target, cams, cfg = _resolve(args)
    camera = _pick_camera(cams, args.camera_id or fc.camera)
    data = load_correction_data(fc)
    before, after = _read(args.before), _read(args.after)
    if before.shape != after.shape:
        raise MeasurementError(f"{args.after}: frame is {after.shape[1]}x{after.shape[0]} px, "
                               f"{args.before} is {before.shape[1]}x{before.shape[0]} px")
    marks = find_marks(before, target, camera)
    if not marks.found:
        raise MeasurementError(f"{args.before}: board marks not found ({marks.reason})")
    cam_k = camera.camera_matrix if camera is not None else None
    dist = np.asarray(camera.distortion) if (camera is not None and camera.distortion is not None) else None
    if fc.corrections.distortion and (cam_k is None or dist is None):
        raise ConfigError(f"{fc.source}: corrections.distortion: the camera has no intrinsics/distortion in the config")
    cell = fc.grid_cell_m or auto_cell_m(marks.homography, before.shape)
    cells = target.size_m[0] * target.size_m[1] / cell**2 if cell > 0 else float("inf")
    if not cells <= MAX_GRID_CELLS:
        key = f"{fc.source}: grid_cell_m: {cell:g} m" if fc.grid_cell_m else f"{args.before}: the automatic grid cell"
        raise ConfigError(f"{key} makes {cells:.3g} cells on the {target.size_m[0]:g} x {target.size_m[1]:g} m board; "
                          f"at most {MAX_GRID_CELLS:.0e} (give a larger grid_cell_m)")
    grid = board_grid(target.size_m, cell)
    heliostat = cfg.heliostat(args.heliostat) if (cfg is not None and args.heliostat) else None
    if args.heliostat and cfg is None:
        raise ConfigError("--heliostat needs --field (the heliostat's position comes from the field config)")
    incidence = args.incidence_deg
    if incidence is None and heliostat is not None:
        incidence = float(incidence_angle_deg(target.normal_enu, target.center_enu_m, heliostat.position_enu_m))
    nl = fc.corrections.non_lambertian
    view = None
    if nl is not None and nl.view_deg is not None and camera is not None and camera.position_enu_m is not None:
        view = view_angles_deg(grid, target.center_enu_m, target.frame_enu, camera.position_enu_m)
    res = measure_flux(
        before, after, marks.homography, grid, fc.fe_wm2_per_grey(cam_k) * exposure_scale,
        dark_grey=data.dark_grey, response=data.response, flat_factors=data.flat_factors,
        camera_matrix=cam_k if fc.corrections.distortion else None,
        distortion=dist if fc.corrections.distortion else None,
        incidence_deg=incidence,
        incidence_table=None if nl is None or nl.incidence_deg is None else (np.array(nl.incidence_deg), np.array(nl.relative)),
        view_deg=view,
        view_table=None if nl is None or nl.view_deg is None else (np.array(nl.view_deg), np.array(nl.view_relative)),
        record=data.record,
    )
    fm = res.fluxmap
    errs = fc.errors.given()
    out = {
        "before": str(args.before), "after": str(args.after), "target": target.id,
        "camera": None if camera is None else camera.id,
        "fe_wm2_per_grey": round(res.fe_wm2_per_grey, 6),
        "fe_method": next(k for k in ("value_wm2_per_grey", "two_radiometer", "sun") if getattr(fc.fe, k) is not None),
        **fm.summary(),
        "saturated_px": res.saturated_px,
        "marks_reprojection_px": round(float(marks.reprojection_px), 4),
        "system_error": round(system_error(errs), 5) if errs else None,
        "component_errors": errs,
        "corrections": res.corrections,
    }
    if args.dni_wm2 is not None or args.time:
        out["cleanliness"] = _cleanliness(args, fc, cfg, target, heliostat, fm)
    if args.plot:
        from helicalib.flux.fluxmap import plot_flux_map

        plot_flux_map(fm, args.plot, title=f"{target.id}: {Path(args.after).name}")
        out["plot"] = str(args.plot)
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{target.id}  Fe {out['fe_wm2_per_grey']:.5g} W/m² per grey ({out['fe_method']}), "
          f"grid {fm.grid.shape[1]}x{fm.grid.shape[0]} cells of {fm.grid.cell_m * 1000:.1f} mm")
    print(f"peak      {fm.peak_wm2 / 1000:.3f} kW/m² at u {fm.peak_uv_m[0]:+.3f} m, v {fm.peak_uv_m[1]:+.3f} m")
    print(f"power     {fm.power_w / 1000:.3f} kW on the board")
    print(f"centre    u {fm.centre_uv_m[0]:+.4f} m, v {fm.centre_uv_m[1]:+.4f} m (flux-weighted)")
    applied = [k for k, v in res.corrections.items() if v.get("applied")]
    print(f"applied   {', '.join(applied)}")
    if out["system_error"] is not None:
        print(f"eps_sys   {100 * out['system_error']:.2f} % from {', '.join(errs)}")
    if res.saturated_px:
        print(f"WARNING   {res.saturated_px} saturated pixels: the peak and power are lower bounds")
    if "cleanliness" in out:
        c = out["cleanliness"]
        print(f"clean     {c['cleanliness']:.3f} (measured {c['power_w'] / 1000:.3f} kW / expected clean "
              f"{c['expected_clean_power_w'] / 1000:.3f} kW)")
        if c["edge_fraction"] is not None and c["edge_fraction"] > MAX_EDGE_FRACTION and args.intercept == 1.0:
            print(f"WARNING   the spot reaches the board edge (edge fraction {c['edge_fraction']:.3f}): power is lost "
                  "off the board, the cleanliness is low unless --intercept says how much")
    if args.plot:
        print(f"plot      {args.plot}")
    return 0


def _cleanliness(args, fc, cfg, target, heliostat, fm) -> dict:
    """The cleanliness estimate as the campaign makes it (``flux.visit``): the beam lands at the map's
    flux-weighted centre, from the mirror centre of the nominal model that sends it there."""
    from helicalib.errors import ConfigError
    from helicalib.flux.cleanliness import atmospheric_attenuation, cos_incidence, estimate_cleanliness, expected_power_w
    from helicalib.flux.visit import edge_fraction
    from helicalib.geometry import optics
    from helicalib.geometry.sun import parse_time, sun_position

    if cfg is None or heliostat is None or args.time is None or args.dni_wm2 is None:
        raise ConfigError("the cleanliness estimate needs --field, --heliostat, --time and --dni-wm2")
    if fc.cleanliness is None:
        raise ConfigError(f"{fc.source}: cleanliness: missing (reflectivity_clean of the mirrors)")
    site = cfg.site
    sun = sun_position(parse_time(args.time), site.latitude_deg, site.longitude_deg, site.altitude_m,
                       site.pressure_hpa_effective, site.temperature_c)
    s = np.asarray(sun.vector_enu, dtype=float)
    centre = np.asarray(fm.centre_uv_m, dtype=float)
    aim = np.asarray(target.uvw_to_enu(centre) if np.all(np.isfinite(centre)) else target.center_enu_m, dtype=float)
    drive = cfg.drive_of(heliostat.id)
    pivot = np.asarray(heliostat.position_enu_m, dtype=float)
    mirror = optics.mirror_centre(pivot, optics.aim_normal(pivot, s, aim, drive.mirror_offset_m), drive.mirror_offset_m)
    cos_i = float(cos_incidence(s, mirror, aim))
    slant = float(np.linalg.norm(aim - mirror))
    tau = float(atmospheric_attenuation(slant, fc.cleanliness.atmosphere))
    area = float(np.prod(drive.mirror_size_m))
    rho = fc.cleanliness.reflectivity_clean
    edge = edge_fraction(fm.flux_wm2, fm.grid.cell_m)
    return {
        "heliostat": heliostat.id, "dni_wm2": args.dni_wm2, "mirror_area_m2": round(area, 4),
        "reflectivity_clean": rho, "aim_enu_m": [round(float(x), 3) for x in aim],
        "cos_incidence": round(cos_i, 6), "slant_range_m": round(slant, 2),
        "attenuation": round(tau, 6), "atmosphere": fc.cleanliness.atmosphere, "intercept": args.intercept,
        "edge_fraction": None if np.isnan(edge) else round(edge, 4),
        "power_w": round(fm.power_w, 2),
        "expected_clean_power_w": round(float(expected_power_w(args.dni_wm2, area, rho, cos_i, tau, args.intercept)), 2),
        "cleanliness": round(float(estimate_cleanliness(fm.power_w, args.dni_wm2, area, rho, cos_i, tau,
                                                        args.intercept)), 5),
    }
