"""Real-data benchmark (issue 5): PAINT import checks, the fit table and the real-spot table.

Usage: ``python benchmarks/bench_realdata.py [REALDATA_DIR]`` (default ``../shared/realdata``).
Prints the tables and writes ``benchmarks/out/bench_realdata.json``.
"""

from __future__ import annotations

import glob
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from helicalib.calibration.observations import read_observations
from helicalib.commands.fit import FitReportOptions, fit_report
from helicalib.config import write_field_config
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.optics import angle_between_rad
from helicalib.realdata import paint
from helicalib.realdata.fitting import REALDATA_PRIOR_SIGMA
from helicalib.calibration.observations import write_observations
from helicalib.vision.single_frame import spot_centre_single_frame

PEERS = {  # normal error [mrad], mean over records (MANIFEST.md / issue 5)
    "AA39": {"nominal": 13.45, "artist_alignment_in_sample": 1.83, "four_tilt_in_sample": 1.79, "four_tilt_loo": 2.68},
    "AA23": {"nominal": 86.0, "four_tilt_in_sample": 1.19, "four_tilt_loo": 1.59},
}


def crop_uv(t: paint.PaintTarget, fraction_xy) -> np.ndarray:
    a, b = fraction_xy
    c = t.corners_enu
    p = (1 - a) * (1 - b) * c["upper_left"] + a * (1 - b) * c["upper_right"] + (1 - a) * b * c["lower_left"] \
        + a * b * c["lower_right"]
    return paint.target_uv(t, p)


def main(root: str) -> dict:
    root = Path(root)
    imp = paint.scan([root / "ARTIST", root / "PAINT"])
    out: dict = {"realdata": str(root)}
    with tempfile.TemporaryDirectory() as tmp:
        cfg = write_field_config(paint.field_config_dict(imp), Path(tmp) / "field.yaml")
        rows, _ = paint.observations(imp, "UTIS")
        write_observations(Path(tmp) / "obs.csv", rows)
        rows = read_observations(Path(tmp) / "obs.csv")

        # -- import checks
        checks = {"heliostats": {h.id: [round(x, 3) for x in h.position_enu_m] for h in cfg.heliostats},
                  "records": {hid: sum(r.heliostat_id == hid for r in rows) for hid in sorted({r.heliostat_id for r in rows})}}
        worst = 0.0
        for rec in imp.records:
            h = imp.heliostats[rec.heliostat_id]
            st = np.array([[float(paint.steps_to_stroke_mm(m, a)) for m, a in zip(rec.motor_steps, h.kinematics.actuators)]])
            _, d = HeliostatModel.from_config(cfg, [h.id]).beam(st, rec.sun_enu)
            _, d_ref = h.kinematics.beam(rec.motor_steps, rec.sun_enu)
            worst = max(worst, 1000 * float(angle_between_rad(d[0], d_ref)))
        checks["nominal_beam_vs_paint_kinematics_max_mrad"] = worst
        out["import"] = checks
        print(f"import: {len(rows)} records; positions {checks['heliostats']}")
        print(f"  our model vs PAINT/ARTIST kinematics, nominal beam: max {worst:.2e} mrad (goal 0.01)")

        # -- fit table
        print("\nfit (normal error, mean mrad; beam error on target, mean m)  fitter: calibration.fit.fit_error_model, "
          "priors: REALDATA_PRIOR_SIGMA")
        print(f"{'heliostat':9s} {'n':>2s} {'nominal':>8s} {'in-sample':>9s} {'LOO':>6s} {'LOO beam m':>10s}   peers")
        fits = {}
        for hid in ("AA39", "AA23", "AA31", "AC43"):
            hr = [r for r in rows if r.heliostat_id == hid]
            loo = len(hr) >= 3
            rep = fit_report(cfg, hr, hid, FitReportOptions(dict(REALDATA_PRIOR_SIGMA), loo=loo))
            fits[hid] = {k: rep.get(k) for k in ("records", "nominal_normal_mrad_mean", "in_sample_normal_mrad_mean",
                                                  "in_sample_beam_m_mean", "loo_normal_mrad_mean", "loo_beam_m_mean")}
            fits[hid]["parameters"] = {k: v["value"] for k, v in rep["parameters"].items()}
            fits[hid]["peers"] = PEERS.get(hid, {})
            loo_s = f"{rep['loo_normal_mrad_mean']:6.2f} {rep['loo_beam_m_mean']:10.3f}" if loo else f"{'-':>6s} {'-':>10s}"
            print(f"{hid:9s} {len(hr):2d} {rep['nominal_normal_mrad_mean']:8.2f} {rep['in_sample_normal_mrad_mean']:9.2f} "
                  f"{loo_s}   {PEERS.get(hid, '')}")
        out["fit"] = fits
        out["priors"] = REALDATA_PRIOR_SIGMA

    # -- real spots
    print("\nsingle-frame spot centre on the AA23 crops (distance in the target plane, m)")
    spots = []
    for f in sorted(glob.glob(str(root / "PAINT/tests/data/test_data/dataset/*/*-cropped.png"))):
        rid = Path(f).name.split("-")[0]
        rec = next(r for r in imp.records if r.record_id == rid)
        t = imp.tower.targets[rec.target_name]
        res = spot_centre_single_frame(cv2.imread(f, cv2.IMREAD_GRAYSCALE), t.size_m)
        uv = crop_uv(t, res.fraction_xy)
        hel = paint.target_uv(t, paint.spot_enu(imp, rec, "HeliOS"))
        uti = paint.target_uv(t, paint.spot_enu(imp, rec, "UTIS"))
        spots.append({"record": rid, "target": rec.target_name, "uv_m": uv.round(4).tolist(),
                      "to_helios_m": float(np.linalg.norm(uv - hel)), "to_utis_m": float(np.linalg.norm(uv - uti)),
                      "utis_to_helios_m": float(np.linalg.norm(uti - hel))})
        s = spots[-1]
        print(f"  {rid:>7s} {rec.target_name:26s} to HeliOS {s['to_helios_m']:.3f}  to UTIS {s['to_utis_m']:.3f}  "
              f"(UTIS-HeliOS {s['utis_to_helios_m']:.3f})")
    d = np.array([[s["to_helios_m"], s["to_utis_m"], s["utis_to_helios_m"]] for s in spots])
    summary = {"to_helios_mean_m": float(d[:, 0].mean()), "to_helios_max_m": float(d[:, 0].max()),
               "to_helios_median_m": float(np.median(d[:, 0])), "to_utis_mean_m": float(d[:, 1].mean()),
               "to_utis_max_m": float(d[:, 1].max()), "utis_to_helios_mean_m": float(d[:, 2].mean()),
               "utis_to_helios_max_m": float(d[:, 2].max()), "goal": "mean <= 0.15, max <= 0.5 m from HeliOS",
               "plain_otsu_peer": "0.68 mean, 3.4 max m from HeliOS"}
    print(f"  to HeliOS: mean {summary['to_helios_mean_m']:.3f} max {summary['to_helios_max_m']:.3f} "
          f"median {summary['to_helios_median_m']:.3f}; to UTIS: mean {summary['to_utis_mean_m']:.3f} "
          f"max {summary['to_utis_max_m']:.3f}; UTIS vs HeliOS: mean {summary['utis_to_helios_mean_m']:.3f} "
          f"max {summary['utis_to_helios_max_m']:.3f}")
    utis_samples = []
    for f in sorted(glob.glob(str(root / "UTIS-HeliostatBeamCharacterization/data/realSamples/*.png"))):
        res = spot_centre_single_frame(cv2.imread(f, cv2.IMREAD_GRAYSCALE), (8.63, 7.22))
        utis_samples.append({"file": Path(f).name, "centre_px": [round(x, 1) for x in res.centre_px],
                             "regions": res.regions, "score_ratio": res.as_dict()["score_ratio"]})
    print(f"  UTIS realSamples (no reference centre): {len(utis_samples)} frames, all centred: "
          f"{[s['centre_px'] for s in utis_samples]}")
    out["spots"] = {"aa23": spots, "summary": summary, "utis_real_samples": utis_samples}
    dest = Path(__file__).parent / "out" / "bench_realdata.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(out, indent=2, default=float))
    print(f"\nwrote {dest}")
    return out


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else str(Path(__file__).resolve().parents[2] / "shared" / "realdata"))
