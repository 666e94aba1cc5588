"""Scale benchmark: how a simulated campaign's cost grows with the field (``fidelity="fast"``, no frames).

For each field size N (``--sizes``, default 1000,3000) the field is made by ``helicalib sim-field --n N
--site 40.063,94.426,1267 --targets 8`` (the demo site; in a temporary directory, or kept in
``--fields-dir`` and reused when its board count matches), then
:func:`helicalib.app.simulated.simulate_campaign` runs it in-process for ``--days`` plant days
from a daylight start (``simulate``'s default start, local midnight of 2026-06-01, plus
``--start-hour`` hours, default 6; or ``--start ISO``), under cProfile unless ``--no-profile``.

Each size runs in its own process (the script re-invokes itself with ``--one N`` and reads one JSON
line back), so peak memory is that size's own. Per size it reports:

* wall and CPU seconds of the campaign (the field loaded, the summary included), peak RSS
  (``resource.getrusage``);
* visits, measurements (observations with iteration ≥ 0, read from the database), measurements per
  wall second, CPU seconds per measurement (of the whole run, and of the campaign loop alone, without
  the end-of-run summary, which evaluates every heliostat over the sky once); decisions (calls of
  ``choice.choose_next_vectorised``, or ``choose_next`` for the baselines) and the profiled time per decision;
* where the time goes: cProfile self time grouped by module (each ``helicalib.*`` module,
  ``sqlite3``, ``numpy``, ``scipy``, ``pandas``, ``other``) as percentages, and the same time
  charged to the ``helicalib`` module that called the library code ("charged": numpy called from
  the planner counts as the planner's);
* the top functions of ``helicalib`` by cumulative time.

And the flatness figure: CPU per measurement at the largest size over the smallest (1.0 is flat).
The product's goal is a 10⁴-heliostat, 30-day campaign in ≤ 10 min wall and ≤ 4 GB, with CPU per
measurement flat in N. The figures are taken under cProfile, which adds its own overhead to wall
and CPU time (``--no-profile`` measures without it; then there is no breakdown).

Usage::

    .venv/bin/python benchmarks/bench_scale.py                                  # 1000, 3000; 0.25 d
    .venv/bin/python benchmarks/bench_scale.py --jobs 2                         # both sizes at once
    .venv/bin/python benchmarks/bench_scale.py --sizes 10000 --days 0.1
    .venv/bin/python benchmarks/bench_scale.py --sizes 1000,3000,10000,30000 --fields-dir /tmp/fields

Progress on stderr at most every 10 s. Prints a table and writes ``benchmarks/out/bench_scale.json``.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import platform
import pstats
import resource
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_campaign import OUT, SITE  # noqa: E402

MARK = "BENCH_SCALE_RESULT "
PROGRESS_S = 10.0
GROUPS_LIB = ("sqlite3", "numpy", "scipy", "pandas")
TOP = 8


# ------------------------------------------------------------------ profile grouping
def module_of(filename: str, funcname: str) -> str:
    """The group of one profiled function: a dotted ``helicalib`` module, a library, or ``other``."""
    path = filename.replace("\\", "/")
    if "/helicalib/" in path:
        tail = path.rsplit("/helicalib/", 1)[1]
        mod = "helicalib." + tail[:-3].replace("/", ".") if tail.endswith(".py") else "helicalib"
        return mod[: -len(".__init__")] if mod.endswith(".__init__") else mod
    if filename == "~":  # built-ins: C functions, named by their object
        for lib in GROUPS_LIB:
            if lib in funcname:
                return lib
        return "other"
    for lib in GROUPS_LIB:
        if f"/{lib}/" in path:
            return lib
    return "other"


def breakdown(stats: pstats.Stats) -> dict:
    """Self time by module, and self time charged to the calling ``helicalib`` module, as percentages;
    the top ``helicalib`` functions by cumulative and by self time; the decision count."""
    raw = stats.stats  # (file, line, func) -> (primitive calls, calls, self, cumulative, callers)
    total = sum(v[2] for v in raw.values()) or 1e-12  # the modules' shares are of the self time
    root = max([v[3] for v in raw.values()] + [total])  # the functions' shares of the whole (simulate_campaign)
    own: dict[str, float] = {}
    for (f, _l, fn), (_cc, _nc, tt, _ct, _callers) in raw.items():
        own[module_of(f, fn)] = own.get(module_of(f, fn), 0.0) + tt

    memo: dict = {}

    def shares(key, seen=frozenset()) -> dict[str, float]:
        """How a non-helicalib function's time divides among the helicalib modules above it."""
        if key in memo:
            return memo[key]
        mod = module_of(key[0], key[2])
        if mod.startswith("helicalib"):
            return {mod: 1.0}
        callers = raw[key][4] if key in raw else {}
        weights = {c: (v[3] if len(v) > 3 else 0.0) for c, v in callers.items() if c not in seen}
        norm = sum(weights.values())
        if norm <= 0:
            return {mod: 1.0}
        out: dict[str, float] = {}
        for c, w in weights.items():
            for m, s in shares(c, seen | {key}).items():
                out[m] = out.get(m, 0.0) + s * w / norm
        memo[key] = out  # cycles aside (their callers skipped), the same for every path that reaches it
        return out

    charged: dict[str, float] = {}
    for key, (_cc, _nc, tt, _ct, _callers) in raw.items():
        for m, s in shares(key).items():
            charged[m] = charged.get(m, 0.0) + tt * s

    def pct(d):
        return {k: round(100.0 * v / total, 1) for k, v in sorted(d.items(), key=lambda kv: -kv[1])}

    def fn_row(key, v):
        f, line, fn = key
        mod = module_of(f, fn)
        return {"function": f"{mod}.{fn}:{line}", "calls": v[1], "self_s": round(v[2], 2), "cum_s": round(v[3], 2),
                "cum_pct": round(100.0 * v[3] / root, 1), "cum_ms_per_call": round(1000.0 * v[3] / max(v[1], 1), 3)}

    ours = [(k, v) for k, v in raw.items() if module_of(k[0], k[2]).startswith("helicalib")]
    decisions = [v for (f, _l, fn), v in raw.items()
                 if fn in ("choose_next", "choose_next_vectorised") and f.endswith("campaign/choice.py")]
    calls = sum(v[1] for v in decisions)
    return {
        "profiled_s": round(root, 2),
        "self_pct": pct(own),
        "charged_pct": pct(charged),
        "top_cumulative": [fn_row(k, v) for k, v in sorted(ours, key=lambda kv: -kv[1][3])[:TOP]],
        "top_self": [fn_row(k, v) for k, v in sorted(ours, key=lambda kv: -kv[1][2])[:TOP]],
        "decisions": calls,
        "decision_ms": round(1000.0 * sum(v[3] for v in decisions) / max(calls, 1), 2) if decisions else None,
    }


# ------------------------------------------------------------------ one size, in its own process
def counts(db: Path) -> dict:
    """Visits and measurements (observations with iteration ≥ 0) of the newest campaign, read-only."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        cid = con.execute("SELECT MAX(id) FROM campaigns").fetchone()[0]
        visits = con.execute("SELECT COUNT(*) FROM visits WHERE campaign_id = ?", (cid,)).fetchone()[0]
        meas, valid = con.execute("SELECT COUNT(*), COALESCE(SUM(valid), 0) FROM observations "
                                  "WHERE campaign_id = ? AND iteration >= 0", (cid,)).fetchone()
    finally:
        con.close()
    return {"visits": int(visits), "measurements": int(meas), "valid_measurements": int(valid)}


def peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return round(r / 2**20 if sys.platform == "darwin" else r / 1024.0, 1)


def run_size(n: int, field: Path, days: float, seed: int, start: str | None, start_hour: float,
             profile: bool) -> dict:
    """The campaign on ``field`` (``n`` heliostats) in this process; its figures."""
    from helicalib.app.simulated import default_start_s, SimulationOptions, simulate_campaign
    from helicalib.config import load_field_config
    from helicalib.geometry.sun import parse_time, to_unix_seconds

    wall0, cpu0 = time.perf_counter(), time.process_time()
    cfg = load_field_config(field)
    start_s = (float(to_unix_seconds([parse_time(start)])[0]) if start
               else default_start_s(cfg) + start_hour * 3600.0)
    load_wall, rss_loaded = time.perf_counter() - wall0, peak_rss_mb()
    state = {"last": time.perf_counter(), "ticks": 0, "loop_cpu": 0.0}
    end_s = start_s + days * 86400.0

    def progress(now_s: float) -> None:
        state["ticks"] += 1
        state["loop_cpu"] = time.process_time()  # the last tick's: the campaign loop ends there
        t = time.perf_counter()
        if t - state["last"] >= PROGRESS_S:
            state["last"] = t
            done = (now_s - start_s) / max(end_s - start_s, 1e-9)
            wall = t - wall0
            eta = wall / done - wall if done > 0 else float("nan")
            print(f"  [N={n}] plant day {now_s / 86400.0 - start_s / 86400.0:.3f} of {days:g} ({100 * done:.0f} %), "
                  f"{wall:.0f} s wall, {time.process_time() - cpu0:.0f} s CPU, {state['ticks']} ticks, "
                  f"peak {peak_rss_mb():.0f} MB, about {eta:.0f} s to go", file=sys.stderr, flush=True)

    prof = cProfile.Profile() if profile else None
    with tempfile.TemporaryDirectory(prefix=f"bench_scale_{n}_") as tmp:
        sim_wall0, sim_cpu0 = time.perf_counter(), time.process_time()
        if prof:
            prof.enable()
        try:
            result = simulate_campaign(cfg, Path(tmp), SimulationOptions(days, seed=seed, start_s=start_s,
                                                                         fidelity="fast"), progress=progress)
        finally:
            if prof:
                prof.disable()
        sim_wall, sim_cpu = time.perf_counter() - sim_wall0, time.process_time() - sim_cpu0
        c = counts(result.database)
        db_mb = round(sum(p.stat().st_size for p in Path(tmp).glob("helicalib.db*")) / 1e6, 1)
    s = result.summary
    out = {
        "n": n, "heliostats": len(cfg.heliostats), "targets": len(cfg.targets), "days": days, "seed": seed,
        "start_s": start_s, "load_wall_s": round(load_wall, 2), "wall_s": round(sim_wall, 1),
        "cpu_s": round(sim_cpu, 1), "peak_rss_mb": peak_rss_mb(), "rss_after_load_mb": rss_loaded,
        "database_mb": db_mb, "ticks": state["ticks"], **c,
        "measurements_per_wall_s": round(c["measurements"] / max(sim_wall, 1e-9), 2),
        "cpu_s_per_measurement": round(sim_cpu / c["measurements"], 4) if c["measurements"] else None,
        "loop_cpu_s": round(state["loop_cpu"] - sim_cpu0, 1),
        "summary_cpu_s": round(sim_cpu - (state["loop_cpu"] - sim_cpu0), 1),
        "loop_cpu_s_per_measurement": (round((state["loop_cpu"] - sim_cpu0) / c["measurements"], 4)
                                       if c["measurements"] else None),
        "accepted": s.get("accepted"), "outcomes": s.get("outcomes"), "profiled": profile,
    }
    if prof:
        out["profile"] = breakdown(pstats.Stats(prof))
    return out


# ------------------------------------------------------------------ the driver
def make_field(n: int, targets: int, directory: Path) -> Path:
    """``directory/field{n}.yaml`` from ``helicalib sim-field`` (reused when it exists with ``targets`` boards)."""
    path = directory / f"field{n}.yaml"
    if path.exists() and path.with_suffix(".csv").exists():
        from helicalib.config import load_field_config

        if len(load_field_config(path).targets) == targets:
            print(f"field {path}: reused", file=sys.stderr, flush=True)
            return path
    site = ",".join(f"{x:g}" for x in SITE)
    cmd = [sys.executable, "-m", "helicalib", "sim-field", "--n", str(n), "--site", site, "--targets", str(targets),
           "--out", str(path)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    print(f"field {path}: sim-field {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return path


def run_child(n: int, field: Path, args) -> dict:
    """One size in a child process (this script with ``--one``): its JSON line."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--one", str(n), "--field", str(field), "--days",
           str(args.days), "--seed", str(args.seed), "--start-hour", str(args.start_hour)]
    cmd += ["--start", args.start] if args.start else []
    cmd += ["--no-profile"] if args.no_profile else []
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)  # stderr (progress) passes through
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(MARK)]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"N={n}: the run failed (exit {proc.returncode})")
    r = json.loads(lines[-1][len(MARK):])
    r["process_wall_s"] = round(time.perf_counter() - t0, 1)
    return r


def table(runs: list[dict]) -> str:
    rows = [("wall [s]", "wall_s"), ("CPU [s]", "cpu_s"), ("peak RSS [MB]", "peak_rss_mb"),
            ("visits", "visits"), ("measurements", "measurements"), ("  valid", "valid_measurements"),
            ("measurements / wall s", "measurements_per_wall_s"), ("CPU s / measurement", "cpu_s_per_measurement"),
            ("campaign loop CPU [s]", "loop_cpu_s"), ("summary CPU [s]", "summary_cpu_s"),
            ("loop CPU s / measurement", "loop_cpu_s_per_measurement"),
            ("decisions", None), ("ms per decision (profiled)", None)]
    w = 12
    lines = [f"{'N':40s}" + "".join(f"{r['n']:>{w}d}" for r in runs)]
    for label, key in rows:
        if key is None:
            k = "decisions" if label.startswith("decisions") else "decision_ms"
            vals = [r.get("profile", {}).get(k) for r in runs]
        else:
            vals = [r.get(key) for r in runs]
        lines.append(f"{label:40s}" + "".join(f"{'-' if v is None else str(v):>{w}s}" for v in vals))
    if all("profile" in r for r in runs):
        for kind, title in (("self_pct", "self time by module [%]"), ("charged_pct", "charged to helicalib module [%]")):
            mods = []
            for r in runs:
                mods += [m for m in r["profile"][kind] if m not in mods]
            mods.sort(key=lambda m: -max(r["profile"][kind].get(m, 0.0) for r in runs))
            lines.append(title)
            for m in mods:
                vals = [r["profile"][kind].get(m, 0.0) for r in runs]
                if max(vals) >= 0.5:
                    lines.append(f"  {m:38s}" + "".join(f"{v:>{w}.1f}" for v in vals))
            rest = [round(sum(v for m, v in r["profile"][kind].items()
                              if max(q["profile"][kind].get(m, 0.0) for q in runs) < 0.5), 1) for r in runs]
            lines.append(f"  {'(each < 0.5)':38s}" + "".join(f"{v:>{w}.1f}" for v in rest))
        for r in runs:
            lines.append(f"top {TOP} helicalib functions by cumulative time, N={r['n']} "
                         f"(profiled {r['profile']['profiled_s']} s):")
            for f in r["profile"]["top_cumulative"]:
                lines.append(f"  {f['cum_pct']:5.1f} %  {f['cum_s']:8.1f} s  {f['calls']:>8d} calls  "
                             f"{f['cum_ms_per_call']:>10.3f} ms/call  {f['function']}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,3000", help="field sizes N, comma-separated (default %(default)s)")
    ap.add_argument("--days", type=float, default=0.25, help="plant days per size (default %(default)s)")
    ap.add_argument("--targets", type=int, default=8, help="boards of each generated field (default %(default)s)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start", default=None, help="plant start, ISO (default simulate's default start + --start-hour)")
    ap.add_argument("--start-hour", type=float, default=6.0,
                    help="hours after simulate's default start, local midnight of 2026-06-01 (default %(default)s)")
    ap.add_argument("--fields-dir", default=None, help="keep (and reuse) the generated fields here")
    ap.add_argument("--jobs", type=int, default=1,
                    help="sizes run at once, each in its own process (2 on a 2-core machine halves the wall time; "
                         "CPU figures stay comparable, wall figures then share the machine)")
    ap.add_argument("--no-profile", action="store_true", help="no cProfile (its overhead out; no breakdown)")
    ap.add_argument("--out", default=str(OUT / "bench_scale.json"))
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)  # a child: one size
    ap.add_argument("--field", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one is not None:
        r = run_size(args.one, Path(args.field), args.days, args.seed, args.start, args.start_hour,
                     profile=not args.no_profile)
        print(MARK + json.dumps(r), flush=True)
        return 0

    sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
    load0 = os.getloadavg()
    tmp = None if args.fields_dir else tempfile.mkdtemp(prefix="bench_scale_fields_")
    fields_dir = Path(args.fields_dir or tmp)
    fields_dir.mkdir(parents=True, exist_ok=True)
    try:
        fields = {n: make_field(n, args.targets, fields_dir) for n in sizes}

        def one(n: int) -> dict:
            print(f"N={n}: {args.days:g} plant days, fast fidelity{'' if args.no_profile else ', under cProfile'}",
                  file=sys.stderr, flush=True)
            r = run_child(n, fields[n], args)
            print(f"N={n}: {r['wall_s']} s wall, {r['cpu_s']} s CPU, {r['measurements']} measurements, "
                  f"peak {r['peak_rss_mb']:.0f} MB", file=sys.stderr, flush=True)
            return r

        with ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:  # each size is its own process
            runs = list(pool.map(one, sizes))
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    small, large = runs[0], runs[-1]
    flat = (round(large["cpu_s_per_measurement"] / small["cpu_s_per_measurement"], 2)
            if len(runs) > 1 and small["cpu_s_per_measurement"] and large["cpu_s_per_measurement"] else None)
    loop_flat = (round(large["loop_cpu_s_per_measurement"] / small["loop_cpu_s_per_measurement"], 2)
                 if len(runs) > 1 and small["loop_cpu_s_per_measurement"] and large["loop_cpu_s_per_measurement"]
                 else None)
    print(table(runs))
    if flat is not None:
        print(f"flatness: CPU per measurement at N={large['n']} over N={small['n']}: {flat} (1.0 is flat); "
              f"the campaign loop alone: {loop_flat}")
    doc = {"date": time.strftime("%Y-%m-%d"), "args": {k: v for k, v in vars(args).items() if k not in ("one", "field")}, "site": SITE,
           "cpus": os.cpu_count(), "machine": platform.machine(), "python": platform.python_version(),
           "load_average_before": load0, "load_average_after": os.getloadavg(),
           "flatness_cpu_per_measurement": flat, "flatness_loop_cpu_per_measurement": loop_flat, "runs": runs}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
