"""``helicalib accuracy``: the T/GRLM 02-2014 tracking-accuracy test on a series of measurements.

    helicalib accuracy SERIES.csv --field FIELD.yaml [--json] [--summary OUT.json] [--plot OUT.png]
                                  [--per-frame OUT.csv] [--method grlm-centroid]

SERIES.csv has a header row with ``time``, ``heliostat``, ``wind_ms`` and either ``u_m``, ``v_m``
(spot centre on the heliostat's target board, metres from its centre; ``u``, ``v`` also accepted) or
``before``, ``after`` (frame paths relative to the CSV; several after frames separated by ``;``).
Rows whose frames give an invalid spot are left out and counted by reason. Exit status 0 when
the test ran (the verdict is in the output), 1 on a user error.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("accuracy", help="T/GRLM 02-2014 tracking-accuracy test (clause 7-8) on a measurement series",
                       description="Tracking error η (formula 1) per measurement, accuracy (3.2) and precision (3.3) "
                                   "RMS, the fraction within the threshold in each wind bin and the clause 8.2 "
                                   "verdict per heliostat; bins and limits from tracking_test in the field config.")
    p.add_argument("series", type=Path, help="CSV: time, heliostat, wind_ms, and u_m, v_m or before, after")
    p.add_argument("--field", type=Path, required=True, help="field config YAML")
    p.add_argument("--method", choices=["grlm", "grlm-centroid", "centroid"], default=None,
                   help="spot method for frame rows (default: calibration.spot_method)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--summary", type=Path, help="write the JSON summary to this file")
    p.add_argument("--plot", type=Path, help="write the figure-3 style plot (PNG)")
    p.add_argument("--per-frame", type=Path, help="write a CSV with η and precision per measurement")
    p.set_defaults(func=run)


def _col(row: dict, *names):
    for n in names:
        if n in row and row[n] not in (None, ""):
            return row[n]
    return None


def _float(value, where: str) -> float:
    from helicalib.errors import ConfigError

    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected a number, got {value!r}") from None


def read_series(path: Path, field, method: str) -> tuple[list[dict], dict]:
    """Rows with ``time, heliostat, wind_ms, u_m, v_m`` (frames measured), and invalid-reason counts."""
    import csv

    from helicalib.errors import ConfigError

    if not path.is_file():
        raise ConfigError(f"{path}: file not found")
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        header = [h.strip() for h in (reader.fieldnames or [])]
        rows = [{k.strip(): (v.strip() if isinstance(v, str) else v) for k, v in r.items() if k} for r in reader]
    missing = [c for c in ("time", "heliostat", "wind_ms") if c not in header]
    has_uv = ("u_m" in header and "v_m" in header) or ("u" in header and "v" in header)
    has_frames = "before" in header and "after" in header
    if missing or not (has_uv or has_frames):
        need = missing + ([] if has_uv or has_frames else ["u_m, v_m or before, after"])
        raise ConfigError(f"{path}: header lacks {', '.join(need)}")
    out, invalid = [], {}
    marks_cache: dict = {}
    for i, r in enumerate(rows, start=2):
        where = f"{path}: line {i}"
        hid = r.get("heliostat")
        if not hid:
            raise ConfigError(f"{where}: heliostat: empty")
        field.heliostat(hid)  # unknown id → ConfigError
        wind = _float(r.get("wind_ms"), f"{where}: wind_ms")
        u, v = _col(r, "u_m", "u"), _col(r, "v_m", "v")
        item = {"time": r.get("time"), "heliostat": hid, "wind_ms": wind, "reason": "ok"}
        if u is not None and v is not None:
            item.update(u_m=_float(u, f"{where}: u_m"), v_m=_float(v, f"{where}: v_m"), source="uv")
        elif _col(r, "before") and _col(r, "after"):
            res = _measure_row(path.parent, r, field, hid, method, marks_cache)
            item["source"] = "frames"
            if res.valid:
                item.update(u_m=float(res.offset_m[0]), v_m=float(res.offset_m[1]))
            else:
                item["reason"] = res.reason
                invalid[res.reason] = invalid.get(res.reason, 0) + 1
        else:
            raise ConfigError(f"{where}: give u_m, v_m or before, after")
        out.append(item)
    return out, invalid


def _measure_row(base: Path, row: dict, field, hid: str, method: str, cache: dict):
    from helicalib.commands.spot import read_frames
    from helicalib.vision.marks import find_marks
    from helicalib.vision.spot import measure_spot

    target = field.target(field.heliostat(hid).target)
    cams = field.cameras_for(target.id)
    camera = cams[0] if cams else None
    before_p = base / row["before"]
    after_ps = [base / a.strip() for a in row["after"].split(";") if a.strip()]
    frames, bad = read_frames([before_p, *after_ps])
    if bad is not None:
        return bad
    key = (str(before_p), target.id)
    if key not in cache:
        cache[key] = find_marks(frames[0], target, camera)
    return measure_spot(frames[0], frames[1:], target, camera, method=method, marks=cache[key])


def evaluate(rows: list[dict], field) -> tuple[dict, dict]:
    """Per heliostat: η and precision per measurement, and the clause 8.2 result."""
    import numpy as np

    from helicalib.calibration.tracking_test import precision_angles_mrad, tracking_errors_mrad, tracking_test

    results, series = {}, {}
    for hid in dict.fromkeys(r["heliostat"] for r in rows):
        good = [r for r in rows if r["heliostat"] == hid and r["reason"] == "ok"]
        h = field.heliostat(hid)
        target = field.target(h.target)
        pivot = np.asarray(h.position_enu_m)
        if good:
            uv = np.array([[r["u_m"], r["v_m"]] for r in good])
            spots = target.uvw_to_enu(uv)
            eta = tracking_errors_mrad(spots, np.asarray(target.center_enu_m), pivot)
            prec = precision_angles_mrad(spots, pivot)
        else:
            eta = prec = np.zeros(0)
        for r, e, p in zip(good, eta, prec):
            r["eta_mrad"], r["precision_mrad"] = float(e), float(p)
        wind = np.array([r["wind_ms"] for r in good])
        results[hid] = tracking_test(eta, wind, field.tracking_test, precision_mrad=prec)
        series[hid] = (eta, wind)
    return results, series


def run(args) -> int:
    import csv

    from helicalib.config import load_field_config

    field = load_field_config(args.field)
    method = args.method or field.calibration.spot_method
    rows, invalid = read_series(args.series, field, method)
    results, series = evaluate(rows, field)
    verdicts = [r.verdict for r in results.values()]
    overall = "fail" if "fail" in verdicts else ("incomplete" if "incomplete" in verdicts or not verdicts else "pass")
    summary = {
        "series": str(args.series), "threshold_mrad": field.tracking_test.threshold_mrad,
        "rows": len(rows), "valid_rows": sum(r["reason"] == "ok" for r in rows), "invalid_reasons": invalid,
        "verdict": overall, "heliostats": {hid: r.to_json() for hid, r in results.items()},
    }
    if args.per_frame is not None:
        args.per_frame.parent.mkdir(parents=True, exist_ok=True)
        cols = ["time", "heliostat", "wind_ms", "u_m", "v_m", "eta_mrad", "precision_mrad", "reason"]
        with args.per_frame.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        summary["per_frame"] = str(args.per_frame)
    if args.plot is not None:
        from helicalib.calibration.tracking_test import plot_tracking_test

        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot_tracking_test(series, field.tracking_test, args.plot)
        summary["plot"] = str(args.plot)
    if args.summary is not None:
        args.summary.parent.mkdir(parents=True, exist_ok=True)
        args.summary.write_text(json.dumps(summary, indent=2))
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"tracking test (T/GRLM 02-2014 8.2), threshold {summary['threshold_mrad']:g} mrad: {overall.upper()}  "
          f"({summary['valid_rows']} of {len(rows)} rows usable)")
    for hid, r in results.items():
        bins = "  ".join(f"{b.wind_ms:g} m/s: {'-' if b.fraction is None else f'{100 * b.fraction:.0f}%'} (n={b.n})"
                         for b in r.bins)
        acc = "-" if r.accuracy_rms_mrad is None else f"{r.accuracy_rms_mrad:.2f}"
        prec = "-" if r.precision_rms_mrad is None else f"{r.precision_rms_mrad:.2f}"
        print(f"  {hid}: {r.verdict:<10} accuracy {acc} mrad RMS, precision {prec} mrad RMS  {bins}")
    if invalid:
        print("  left out: " + ", ".join(f"{k} × {v}" for k, v in sorted(invalid.items())))
    return 0
