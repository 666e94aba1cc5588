"""Accuracy and speed of the trough overlay method on ray-traced photos of the paper's unit.

Prints the figures quoted in docs/trough.md and writes benchmarks/out/bench_trough.json:
tilt recovery error (random tilts, noise), untilted edge offsets, sensitivity [px/mrad], and the
effect of camera-position errors (eq. 11's gauge) on the overlay.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from helicalib.trough.config import Camera, Collector
from helicalib.trough.measure import detect_edges, estimate_tilts
from helicalib.trough.overlay import edges_in_image
from helicalib.trough.paper import boresight_distance_mm, boresight_gauge_width_mm
from helicalib.trough.render import render_collector

PAPER = dict(focal_length_mm=1710.0, aperture_mm=5774.0, length_mm=12000.0, tube_radius_mm=35.0, rows=4, columns=7,
             row_edges_mm=[[1640, 2887], [50, 1612], [-1612, -50], [-2887, -1640]], column_gap_mm=20)
OUT = Path(__file__).resolve().parent / "out" / "bench_trough.json"


def camera(y_mm, size, pitch_um, pos=(0.0, None, 10000.0)):
    return Camera(position_mm=(pos[0], y_mm, pos[2]), image_size_px=size, focal_length_mm=8.0, pixel_pitch_um=pitch_um).pinhole()


def rows_window(ov, h, pad=8):
    v = np.concatenate([ov.strip_top_uv_px[ov.visible, :, 1].ravel(), ov.strip_bottom_uv_px[ov.visible, :, 1].ravel()])
    return max(int(np.nanmin(v)) - pad, 0), min(int(np.nanmax(v)) + pad, h)


def trial(col, cam, row, tilts_by_id, noise, seed, supersample):
    lay = col.facets()
    ov = edges_in_image(col, lay, cam)
    t0 = time.perf_counter()
    img = render_collector(col, cam, tilts_by_id, supersample=supersample, rows_px=rows_window(ov, cam.image_size_px[1]),
                           noise_grey=noise, seed=seed)
    t1 = time.perf_counter()
    det = detect_edges(img, ov, cam)
    est = estimate_tilts(col, ov, cam, det)
    t2 = time.perf_counter()
    errs, offsets = [], []
    for i in np.flatnonzero(ov.visible):
        truth = tilts_by_id.get(lay.ids[i], 0.0)
        errs.append(est.tilt_mrad[i] - truth)
        if truth == 0.0:
            offsets += [det.lower_offset_px[i], det.upper_offset_px[i]]
    return np.array(errs), np.array(offsets), t1 - t0, t2 - t1


def main() -> None:
    col = Collector(**PAPER)
    lay = col.facets()
    rng = np.random.default_rng(7)
    results = {}
    cases = [("paper camera 1600x1200, row R2", 831.0, (1600, 1200), 4.4, 2),
             ("binned 640x480, row R2", 831.0, (640, 480), 11.0, 2),
             ("binned 640x480, row R1 (outer)", 2263.0, (640, 480), 11.0, 1)]
    for name, y_cam, size, pitch, row in cases:
        cam = camera(y_cam, size, pitch)
        ov = edges_in_image(col, lay, cam)
        vis = [lay.ids[i] for i in np.flatnonzero(ov.visible)]
        for noise in (0.0, 3.0):
            errs_all, off_all, t_r, t_m = [], [], [], []
            for k in range(4):
                tilts = {fid: float(rng.uniform(-5, 5)) for fid in vis if rng.random() < 0.6}
                e, o, tr, tm = trial(col, cam, row, tilts, noise, seed=k, supersample=(1, 8))
                errs_all.append(e)
                off_all.append(o)
                t_r.append(tr)
                t_m.append(tm)
            e = np.concatenate(errs_all)
            o = np.concatenate(off_all)
            key = f"{name}, noise {noise:g} grey"
            results[key] = {"facets": int(e.size), "tilt_rms_mrad": float(np.sqrt(np.mean(e**2))),
                            "tilt_max_abs_mrad": float(np.max(np.abs(e))),
                            "untilted_edge_max_abs_px": float(np.max(np.abs(o))) if o.size else None,
                            "render_s": float(np.mean(t_r)), "measure_s": float(np.mean(t_m))}
            print(f"{key}: {e.size} facets, tilt error rms {results[key]['tilt_rms_mrad']:.3f} mrad, "
                  f"max {results[key]['tilt_max_abs_mrad']:.3f} mrad; untilted edges max "
                  f"{results[key]['untilted_edge_max_abs_px']} px; render {np.mean(t_r):.1f} s, measure {np.mean(t_m):.2f} s")
        # sensitivity: image shift of the edges per mrad of tilt (model)
        i = int(np.flatnonzero(ov.visible)[len(vis) // 2])
        ov1 = edges_in_image(col, lay, cam, tilt_mrad=np.where(np.arange(len(lay.ids)) == i, 1.0, 0.0))
        sens = float(np.mean(np.abs(ov1.lower_uv_px[i, :, 1] - ov.lower_uv_px[i, :, 1])))
        results[f"{name}: sensitivity_px_per_mrad"] = sens
        print(f"{name}: edges move {sens:.2f} px per mrad of facet tilt")

    # camera distance from the gauge (eq. 11): error of d -> OPc -> overlay shift -> apparent tilt
    cam = camera(831.0, (1600, 1200), 4.4)
    d = boresight_gauge_width_mm(10000.0, 1710.0, 35.0)
    opc_err = boresight_distance_mm(d + 1.0, 1710.0, 35.0) - 10000.0
    cam_far = camera(831.0, (1600, 1200), 4.4, pos=(0.0, None, 10000.0 + opc_err))
    ov0, ovf = edges_in_image(col, lay, cam), edges_in_image(col, lay, cam_far)
    i = lay.ids.index("R2C4")
    shift = float(ovf.lower_uv_px[i, 0, 1] - ov0.lower_uv_px[i, 0, 1])
    results["gauge"] = {"d_mm_for_10m": d, "opc_error_mm_per_mm_of_d": opc_err, "edge_shift_px_per_mm_of_d": shift}
    print(f"gauge: d = {d:.3f} mm for OPc = 10 m; 1 mm error in d moves the camera {opc_err:+.0f} mm "
          f"and the theoretical B edge {shift:+.2f} px (paper camera)")
    # camera placed 10 mm too high: apparent tilt of every facet in the row
    ov_hi = edges_in_image(col, lay, camera(841.0, (1600, 1200), 4.4))
    shift_y = float(ov_hi.lower_uv_px[i, 0, 1] - ov0.lower_uv_px[i, 0, 1])
    sens = results["paper camera 1600x1200, row R2: sensitivity_px_per_mrad"]
    results["camera_y_offset"] = {"edge_shift_px_per_10_mm": shift_y, "apparent_tilt_mrad_per_10_mm": abs(shift_y) / sens}
    print(f"camera 10 mm too high: theoretical B edge moves {shift_y:+.2f} px = {abs(shift_y) / sens:.2f} mrad apparent tilt")
    # camera pitched by 0.05° about X (attitude error): apparent tilt
    rot = Camera(position_mm=(0.0, 831.0, 10000.0), rotation_deg=(0.05, 0.0, 0.0), image_size_px=(1600, 1200),
                 focal_length_mm=8.0, pixel_pitch_um=4.4).pinhole()
    shift_r = float(edges_in_image(col, lay, rot).lower_uv_px[i, 0, 1] - ov0.lower_uv_px[i, 0, 1])
    results["camera_pitch"] = {"edge_shift_px_per_0.05_deg": shift_r, "apparent_tilt_mrad_per_0.05_deg": abs(shift_r) / sens}
    print(f"camera pitched 0.05°: theoretical B edge moves {shift_r:+.2f} px = {abs(shift_r) / sens:.2f} mrad apparent tilt")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
