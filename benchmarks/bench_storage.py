"""Storage benchmark: what a 10⁴-heliostat campaign keeps on disk per month, and whether frame
retention (``helicalib prune-frames``, the nightly retention of ``operate``) keeps up at that size.

Databases are synthetic (:mod:`helicalib.store.synthetic`: rows written through the store's own
API, the campaign's shapes, seeded numbers), of the first N heliostats of a ``sim-field --n 10000
--targets 8`` field at the demo site (``--field``, or made by ``sim-field`` in ``--fields-dir``).
It prints and writes to ``benchmarks/out/bench_storage.json``:

* rows: per table (with its indexes) the bytes on disk (SQLite's ``dbstat``), rows, bytes per
  row and rows per heliostat-month of a 10⁴ × ``--days`` database (and of ``--real-db``, a real
  run's database, when given); the fits' JSON as stored and re-encoded without blanks;
* frames: bytes per real rendered camera frame (``--frames``, default ``demo_out/images`` of
  ``helicalib demo``), and what the lossless levers do to a sample of them (PNG level, strategy, a
  camera of half the resolution); frames written per heliostat-month; frames kept under the
  default retention (``operate --keep-frames 20``, rejected readings' frames kept) in the steady
  state, measured on a ``--months-heliostats`` × ``--months-days`` database, and the rejected
  frames that accumulate per month;
* GB per 10⁴ heliostat-months: rows, frames written, frames kept (steady state), total;
* retention times at each of ``--sizes`` (10³, 10⁴) on databases with small real PNG frames
  (``--frame-shape``; the time goes to rows and files, not to bytes): a dry run, the default
  retention, a first pruning that deletes most frames (``--keep-last 2``), an idle nightly pass
  after it, and the ``prune-frames --json`` command.

Usage::

    .venv/bin/python benchmarks/bench_storage.py --field /tmp/f10k.yaml          # ≈ 20 min on 2 busy cores
    .venv/bin/python benchmarks/bench_storage.py --field F.yaml --sizes 1000 --days 10 --months-days 60  # quick

Progress on stderr.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_campaign import OUT, ROOT
from bench_scale import make_field

TABLES = ("campaigns", "heliostats", "visits", "observations", "fits", "verdicts", "events", "operator_actions")
DEFAULT_KEEP = 20
"""``helicalib operate --keep-frames``'s default."""
MONTH_DAYS = 30.0


def log(msg: str) -> None:
    print(f"bench_storage: {msg}", file=sys.stderr, flush=True)


def build(cfg, path: Path, n: int, days: float, frame_shape=None) -> dict:
    """A synthetic campaign of the first ``n`` heliostats of ``cfg`` at ``path``; its counts and build time."""
    from helicalib.store.synthetic import build_synthetic_campaign, open_for_synthesis

    ids = [h.id for h in cfg.heliostats[:n]]
    t0 = time.perf_counter()
    with open_for_synthesis(path) as store:
        s = build_synthetic_campaign(store, cfg, days=days, heliostat_ids=ids, frame_shape=frame_shape,
                                     progress=lambda d, total: log(f"{path.name}: {d} of {total} heliostats, "
                                                                   f"{time.perf_counter() - t0:.0f} s"))
    with sqlite3.connect(path) as con:  # a checkpointed file: its size is the database's
        con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return {"heliostats": n, "days": days, "build_s": round(time.perf_counter() - t0, 1),
            **{k: getattr(s, k) for k in ("visits", "observations", "fits", "verdicts", "events", "frames")}}


def table_figures(db: Path, heliostats: int, days: float) -> dict:
    """Per table (with its indexes): bytes, rows, bytes per row, rows per heliostat-month."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        owner = dict(con.execute("SELECT name, tbl_name FROM sqlite_master WHERE type IN ('table', 'index')"))
        size: dict[str, int] = {}
        for name, pgsize in con.execute("SELECT name, SUM(pgsize) FROM dbstat GROUP BY name"):
            table = owner.get(name, name)
            size[table] = size.get(table, 0) + int(pgsize)
        hm = heliostats * days / MONTH_DAYS
        out = {}
        for t in TABLES:
            rows = con.execute(f"SELECT COUNT(*) FROM {t}").fetchone()[0]
            out[t] = {"bytes": size.get(t, 0), "rows": rows, "bytes_per_row": round(size.get(t, 0) / rows) if rows else None,
                      "rows_per_heliostat_month": round(rows / hm, 3)}
        fits = con.execute("SELECT params_json, sigma_json FROM fits").fetchall()
        stored = sum(len(p) + len(s) for p, s in fits)
        compact = sum(len(json.dumps(json.loads(p), sort_keys=True, separators=(",", ":")))
                      + len(json.dumps(json.loads(s), sort_keys=True, separators=(",", ":"))) for p, s in fits)
        n_params = len(json.loads(fits[0][0])) if fits else 0
        file_bytes = db.stat().st_size
    finally:
        con.close()
    return {"file_bytes": file_bytes, "heliostat_months": round(hm, 1), "tables": out,
            "fit_json": {"params": n_params, "stored_bytes_per_fit": round(stored / max(1, len(fits))),
                         "compact_bytes_per_fit": round(compact / max(1, len(fits))),
                         "float64_bytes_per_fit": 2 * 8 * n_params}}


def real_frames(folder: Path, sample: int) -> dict:
    """Bytes per real rendered frame, and what lossless re-encodings of a sample would take."""
    import cv2

    files = sorted(glob.glob(str(folder / "**" / "*.png"), recursive=True))
    if not files:
        return {"folder": str(folder), "frames": 0}
    sizes = [os.path.getsize(f) for f in files]
    levers = {"stored": 0, "png_level1": 0, "png_level9": 0, "png_huffman_only": 0, "half_resolution_level1": 0}
    encode_s = dict.fromkeys(levers, 0.0)
    picked = files[:: max(1, len(files) // sample)][:sample]
    shape = None
    for f in picked:
        image = cv2.imread(f, cv2.IMREAD_UNCHANGED)
        shape = image.shape
        levers["stored"] += os.path.getsize(f)
        for key, img, params in (
                ("png_level1", image, [cv2.IMWRITE_PNG_COMPRESSION, 1]),
                ("png_level9", image, [cv2.IMWRITE_PNG_COMPRESSION, 9]),
                ("png_huffman_only", image, [cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]),
                ("half_resolution_level1", cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2),
                                                      interpolation=cv2.INTER_AREA), [cv2.IMWRITE_PNG_COMPRESSION, 1])):
            t0 = time.process_time()
            ok, buf = cv2.imencode(".png", img, params)
            encode_s[key] += time.process_time() - t0
            assert ok and (key.startswith("half") or (cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) == image).all())
            levers[key] += len(buf)
    return {"folder": str(folder), "frames": len(files), "shape": list(shape or ()),
            "bytes_per_frame": round(sum(sizes) / len(sizes)), "min_bytes": min(sizes), "max_bytes": max(sizes),
            "sample": len(picked), "levers_bytes_per_frame": {k: round(v / len(picked)) for k, v in levers.items()},
            "levers_encode_cpu_ms": {k: round(1e3 * v / len(picked), 1) for k, v in encode_s.items() if k != "stored"}}


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, round(time.perf_counter() - t0, 2)


def retention_times(db: Path) -> dict:
    """The retention passes on ``db`` itself (module docstring): files really deleted, not links of a copy."""
    from helicalib.store.retention import retain_frames
    from helicalib.store.sqlite import Store

    out: dict = {}
    with Store.open(db, owner="bench_storage") as s:
        tracemalloc.start()
        r, out["dry_run_s"] = timed(lambda: retain_frames(s, DEFAULT_KEEP, dry_run=True))
        out["dry_run_peak_mb"] = round(tracemalloc.get_traced_memory()[1] / 1e6, 1)
        tracemalloc.stop()
        out["default"] = r.as_dict()
        r, out["default_s"] = timed(lambda: retain_frames(s, DEFAULT_KEEP))
        r, out["first_prune_s"] = timed(lambda: retain_frames(s, 2))
        out["first_prune"] = r.as_dict()
        out["files_per_s"] = round(r.files / max(out["first_prune_s"], 1e-3))
        r, out["idle_nightly_s"] = timed(lambda: retain_frames(s, 2))
        out["idle_nightly"] = r.as_dict()
    cmd = [sys.executable, "-m", "helicalib", "prune-frames", str(db), "--keep-last", "1", "--json"]
    done, out["command_s"] = timed(lambda: subprocess.run(cmd, capture_output=True, text=True, check=True))
    out["command"] = json.loads(done.stdout)
    return out


def steady_state(db: Path, heliostats: int, days: float) -> dict:
    """Frames kept per heliostat under the default retention after ``days`` (a long campaign): the
    bounded part (the newest ``DEFAULT_KEEP`` observations' frames) and the rejected ones beyond it,
    which are kept for ever and grow with the months."""
    from helicalib.store.retention import retain_frames
    from helicalib.store.sqlite import Store

    with Store.open(db, owner="bench_storage") as s:
        r = retain_frames(s, DEFAULT_KEEP)
        older = s._read("SELECT COUNT(*) FROM (SELECT valid, ROW_NUMBER() OVER (PARTITION BY heliostat_id ORDER BY "
                        "id DESC) AS k FROM observations WHERE before_frame_path IS NOT NULL) WHERE k > ?",
                        (DEFAULT_KEEP,))[0][0]
        rejected = s._read("SELECT COUNT(*) FROM observations WHERE valid = 0")[0][0]
    hm = heliostats * days / MONTH_DAYS
    per_obs = 2  # the synthetic campaign writes a before and an after frame per observation
    return {"heliostats": heliostats, "days": days, **r.as_dict(), "rejected_observations": rejected,
            "rejected_kept_beyond_newest": older,
            "kept_files_per_heliostat": round(r.kept_files / heliostats, 2),
            "bounded_files_per_heliostat": round((r.kept_files - per_obs * older) / heliostats, 2),
            "rejected_frames_per_heliostat_month": round(per_obs * rejected / hm, 3)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--field", default=None, help="a 10⁴-heliostat field config (default: made by sim-field)")
    ap.add_argument("--fields-dir", default=None, help="keep (and reuse) the generated field here")
    ap.add_argument("--sizes", default="1000,10000", help="heliostat counts timed (default %(default)s)")
    ap.add_argument("--days", type=float, default=30.0, help="plant days of each database (default %(default)s)")
    ap.add_argument("--frame-shape", default="8x8", help="frames of the timed databases, HxW (default %(default)s)")
    ap.add_argument("--frames", default=str(ROOT / "demo_out" / "images"), help="real rendered frames (default "
                    "demo_out/images of helicalib demo)")
    ap.add_argument("--sample", type=int, default=12, help="frames re-encoded for the levers (default %(default)s)")
    ap.add_argument("--months-heliostats", type=int, default=1000)
    ap.add_argument("--months-days", type=float, default=120.0, help="the steady-state database's days")
    ap.add_argument("--real-db", default=None, help="a real run's database: its tables' figures too")
    ap.add_argument("--work", default=None, help="work folder, kept (default a temporary one, removed at the end)")
    ap.add_argument("--out", default=str(OUT / "bench_storage.json"))
    args = ap.parse_args(argv)

    from helicalib.config import load_field_config

    work = Path(args.work or tempfile.mkdtemp(prefix="bench_storage_"))
    work.mkdir(parents=True, exist_ok=True)
    field = Path(args.field) if args.field else make_field(10000, 8, Path(args.fields_dir or work))
    cfg = load_field_config(field)
    sizes = [int(x) for x in args.sizes.split(",")]
    shape = tuple(int(x) for x in args.frame_shape.split("x"))
    n_rows = max(sizes)
    res: dict = {"field": str(field), "days": args.days, "default_keep_last": DEFAULT_KEEP}

    res["frames_real"] = real_frames(Path(args.frames), args.sample)
    log(f"real frames: {res['frames_real']}")
    if args.real_db:
        con = sqlite3.connect(f"file:{args.real_db}?mode=ro", uri=True)
        n_real = con.execute("SELECT COUNT(DISTINCT heliostat_id) FROM observations").fetchone()[0]
        lo, hi = con.execute("SELECT MIN(capture_time_s), MAX(capture_time_s) FROM observations").fetchone()
        con.close()
        res["rows_real"] = table_figures(Path(args.real_db), n_real, max((hi - lo) / 86400.0, 1 / 24))

    res["timed"] = {}
    for n in sizes:
        db = work / f"f{n}" / "syn.db"
        res["timed"][str(n)] = {"build": build(cfg, db, n, args.days, shape)}
        if n == n_rows:
            res["rows"] = table_figures(db, n, args.days)
            log(f"rows: {res['rows']['file_bytes'] / 1e6:.0f} MB for {n} heliostats x {args.days:g} days")
        res["timed"][str(n)].update(retention_times(db))
        log(f"retention at {n}: {res['timed'][str(n)]}")

    db = work / "months" / "syn.db"
    build(cfg, db, args.months_heliostats, args.months_days, shape)
    res["steady_state"] = steady_state(db, args.months_heliostats, args.months_days)
    log(f"steady state: {res['steady_state']}")

    res["per_10k_heliostat_months"] = per_10k(res)
    res["load_average_1min_end"] = round(os.getloadavg()[0], 2)
    print(table(res))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    log(f"wrote {out}; load average {res['load_average_1min_end']} (2 cores)")
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def per_10k(res: dict) -> dict:
    """GB per 10⁴ heliostat-months: rows, frames written, frames kept in the steady state."""
    rows = res["rows"]
    frame_b = res["frames_real"].get("bytes_per_frame", 0)
    n_rows = max(int(k) for k in res["timed"])
    written = res["timed"][str(n_rows)]["build"]["frames"] / rows["heliostat_months"]
    st = res["steady_state"]
    scale = 1e4 / 1e9
    out = {}
    if "rows_real" in res:  # the real run's bytes per row at the synthetic campaign's rows per heliostat-month
        real = res["rows_real"]["tables"]
        out["rows_gb_real_row_sizes"] = round(sum((real[t]["bytes_per_row"] or f["bytes_per_row"] or 0)
                                                  * f["rows_per_heliostat_month"]
                                                  for t, f in rows["tables"].items() if t in real) * scale, 3)
    return {**out, "rows_gb": round(rows["file_bytes"] / rows["heliostat_months"] * scale, 3),
            "frames_written_per_heliostat_month": round(written, 2),
            "frames_written_gb": round(written * frame_b * scale, 1),
            "frames_kept_per_heliostat": st["bounded_files_per_heliostat"],
            "frames_kept_gb": round(st["bounded_files_per_heliostat"] * frame_b * scale, 1),
            "rejected_frames_gb_per_month": round(st["rejected_frames_per_heliostat_month"] * frame_b * scale, 2)}


def table(res: dict) -> str:
    lines = ["table          bytes/row   rows/heliostat-month   MB (10⁴ x {:g} d)".format(res["days"])]
    for t, f in res["rows"]["tables"].items():
        if f["rows"]:
            lines.append(f"{t:14} {f['bytes_per_row'] or 0:9}   {f['rows_per_heliostat_month']:20.3f}   "
                         f"{f['bytes'] / 1e6:8.1f}")
    fj = res["rows"]["fit_json"]
    lines.append(f"fit JSON: {fj['stored_bytes_per_fit']} B stored, {fj['compact_bytes_per_fit']} B without blanks, "
                 f"{fj['float64_bytes_per_fit']} B as float64 ({fj['params']} parameters and sigmas)")
    fr = res["frames_real"]
    if fr.get("frames"):
        lines.append(f"real frame {fr['shape']}: {fr['bytes_per_frame'] / 1e3:.0f} KB ({fr['frames']} frames); levers "
                     + ", ".join(f"{k} {v / 1e3:.0f} KB" for k, v in fr["levers_bytes_per_frame"].items()))
    for n, t in res["timed"].items():
        lines.append(f"{n:>6} heliostats: build {t['build']['build_s']} s ({t['build']['frames']} frames); dry run "
                     f"{t['dry_run_s']} s (under tracemalloc: peak {t['dry_run_peak_mb']} MB), default retention {t['default_s']} s, "
                     f"first pruning {t['first_prune_s']} s ({t['first_prune']['files']} files, {t['files_per_s']}/s), "
                     f"idle nightly {t['idle_nightly_s']} s, prune-frames command {t['command_s']} s")
    st = res["steady_state"]
    lines.append(f"steady state ({st['heliostats']} x {st['days']:g} d, keep {res['default_keep_last']}): "
                 f"{st['kept_files_per_heliostat']} frames kept per heliostat, of which "
                 f"{st['bounded_files_per_heliostat']} of the newest (bounded); "
                 f"{st['rejected_frames_per_heliostat_month']} rejected frames per heliostat-month kept for ever")
    g = res["per_10k_heliostat_months"]
    real = f" ({g['rows_gb_real_row_sizes']} GB at the real run's bytes per row)" if "rows_gb_real_row_sizes" in g else ""
    lines.append(f"per 10⁴ heliostat-months: rows {g['rows_gb']} GB{real}; frames written {g['frames_written_gb']} GB "
                 f"({g['frames_written_per_heliostat_month']} per heliostat-month); kept under the default retention "
                 f"{g['frames_kept_gb']} GB (bounded) + {g['rejected_frames_gb_per_month']} GB per month of rejected")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
