"""``helicalib accuracy``: the T/GRLM 02-2014 tracking-accuracy test on a series of measurements.

    helicalib accuracy SERIES.csv --field FIELD.yaml [--json] [--summary OUT.json] [--plot OUT.png]
                                  [--per-frame OUT.csv] [--method grlm-centroid]

SERIES.csv has a header row with ``time``, ``heliostat``, ``wind_ms`` and either ``u_m``, ``v_m``
(spot centre on the heliostat's target board, metres from its centre; ``u``, ``v`` also accepted) or
``before``, ``after`` (frame paths relative to the CSV; several after frames separated by ``;``).
``time`` is an ISO 8601 instant with an offset, ``wind_ms`` a speed >= 0; a bad cell is refused
naming the file, line and column.
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


def _float(value, where: str, minimum: float | None = None) -> float:
    import math

    from helicalib.config import MAX_COORDINATE_M
    from helicalib.errors import ConfigError

    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected a number, got {str(value)[:40]!r}") from None
    if not math.isfinite(x):
        raise ConfigError(f"{where}: expected a finite number, got {value!r}")
    if minimum is not None and x < minimum:
        raise ConfigError(f"{where}: expected a number >= {minimum:g}, got {value!r}")
    if abs(x) > MAX_COORDINATE_M:
        raise ConfigError(f"{where}: {value!r} is out of range (at most {MAX_COORDINATE_M:g} in size)")
    return x


def read_series(path: Path, field, method: str) -> tuple[list[dict], dict]:
    """Rows with ``time, heliostat, wind_ms, u_m, v_m`` (frames measured), and invalid-reason counts.

    Every cell is checked: ``time`` an ISO 8601 instant with an offset, ``wind_ms`` a finite speed
    >= 0, ``u_m``/``v_m`` finite, ``heliostat`` an id of the field; a bad cell raises
    :class:`ConfigError` naming the file, line and column.
    """
    from helicalib.config import read_csv_rows
    from helicalib.errors import ConfigError, HelicalibError
    from helicalib.geometry.sun import parse_time

    lines = read_csv_rows(path)
    header = [h.strip() for h in lines[0][1]] if lines else []
    missing = [c for c in ("time", "heliostat", "wind_ms") if c not in header]
    has_uv = ("u_m" in header and "v_m" in header) or ("u" in header and "v" in header)
    has_frames = "before" in header and "after" in header
    if missing or not (has_uv or has_frames):
        need = missing + ([] if has_uv or has_frames else ["u_m, v_m or before, after"])
        raise ConfigError(f"{path}: header lacks {', '.join(need)}")
    dupes = sorted({h for h in header if h and header.count(h) > 1})
    if dupes:
        raise ConfigError(f"{path}: line {lines[0][0]}: column {dupes[0]} appears twice in the header")
    out, invalid = [], {}
    marks_cache: dict = {}
    for line_no, cells in lines[1:]:
        where = f"{path}: line {line_no}"
        if len(cells) != len(header):
            raise ConfigError(f"{where}: expected {len(header)} fields (as the header), got {len(cells)}")
        r = {k: v.strip() for k, v in zip(header, cells) if k}
        try:
            when = parse_time(r["time"]).isoformat() if r["time"] else None
        except HelicalibError as err:
            raise ConfigError(f"{where}: column time: {err}") from None
        if when is None:
            raise ConfigError(f"{where}: column time: empty (expected an ISO 8601 time with offset)")
        hid = r.get("heliostat")
        if not hid:
            raise ConfigError(f"{where}: column heliostat: empty")
        if not _known(field, hid):
            raise ConfigError(f"{where}: column heliostat: no heliostat {hid[:40]!r} in {field.source}")
        wind = _float(r.get("wind_ms"), f"{where}: column wind_ms", minimum=0.0)
        u, v = _col(r, "u_m", "u"), _col(r, "v_m", "v")
        item = {"time": r["time"], "heliostat": hid, "wind_ms": wind, "reason": "ok"}
        if u is not None and v is not None:
            item.update(u_m=_float(u, f"{where}: column {'u_m' if 'u_m' in r else 'u'}"),
                        v_m=_float(v, f"{where}: column {'v_m' if 'v_m' in r else 'v'}"), source="uv")
        elif _col(r, "before") and _col(r, "after") and any(a.strip() for a in r["after"].split(";")):
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
    if not out:
        raise ConfigError(f"{path}: no measurement rows after the header")
    return out, invalid


def _known(field, heliostat_id: str) -> bool:
    from helicalib.errors import ConfigError

    try:
        field.heliostat(heliostat_id)
    except ConfigError:
        return False
    return True


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
