"""What a crew reads, timed at 10³ and 10⁴ heliostats: ``status``, ``status --json`` and the crew
console (page load in headless Chromium, first paint of the map and of the heliostats table, the
table's page / sort / filter answers).

Databases are synthetic (:mod:`helicalib.store.synthetic`: rows written through the store's own
API), of the first N heliostats of a ``sim-field --n 10000 --targets 8`` field at the demo site
(``--field``, or made by ``sim-field`` in ``--fields-dir``), ``--days`` plant days each; or one
given database (``--db`` with ``--field``), copied first (a writer adds the read indexes,
:data:`helicalib.store.schema.READ_INDEXES`, as a campaign command would).

Each timing is the median of ``--repeat`` runs, wall and CPU: on a loaded machine the wall time
is mostly waiting for a core, the CPU time what the read costs. ``status`` runs as the command
(``python -m helicalib status``: interpreter start and imports included); the console is
``helicalib console DB`` in its own process, its CPU read from ``/proc``, and so is Chromium's
(every process of its profile) for a page load. In the printed table, a page load's CPU is the
server's on the ``response_end`` line and the browser's on the ``table`` line (the load is over
once the table's first page is in).

Usage::

    .venv/bin/python benchmarks/bench_crew_reads.py --field /tmp/f10k.yaml              # both sizes, ≈ 3 min
    .venv/bin/python benchmarks/bench_crew_reads.py --db syn1k.db --field f1k.yaml --db syn10k.db --field f10k.yaml
    .venv/bin/python benchmarks/bench_crew_reads.py --db syn10k.db --field f10k.yaml --what status

Prints a table and writes ``benchmarks/out/bench_crew_reads.json``: ``{"sizes": {N: {"database":
{...}, "status": {...}, "console": {...}}}, "machine": {...}}``. ``--what`` picks the parts
(:data:`PARTS`; a part is one function ``part(db, field, args) -> dict``). Progress on stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_campaign import OUT  # noqa: E402
from bench_scale import make_field  # noqa: E402

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
TABLE_QUERIES = {
    "first page": "",
    "next page": "offset=50",
    "sort by last error, desc": "sort=last_error_mrad&order=desc",
    "filter board T3, not accepted": "board=T3&verdict=not-accepted",
    "filter board T3, accepted": "board=T3&verdict=accepted",
    "filter last error 2-3 mrad, sort by RMS": "min_error=2&max_error=3&sort=rms_mrad",
    "search id": "q={first_id_but_last}",
}
"""The heliostats table's requests timed (``GET /api/heliostats?...``; the search is for the first
heliostat's id less its last character)."""


def log(msg: str) -> None:
    print(f"bench_crew_reads: {msg}", file=sys.stderr, flush=True)


def build(cfg, path: Path, n: int, days: float) -> dict:
    """A synthetic campaign of the first ``n`` heliostats of ``cfg`` at ``path``; its counts and build time."""
    from helicalib.store.synthetic import build_synthetic_campaign, open_for_synthesis

    ids = [h.id for h in cfg.heliostats[:n]]
    t0 = time.perf_counter()
    with open_for_synthesis(path) as store:
        s = build_synthetic_campaign(store, cfg, days=days, heliostat_ids=ids,
                                     progress=lambda d, total: log(f"{path.name}: {d} of {total} heliostats"))
    return {"heliostats": n, "days": days, "build_s": round(time.perf_counter() - t0, 1),
            **{k: getattr(s, k) for k in ("visits", "observations", "fits", "verdicts", "events")}}


def prepare(db: Path) -> dict:
    """Open ``db`` once as a writer (the read indexes are added), checkpoint; its size and counts."""
    from helicalib.store.sqlite import Store

    Store.open(db).close()
    with sqlite3.connect(db) as con:
        con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        counts = {t: con.execute(f"SELECT COUNT(*) FROM {t}").fetchone()[0]
                  for t in ("heliostats", "visits", "observations", "verdicts", "events")}
    return {"file_mb": round(db.stat().st_size / 1e6, 1), **counts}


def _median(runs: list[dict]) -> dict:
    return {k: round(statistics.median(r[k] for r in runs), 3) for k in runs[0]}


def time_command(cmd: list[str], repeat: int) -> dict:
    """Median wall and CPU (user + system of the child) seconds of ``cmd``; its output's size."""
    runs = []
    for _ in range(repeat):
        before = os.times()
        t0 = time.perf_counter()
        out = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, check=True,
                             env={**os.environ, "COLUMNS": "100"})
        wall = time.perf_counter() - t0
        after = os.times()
        runs.append({"wall_s": wall, "cpu_s": (after.children_user - before.children_user)
                     + (after.children_system - before.children_system), "bytes": len(out.stdout)})
    return _median(runs)


def part_status(db: Path, field: Path, args) -> dict:
    """``status`` and ``status --json`` as a crew runs them."""
    base = [sys.executable, "-m", "helicalib", "status", str(db)]
    res = {"status": time_command(base, args.repeat), "status --json": time_command(base + ["--json"], args.repeat)}
    log(f"status: {res}")
    return res


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (``/proc/PID/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _browser_cpu_s(profile: str) -> float:
    """User + system CPU seconds of every Chromium process of this profile so far."""
    total = 0.0
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if profile.encode() in (proc / "cmdline").read_bytes():
                total += _cpu_s(int(proc.name))
        except OSError:
            continue  # gone meanwhile
    return total


def _get(url: str) -> tuple[float, bytes]:
    t0 = time.perf_counter()
    with urllib.request.urlopen(url, timeout=120) as resp:
        body = resp.read()
    return time.perf_counter() - t0, body


def _browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="bench-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--window-size=1400,1800", f"--user-data-dir={profile}"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
    driver.set_page_load_timeout(120)
    return driver, profile


PAGE_FIGURES = """
const nav = performance.getEntriesByType("navigation")[0];
const canvas = document.getElementById("field-canvas");
const drawn = canvas ? Number(canvas.dataset.drawn || 0) : document.querySelectorAll("svg.field circle").length;
return {response_end_ms: nav.responseEnd, dom_content_loaded_ms: nav.domContentLoadedEventEnd,
        load_ms: nav.loadEventEnd, map_drawn_ms: window.helicalibMapDrawnAt || null,
        table_ms: window.helicalibTableLoadedAt || null, map_points: drawn, map_kind: canvas ? "canvas" : "svg",
        bytes: nav.transferSize};
"""


def page_load(driver, url: str, n: int) -> dict:
    """Load the page; wait for the map and the table's first page; the browser's timings [ms]."""
    driver.get(url)
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 120:
        got = driver.execute_script(PAGE_FIGURES)
        if got["table_ms"] is not None and (got["map_points"] or 0) > 0 and got["load_ms"]:
            break
        time.sleep(0.05)
    got = driver.execute_script(PAGE_FIGURES)
    if got["map_points"] != n:
        log(f"the map drew {got['map_points']} of {n} heliostats")
    return got


def part_console(db: Path, field: Path, args) -> dict:
    """``helicalib console DB`` in its own process: page loads in Chromium, table requests."""
    cmd = [sys.executable, "-m", "helicalib", "console", str(db), "--listen", "127.0.0.1:0", "--json",
           "--field", str(field)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    res: dict = {}
    try:
        url = json.loads(proc.stdout.readline())["url"]
        time.sleep(args.warm_s)  # the console reads the page's figures once at start (imports, layout)
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
        n = con.execute("SELECT COUNT(*) FROM heliostats").fetchone()[0]
        first_id = con.execute("SELECT heliostat_id FROM heliostats ORDER BY block_index LIMIT 1").fetchone()[0]
        con.close()
        cpu0 = _cpu_s(proc.pid)
        wall, body = _get(url)
        res[f"first page, {args.warm_s:g} s after start"] = {"wall_s": round(wall, 3), "server_cpu_s": round(_cpu_s(proc.pid) - cpu0, 3),
                                          "bytes": len(body)}
        driver, profile = _browser()
        try:
            loads = []
            for _ in range(args.repeat):
                time.sleep(1.1)  # past the view's cache: each load reads the database again
                cpu0, browser0 = _cpu_s(proc.pid), _browser_cpu_s(profile)
                got = page_load(driver, url, n)
                got["server_cpu_s"] = _cpu_s(proc.pid) - cpu0
                got["browser_cpu_s"] = _browser_cpu_s(profile) - browser0
                loads.append(got)
            res["page in Chromium"] = {**_median([{k: v for k, v in g.items() if isinstance(v, (int, float))}
                                                  for g in loads]), "map_kind": loads[-1]["map_kind"]}
        finally:
            driver.quit()
            shutil.rmtree(profile, ignore_errors=True)
        table = {}
        for name, q in TABLE_QUERIES.items():
            runs = []
            for _ in range(args.repeat):
                cpu0 = _cpu_s(proc.pid)
                wall, body = _get(url.rstrip("/") + "/api/heliostats?" + q.format(first_id_but_last=first_id[:-1]))
                runs.append({"wall_s": wall, "server_cpu_s": _cpu_s(proc.pid) - cpu0, "bytes": len(body)})
            table[name] = {**_median(runs), "matched": json.loads(body)["matched"]}
        res["table"] = table
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    log(f"console: {res}")
    return res


_MEASURED = ("import resource, subprocess, sys, time; t = time.perf_counter(); subprocess.run(sys.argv[1:], check=True, "
             "stdout=subprocess.DEVNULL); u = resource.getrusage(resource.RUSAGE_CHILDREN); print(time.perf_counter() - t, "
             "u.ru_utime + u.ru_stime, u.ru_maxrss)")
"""A child that runs a command and prints its wall [s], CPU [s] and largest resident set of it and its
worker processes [KB] (getrusage of the waited-for descendants)."""


def part_report_export(db: Path, field: Path, args, what: str) -> dict:
    """``report`` (build time) or ``export-paint --no-frames`` (peak RSS: it streams), once each."""
    out = db.parent / f"{what}_out"
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "helicalib"] + (
        ["report", str(db), "--out", str(out), "--no-frames", "--jobs", "2"] if what == "report" else
        ["export-paint", str(db), "--out", str(out), "--field", str(field), "--no-frames"])
    done = subprocess.run([sys.executable, "-c", _MEASURED, *cmd], stdout=subprocess.PIPE, text=True, check=True)
    wall, cpu, rss_kb = (float(x) for x in done.stdout.split())
    res = {"wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "peak_rss_mb": round(rss_kb / 1024, 1)}
    log(f"{what}: {res}")
    shutil.rmtree(out, ignore_errors=True)
    return res


PARTS = {"status": part_status, "console": part_console,
         "report": lambda db, field, args: part_report_export(db, field, args, "report"),
         "export": lambda db, field, args: part_report_export(db, field, args, "export")}
"""The parts ``--what`` names, in the order they run."""


def table(res: dict) -> str:
    lines = [f"{'heliostats':>10}  {'what':42} {'wall s':>8} {'CPU s':>8}"]
    for n, r in res["sizes"].items():
        for name, t in r.get("status", {}).items():
            lines.append(f"{n:>10}  {name:42} {t['wall_s']:8.2f} {t['cpu_s']:8.2f}")
        c = r.get("console")
        if c:
            first = next(v for k, v in c.items() if k.startswith("first page"))
            lines.append(f"{n:>10}  {'console: first page after start':42} {first['wall_s']:8.2f} "
                         f"{first['server_cpu_s']:8.2f}")
            p = c["page in Chromium"]
            cpu = {"response_end_ms": p["server_cpu_s"], "table_ms": p["browser_cpu_s"]}  # server's, browser's
            for key in ("response_end_ms", "dom_content_loaded_ms", "map_drawn_ms", "table_ms"):
                lines.append(f"{n:>10}  {'console page: ' + key.replace('_ms', '') + ' (' + p['map_kind'] + ')':42} "
                             f"{(p[key] or 0) / 1000:8.2f} {cpu.get(key, 0):8.2f}")
            for name, t in c["table"].items():
                lines.append(f"{n:>10}  {'table: ' + name:42} {t['wall_s']:8.3f} {t['server_cpu_s']:8.3f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--field", action="append", default=None,
                    help="a 10⁴-heliostat field config (default: made by sim-field); with --db, each database's "
                         "field config, in the same order")
    ap.add_argument("--fields-dir", default=None, help="keep (and reuse) the generated field here")
    ap.add_argument("--db", action="append", default=None,
                    help="time this database (copied first) instead of building (repeat for several); needs --field")
    ap.add_argument("--sizes", default="1000,10000", help="heliostat counts timed (default %(default)s)")
    ap.add_argument("--days", type=float, default=30.0, help="plant days of each database (default %(default)s)")
    ap.add_argument("--what", default=",".join(PARTS), help="parts timed, of " + ", ".join(PARTS)
                    + " (default %(default)s)")
    ap.add_argument("--warm-s", type=float, default=15.0, help="seconds between the console's start and the first "
                    "request (default %(default)s; 0: the first page while it still starts)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing, the median kept (default %(default)s)")
    ap.add_argument("--work", default=None, help="work folder (default a temporary one, removed)")
    ap.add_argument("--out", default=str(OUT / "bench_crew_reads.json"))
    args = ap.parse_args(argv)
    parts = [p.strip() for p in args.what.split(",") if p.strip()]
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        ap.error(f"--what {unknown[0]!r}: not one of {', '.join(PARTS)}")
    if args.db and (not args.field or len(args.field) != len(args.db)):
        ap.error("--db needs one --field per database (its campaign's field config), in the same order")
    if not args.db and args.field and len(args.field) > 1:
        ap.error("--field once: the field the databases are built from")

    from helicalib.config import load_field_config

    work = Path(args.work or tempfile.mkdtemp(prefix="bench_crew_reads_"))
    work.mkdir(parents=True, exist_ok=True)
    field = Path(args.field[0]) if args.field else make_field(10000, 8, Path(args.fields_dir or work))
    res: dict = {"field": str(field) if not args.db else args.field, "days": args.days, "what": parts, "sizes": {},
                 "machine": {"cpus": os.cpu_count(), "load_average_1min": round(os.getloadavg()[0], 2),
                             "date": time.strftime("%Y-%m-%d")}}
    if args.db:
        targets = []
        for k, (given, given_field) in enumerate(zip(args.db, args.field)):
            db = work / f"given{k}" / Path(given).name
            db.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(given, db)
            db.chmod(0o644)
            targets.append((None, db, Path(given_field)))
    else:
        cfg = load_field_config(field)
        targets = [(int(x), work / f"f{x}" / "syn.db", field) for x in args.sizes.split(",")]
        for n, db, _f in targets:
            res["sizes"][str(n)] = {"build": build(cfg, db, n, args.days)}
    for n, db, field in targets:
        figures = prepare(db)
        key = str(n if n is not None else figures["heliostats"])
        entry = res["sizes"].setdefault(key, {})
        entry["database"] = figures
        log(f"{key} heliostats: {figures}")
        for name in parts:
            entry[name] = PARTS[name](db, field, args)
    res["machine"]["load_average_1min_end"] = round(os.getloadavg()[0], 2)
    print(table(res))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    log(f"wrote {args.out}")
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
