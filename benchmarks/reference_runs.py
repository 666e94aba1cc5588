"""Reference runs: record five runs of the product, and compare two recordings row for row.

A change that must not change behaviour (a reshape of the campaign core, say) is proved by
recording the reference runs before it, recording them again after it, and comparing the two:
every table of every database row for row, the printed JSON summaries key by key, and every other
file the runs wrote (frames, CSV exports, generated fields) byte for byte. Only what holds real
(wall-clock) time or the recording's own folder is left out or normalised; the lists below say
which and why. The live run against ``sim-plant`` runs in real time, so for it only the verdicts
and the observation counts are compared.

    .venv/bin/python benchmarks/reference_runs.py record OUT_DIR [--runs a,b] [--quick]
    .venv/bin/python benchmarks/reference_runs.py compare A_DIR B_DIR [--json] [--max N]

``record`` runs each reference run with the installed ``helicalib`` (``sys.executable -m
helicalib``) into ``OUT_DIR/<name>/``, prints which run is going and for how long, and writes
``OUT_DIR/manifest.json`` (commands, git commit, durations). ``--quick`` shortens every run (a few
minutes in all) for checking that the comparison itself is deterministic. ``compare`` exits 0 when
every run present in both recordings is identical, 1 otherwise. See docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import sqlite3
import struct
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from helicalib.commands._progress import format_elapsed

REPO = Path(__file__).resolve().parents[1]
DEMO = "field_config/demo_north.yaml"
MANIFEST = "manifest.json"

# ---------------------------------------------------------------------------------------------
# What the comparison leaves out, and why
# ---------------------------------------------------------------------------------------------

WALL_CLOCK_COLUMNS: dict[tuple[str, str], str] = {
    ("operator_actions", "requested_wall_s"):
        "the controller's wall clock when the crew's request arrived (plant time is requested_s)",
}
"""Database columns that hold real time, not plant time: skipped. Every other time column of the
schema (``started_s``, ``ended_s``, ``capture_time_s``, ``time_s``, ``requested_s``, ``done_s``) is
plant time, which the simulated plant's virtual clock makes reproducible."""

PATH_COLUMNS: dict[tuple[str, str], str] = {
    ("campaigns", "config_path"):
        "the field config's absolute path: the checkout (the demo field) or the run folder (a sim-field field)",
    ("campaigns", "settings_json"):
        "holds images_dir, the frames folder: relative beside the database, absolute (the run folder) elsewhere",
    ("observations", "before_frame_path"): "a frame's path (relative to the images folder today; normalised if not)",
    ("observations", "after_frame_paths_json"): "as before_frame_path, a JSON list of them",
}
"""Database columns that name files: compared after the recording's run folder and checkout are
replaced by ``<run>`` and ``<repo>``, so two recordings in two folders (or two checkouts) compare."""

WALL_CLOCK_SUMMARY_KEYS: dict[str, str] = {
    "wall_s": "simulate's real duration of the campaign loop",
    "cpu_s": "real CPU time, where a summary gives it",
}
"""Keys of a JSON summary (at any depth) that hold real time: skipped."""

PATH_SUMMARY_KEYS: dict[str, str] = {
    "database": "the database path as given on the command line: normalised like PATH_COLUMNS",
}
"""Keys of a JSON summary that name files: normalised."""

STDERR_PROGRESS = ("elapsed ",)
"""A stderr line containing this is a progress line: printed every few real seconds (how many lines
depends on the machine's speed), so progress lines are dropped before stderr is compared."""

DATABASE_SUFFIXES = (".db", ".db-wal", ".db-shm", ".db.lock", ".db-journal")
"""The database's own files: compared as tables, never as bytes (SQLite's page layout and its WAL
depend on when checkpoints ran)."""

# ---------------------------------------------------------------------------------------------
# The reference runs
# ---------------------------------------------------------------------------------------------

LIVE_RATE = 300.0
"""Plant seconds per real second of the live run's ``sim-plant`` (0.1 plant days in about 30 s)."""
LIVE_START = "2026-06-01T07:00:00+06:18"
"""The live run's plant start: 07:00 local time at the demo site, the sun up and rising."""
LIVE_SEED = 5
SIMFIELD_SITE = "40.063,94.426,1267"


@dataclass(frozen=True)
class Run:
    """One reference run: its name (its folder), what it is, and its length in plant days (full and
    ``--quick``)."""

    name: str
    what: str
    days: float
    quick_days: float
    live: bool = False


RUNS: tuple[Run, ...] = (
    Run("render-1d", "simulate demo_north.yaml --days 1 --seed 11: rendered frames, measured by the vision", 1.0, 0.28),
    Run("simfield-200-fast", "a 200-heliostat sim-field field (4 boards), --fidelity fast --days 0.3 --seed 3", 0.3,
        0.27),
    Run("operate-30d", "simulate demo_north.yaml --days 30 --fidelity fast --operate --drift-share 0.2 --seed 1",
        30.0, 2.5),
    Run("spots-auto-1d", "simulate demo_north.yaml --spots-per-board auto --days 1 --seed 7: rendered frames, "
        "three beams taking turns on a board", 1.0, 0.28),
    Run("live-arm", f"run --arm --days 0.1 --json against sim-plant on loopback (--rate {LIVE_RATE:g}, --start "
        f"{LIVE_START}, --seed {LIVE_SEED}): verdicts and observation counts only", 0.1, 0.05, live=True),
)
RUN_NAMES = tuple(r.name for r in RUNS)


def _helicalib() -> list[str]:
    return [sys.executable, "-m", "helicalib"]


def _simulate(field: str, days: float, *extra: str) -> list[str]:
    return [*_helicalib(), "simulate", field, "--days", f"{days:g}", "--out", "sim", "--json", *extra]


def planned_steps(run: Run, quick: bool) -> list[tuple[str, list[str]]]:
    """The commands of ``run`` as (step name, argv), run in its folder; the live run's are its
    sim-plant and its ``run`` (started by :func:`_record_live`)."""
    days = run.quick_days if quick else run.days
    demo = str(REPO / DEMO)
    if run.name == "render-1d":
        return [("simulate", _simulate(demo, days, "--seed", "11"))]
    if run.name == "simfield-200-fast":
        return [("sim-field", [*_helicalib(), "sim-field", "--n", "200", "--site", SIMFIELD_SITE, "--targets", "4",
                               "--out", "field.yaml"]),
                ("simulate", _simulate("field.yaml", days, "--fidelity", "fast", "--seed", "3"))]
    if run.name == "operate-30d":
        return [("simulate", _simulate(demo, days, "--fidelity", "fast", "--operate", "--drift-share", "0.2",
                                       "--seed", "1"))]
    if run.name == "spots-auto-1d":
        return [("simulate", _simulate(demo, days, "--spots-per-board", "auto", "--seed", "7"))]
    if run.name == "live-arm":
        return [("sim-plant", [*_helicalib(), "sim-plant", "live.yaml", "--rate", f"{LIVE_RATE:g}", "--start",
                               LIVE_START, "--seed", str(LIVE_SEED)]),
                ("run", [*_helicalib(), "run", "live.yaml", "--arm", "--days", f"{days:g}", "--json"])]
    raise SystemExit(f"unknown run {run.name!r}; known: {', '.join(RUN_NAMES)}")


# ---------------------------------------------------------------------------------------------
# record
# ---------------------------------------------------------------------------------------------


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, timeout=30).stdout.strip()
    except OSError:
        return ""


def _step(run_dir: Path, name: str, argv: list[str], label: str) -> dict:
    """Run one command in ``run_dir``, stdout and stderr into ``<name>.stdout``/``.stderr``, with a
    progress line every 30 s (the command's own last progress line)."""
    t0 = time.monotonic()
    err_path = run_dir / f"{name}.stderr"
    with open(run_dir / f"{name}.stdout", "w") as out, open(err_path, "w") as err:
        proc = subprocess.Popen(argv, cwd=run_dir, stdout=out, stderr=err, text=True)
        last = t0
        while proc.poll() is None:
            time.sleep(0.5)
            if time.monotonic() - last >= 30.0:
                last = time.monotonic()
                lines = err_path.read_text(errors="replace").splitlines()
                print(f"  {label}: {name} running, {format_elapsed(last - t0)}" + (f" ({lines[-1].strip()})" if lines else ""),
                      flush=True)
    took = time.monotonic() - t0
    if proc.returncode != 0:
        tail = err_path.read_text(errors="replace").strip().splitlines()[-3:]
        raise SystemExit(f"{label}: {name} failed (exit {proc.returncode}): " + " | ".join(tail))
    return {"step": name, "argv": argv, "duration_s": round(took, 1)}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise SystemExit(f"sim-plant exited (status {proc.returncode}) before listening on port {port}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise SystemExit(f"sim-plant: nothing listens on 127.0.0.1:{port} after {timeout_s:g} s")


def _live_field(run_dir: Path) -> None:
    """``live.yaml``: the demo field pointed at free loopback ports, its database in the run folder."""
    import yaml  # a dependency of helicalib

    data = yaml.safe_load((REPO / DEMO).read_text())
    port, cam_port = _free_port(), _free_port()
    data["plant"]["scs"]["port"] = port
    for cam in data["cameras"]:
        cam["url"] = f"http://127.0.0.1:{cam_port}/{cam['target']}.png"
    data["storage"] = {"database": "sqlite:///campaign.db", "images_dir": "frames"}
    (run_dir / "live.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    return port, cam_port


def _record_live(run: Run, run_dir: Path, quick: bool, label: str) -> list[dict]:
    """sim-plant in the background on free ports, ``run --arm`` against it, sim-plant stopped."""
    port, cam_port = _live_field(run_dir)
    (plant_name, plant_argv), (run_name, run_argv) = planned_steps(run, quick)
    log = open(run_dir / f"{plant_name}.stderr", "w")
    plant = subprocess.Popen(plant_argv, cwd=run_dir, stdout=subprocess.DEVNULL, stderr=log, text=True)
    try:
        _wait_port(port, plant)
        _wait_port(cam_port, plant)
        step = _step(run_dir, run_name, run_argv, label)
    finally:
        plant.send_signal(signal.SIGTERM)
        try:
            plant.wait(20)
        except subprocess.TimeoutExpired:
            plant.kill()
            plant.wait()
        log.close()
    return [{"step": plant_name, "argv": plant_argv, "duration_s": None}, step]


def record(out_dir: Path, names: list[str], quick: bool) -> dict:
    """Record the runs ``names`` into ``out_dir`` and write its manifest; returns the manifest."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / MANIFEST
    manifest = json.loads(path.read_text()) if path.exists() else {"runs": {}}
    package = subprocess.run([*_helicalib(), "--version"], capture_output=True, text=True).stdout.strip()
    manifest.update(git_commit=_git("rev-parse", "HEAD"), git_dirty=bool(_git("status", "--porcelain", "--", "src")),
                    repo=str(REPO), helicalib=package, python=platform.python_version(), cpus=os.cpu_count(),
                    quick=quick)
    wanted = [r for r in RUNS if r.name in names]
    t_all = time.monotonic()
    for i, run in enumerate(wanted, 1):
        label = f"[{i}/{len(wanted)}] {run.name}"
        run_dir = out_dir / run.name
        if run_dir.exists() and any(run_dir.iterdir()):
            raise SystemExit(f"{run_dir}: not empty (record into a new folder, or remove that run's folder)")
        run_dir.mkdir(parents=True, exist_ok=True)
        print(f"{label}: {run.what}{' (quick: %g days)' % run.quick_days if quick else ''}", flush=True)
        t0 = time.monotonic()
        if run.live:
            steps = _record_live(run, run_dir, quick, label)
        else:
            steps = [_step(run_dir, name, argv, label) for name, argv in planned_steps(run, quick)]
        took = time.monotonic() - t0
        manifest["runs"][run.name] = {"what": run.what, "days": run.quick_days if quick else run.days,
                                      "quick": quick, "steps": steps, "duration_s": round(took, 1),
                                      "load_average_after": list(os.getloadavg())}
        path.write_text(json.dumps(manifest, indent=2))
        print(f"{label}: done in {format_elapsed(took)} (all: {format_elapsed(time.monotonic() - t_all)})", flush=True)
    manifest["duration_s"] = round(sum(r["duration_s"] for r in manifest["runs"].values()), 1)
    path.write_text(json.dumps(manifest, indent=2))
    print(f"recorded {len(wanted)} run(s) in {format_elapsed(time.monotonic() - t_all)}; manifest {path}", flush=True)
    return manifest


# ---------------------------------------------------------------------------------------------
# compare
# ---------------------------------------------------------------------------------------------


@dataclass
class Difference:
    """One difference: where (``table``: a database table or ``file:<path>``; ``row``; ``column``:
    a column, a summary key, or a bracketed kind such as ``(row count)``) and the two values."""

    table: str
    row: Any
    column: str
    a: Any
    b: Any

    def line(self) -> str:
        row = "" if self.row is None else f", row {self.row}"
        return f"{self.table}{row}, {self.column}: A {_short(self.a)} | B {_short(self.b)}"


def _short(value: Any, width: int = 90) -> str:
    text = repr(value)
    return text if len(text) <= width else text[:width - 3] + "..."


@dataclass
class Side:
    """One recording's run folder and the prefixes its paths are normalised with."""

    run_dir: Path
    repo: str

    def normalise(self, text: str) -> str:
        for prefix, name in ((str(self.run_dir.resolve()), "<run>"), (str(self.run_dir), "<run>"),
                             (self.repo, "<repo>")):
            if prefix:
                text = text.replace(prefix, name)
        return text


@dataclass
class RunResult:
    name: str
    count: int = 0
    differences: list[Difference] = field(default_factory=list)
    compared: dict[str, int] = field(default_factory=dict)
    note: str = ""
    counts: dict[str, Any] = field(default_factory=dict)

    def add(self, diff: Difference, keep: int) -> None:
        self.count += 1
        if len(self.differences) < keep:
            self.differences.append(diff)


def same_value(a: Any, b: Any) -> bool:
    """Equal in type and value; floats bit for bit (``0.0`` and ``-0.0`` differ, NaN equals NaN)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return struct.pack("<d", a) == struct.pack("<d", b)
    return a == b


def _connect(db: Path) -> sqlite3.Connection:
    return sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True, timeout=10)


def _tables(conn: sqlite3.Connection) -> dict[str, str]:
    return dict(conn.execute("SELECT name, sql FROM sqlite_master WHERE type = 'table' ORDER BY name"))


def _table_rows(conn: sqlite3.Connection, table: str) -> tuple[list[str], list[tuple]]:
    """Column names (the first the rowid) and every row, in rowid (= id) order."""
    cur = conn.execute(f'SELECT rowid, * FROM "{table}" ORDER BY rowid')
    return [d[0] for d in cur.description], cur.fetchall()


def compare_databases(a_db: Path, b_db: Path, a: Side, b: Side, result: RunResult, keep: int) -> None:
    """Every table of the two databases, row for row in id order, into ``result``."""
    name = a_db.name
    ca, cb = _connect(a_db), _connect(b_db)
    try:
        ta, tb = _tables(ca), _tables(cb)
        for t in sorted(set(ta) | set(tb)):
            if t not in tb or t not in ta:
                result.add(Difference(t, None, "(table)", "present" if t in ta else "missing",
                                      "present" if t in tb else "missing"), keep)
                continue
            if ta[t] != tb[t]:
                result.add(Difference(t, None, "(schema)", ta[t], tb[t]), keep)
            cols_a, rows_a = _table_rows(ca, t)
            cols_b, rows_b = _table_rows(cb, t)
            result.compared[f"{name}:{t}"] = len(rows_a)
            if cols_a != cols_b:
                result.add(Difference(t, None, "(columns)", cols_a[1:], cols_b[1:]), keep)
                continue
            if len(rows_a) != len(rows_b):
                result.add(Difference(t, None, "(row count)", len(rows_a), len(rows_b)), keep)
            for ra, rb in zip(rows_a, rows_b):
                if ra[0] != rb[0]:
                    result.add(Difference(t, ra[0], "(row id)", ra[0], rb[0]), keep)
                for col, va, vb in zip(cols_a[1:], ra[1:], rb[1:]):
                    if (t, col) in WALL_CLOCK_COLUMNS:
                        continue
                    if (t, col) in PATH_COLUMNS and isinstance(va, str) and isinstance(vb, str):
                        va, vb = a.normalise(va), b.normalise(vb)
                    if not same_value(va, vb):
                        result.add(Difference(t, ra[0], col, va, vb), keep)
    finally:
        ca.close()
        cb.close()


def _flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(value, list):
        out = {f"{prefix}(length)": len(value)}
        for i, v in enumerate(value):
            out.update(_flatten(v, f"{prefix}[{i}]"))
        return out
    return {prefix: value}


def _leaf_key(key: str) -> str:
    return key.rsplit(".", 1)[-1].split("[", 1)[0]


def compare_json(table: str, va: Any, vb: Any, a: Side, b: Side, result: RunResult, keep: int) -> None:
    """Two JSON documents key by key (nested keys dotted), wall-time keys skipped, paths normalised."""
    fa, fb = _flatten(va), _flatten(vb)
    for key in list(fa) + [k for k in fb if k not in fa]:
        leaf = _leaf_key(key)
        if leaf in WALL_CLOCK_SUMMARY_KEYS:
            continue
        xa, xb = fa.get(key, "(missing)"), fb.get(key, "(missing)")
        if leaf in PATH_SUMMARY_KEYS and isinstance(xa, str) and isinstance(xb, str):
            xa, xb = a.normalise(xa), b.normalise(xb)
        if not same_value(xa, xb):
            result.add(Difference(table, None, key, xa, xb), keep)


def _json_lines(path: Path) -> Any:
    """A file's JSON: one document, or one per line (``run --json``)."""
    text = path.read_text()
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return [json.loads(line) for line in text.splitlines() if line.strip()]


def _stderr_lines(path: Path, side: Side) -> list[str]:
    return [side.normalise(line) for line in path.read_text(errors="replace").splitlines()
            if not any(p in line for p in STDERR_PROGRESS)]


def _files(run_dir: Path) -> dict[str, Path]:
    return {p.relative_to(run_dir).as_posix(): p for p in sorted(run_dir.rglob("*")) if p.is_file()}


def _is_database_file(rel: str) -> bool:
    return rel.endswith(DATABASE_SUFFIXES)


def compare_files(a: Side, b: Side, result: RunResult, keep: int) -> None:
    """Every file of the two run folders: databases table by table, JSON key by key (``*.json``,
    ``*.stdout``), stderr without progress lines, anything else byte for byte."""
    fa, fb = _files(a.run_dir), _files(b.run_dir)
    for rel in sorted(set(fa) | set(fb)):
        if rel.endswith(".db") and rel in fa and rel in fb:
            compare_databases(fa[rel], fb[rel], a, b, result, keep)
            continue
        if _is_database_file(rel):
            continue
        if rel not in fa or rel not in fb:
            result.add(Difference(f"file:{rel}", None, "(file)", "present" if rel in fa else "missing",
                                  "present" if rel in fb else "missing"), keep)
            continue
        result.compared["files"] = result.compared.get("files", 0) + 1
        if rel.endswith((".json", ".stdout")):
            try:
                ja, jb = _json_lines(fa[rel]), _json_lines(fb[rel])
            except json.JSONDecodeError:
                ja, jb = None, None
            if ja is not None:
                compare_json(f"file:{rel}", ja, jb, a, b, result, keep)
                continue
        if rel.endswith(".stderr"):
            la, lb = _stderr_lines(fa[rel], a), _stderr_lines(fb[rel], b)
            for i in range(max(len(la), len(lb))):
                xa = la[i] if i < len(la) else "(missing)"
                xb = lb[i] if i < len(lb) else "(missing)"
                if xa != xb:
                    result.add(Difference(f"file:{rel}", i + 1, "(line)", xa, xb), keep)
            continue
        ba, bb = fa[rel].read_bytes(), fb[rel].read_bytes()
        if ba != bb:
            result.add(Difference(f"file:{rel}", None, "(bytes)", f"{len(ba)} bytes", f"{len(bb)} bytes"), keep)


LIVE_SUMMARY_KEYS = ("status", "ended_because", "armed", "heliostats", "accepted")
"""Keys of ``run --json``'s final summary line compared for the live run (none depends on timing)."""


def _live_rows(run_dir: Path) -> tuple[list[tuple], list[tuple], dict[str, list]]:
    """The live run's visits (heliostat, target, outcome, iterations, reason), observations (valid,
    reason) and final verdicts per heliostat (accepted, points), in id order; empty without a database."""
    db = run_dir / "campaign.db"
    if not db.exists():
        return [], [], {}
    conn = _connect(db)
    try:
        visits = conn.execute("SELECT heliostat_id, target_id, outcome, iterations, reason FROM visits ORDER BY id").fetchall()
        obs = conn.execute("SELECT valid, reason FROM observations ORDER BY id").fetchall()
        verdicts = {h: [bool(a), n] for h, a, n in conn.execute(
            "SELECT heliostat_id, accepted, n_points FROM verdicts ORDER BY id")}  # the newest wins
    finally:
        conn.close()
    return visits, obs, verdicts


def _live_summary(run_dir: Path) -> dict:
    out = run_dir / "run.stdout"
    if not out.exists():
        return {}
    lines = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
    return next((x for x in reversed(lines) if x.get("event") == "summary"), {})


def live_facts(run_dir: Path) -> dict[str, Any]:
    """What the live run is judged by, none of it hanging on how fast the machine was: the summary's
    status, reason to end, arming, heliostats and accepted count; that every observation is valid;
    how the visits that the end of the run did not cut ended; each heliostat's final verdict."""
    visits, obs, verdicts = _live_rows(run_dir)
    summary = _live_summary(run_dir)
    facts: dict[str, Any] = {f"summary.{k}": summary.get(k) for k in LIVE_SUMMARY_KEYS}
    facts["invalid_observations"] = sum(1 for valid, _ in obs if not valid)
    facts["invalid_reasons"] = sorted({reason for valid, reason in obs if not valid})
    facts["outcomes_before_the_end"] = sorted({v[2] for v in visits if "campaign stopped" not in v[4]})
    facts["final_verdict_accepted"] = {h: v[0] for h, v in sorted(verdicts.items())}
    return facts


def live_counts(run_dir: Path) -> dict[str, Any]:
    """The live run's counts, reported beside the facts but not compared (they follow real time)."""
    visits, obs, verdicts = _live_rows(run_dir)
    summary = _live_summary(run_dir)
    return {"visits": len(visits), "observations": len(obs), "summary_observations": summary.get("observations"),
            "heliostats_with_a_verdict": len(verdicts),
            "visit_sequence": [f"{h}/{t}:{o}:{i}" for h, t, o, i, _ in visits]}


def _common_prefix(a: list, b: list) -> int:
    n = 0
    for x, y in zip(a, b):
        if x != y:
            break
        n += 1
    return n


def compare_live(a: Side, b: Side, result: RunResult, keep: int) -> None:
    """The live run: :func:`live_facts` compared (heliostats with a verdict in one run only are left
    out: which heliostats a 0.1-day run reaches depends on its speed); :func:`live_counts` reported."""
    fa, fb = live_facts(a.run_dir), live_facts(b.run_dir)
    both = set(fa["final_verdict_accepted"]) & set(fb["final_verdict_accepted"])
    for f in (fa, fb):
        f["final_verdict_accepted"] = {h: v for h, v in f["final_verdict_accepted"].items() if h in both}
    result.compared["live facts"] = len(fa)
    compare_json("live", fa, fb, a, b, result, keep)
    ca, cb = live_counts(a.run_dir), live_counts(b.run_dir)
    same = _common_prefix(ca["visit_sequence"], cb["visit_sequence"])
    result.note = (f"live run: timing-free facts only; not compared (real time): observations A {ca['observations']}"
                   f" | B {cb['observations']}, visits A {ca['visits']} | B {cb['visits']}, the first {same} visits "
                   f"alike (heliostat, board, outcome, iterations), {len(both)} heliostats with a verdict in both")
    result.counts = {"a": ca, "b": cb, "common_visit_prefix": same, "heliostats_with_a_verdict_in_both": len(both)}


def _manifest(root: Path) -> dict:
    path = root / MANIFEST
    return json.loads(path.read_text()) if path.exists() else {"runs": {}}


def _argv_text(steps: list[dict], repo: str) -> list[str]:
    """A run's commands as text, the interpreter and checkout left out (they may differ)."""
    out = []
    for s in steps:
        argv = list(s["argv"])
        if argv[1:3] == ["-m", "helicalib"]:
            argv = ["helicalib", *argv[3:]]
        out.append(" ".join(a.replace(repo, "<repo>") if repo else a for a in argv))
    return out


def compare(a_dir: Path, b_dir: Path, keep: int = 10) -> dict:
    """Compare two recordings; returns the report (``identical``, per run ``count`` and the first
    ``keep`` ``differences``)."""
    ma, mb = _manifest(a_dir), _manifest(b_dir)
    side_repo = (ma.get("repo", ""), mb.get("repo", ""))

    def runs(root: Path) -> set[str]:
        return {p.name for p in root.iterdir() if p.is_dir()} if root.is_dir() else set()

    ra, rb = runs(a_dir), runs(b_dir)
    report: dict[str, Any] = {"a": str(a_dir), "b": str(b_dir), "runs": {},
                              "only_in_a": sorted(ra - rb), "only_in_b": sorted(rb - ra)}
    live_names = {r.name for r in RUNS if r.live}
    for name in sorted(ra & rb, key=lambda n: (RUN_NAMES.index(n) if n in RUN_NAMES else len(RUN_NAMES), n)):
        a, b = Side(a_dir / name, side_repo[0]), Side(b_dir / name, side_repo[1])
        result = RunResult(name)
        sa, sb = ma["runs"].get(name), mb["runs"].get(name)
        if sa and sb:
            ca, cb = _argv_text(sa["steps"], side_repo[0]), _argv_text(sb["steps"], side_repo[1])
            if ca != cb:  # a quick recording against a full one, say: not the same runs
                result.add(Difference("manifest", None, "(commands)", ca, cb), keep)
        if name in live_names:
            compare_live(a, b, result, keep)
        else:
            compare_files(a, b, result, keep)
        report["runs"][name] = {"identical": result.count == 0, "count": result.count,
                                "differences": [asdict(d) for d in result.differences],
                                "compared": result.compared, "note": result.note, "counts": result.counts,
                                "lines": [d.line() for d in result.differences]}
    report["identical"] = bool(report["runs"]) and all(r["identical"] for r in report["runs"].values())
    return report


def print_report(report: dict) -> None:
    for name, r in report["runs"].items():
        tables = sum(1 for k in r["compared"] if k != "files")
        rows = sum(v for k, v in r["compared"].items() if k != "files")
        files = r["compared"].get("files", 0)
        if "live facts" in r["compared"]:
            what = f"{r['compared']['live facts']} facts; {r['note']}"
        else:
            what = f"{tables} tables, {rows} rows, {files} other files"
        if r["identical"]:
            print(f"{name}: identical ({what})")
        else:
            print(f"{name}: {r['count']} difference(s) ({what}); the first {len(r['lines'])}:")
            for line in r["lines"]:
                print(f"  {line}")
    for side in ("a", "b"):
        if report[f"only_in_{side}"]:
            print(f"only in {side.upper()} ({report[side]}): {', '.join(report[f'only_in_{side}'])} (not compared)")
    if not report["runs"]:
        print("no run is present in both recordings")
    print("all identical" if report["identical"] else "NOT identical")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="run the reference runs into OUT_DIR/<name>/")
    rec.add_argument("out_dir", type=Path)
    rec.add_argument("--runs", default=",".join(RUN_NAMES), help="comma-separated (default all: %(default)s)")
    rec.add_argument("--quick", action="store_true", help="shorten every run (a determinism check of the comparison)")
    cmp_ = sub.add_parser("compare", help="compare two recordings; exit 0 when identical, 1 otherwise")
    cmp_.add_argument("a_dir", type=Path)
    cmp_.add_argument("b_dir", type=Path)
    cmp_.add_argument("--json", action="store_true", help="print one JSON document")
    cmp_.add_argument("--max", type=int, default=10, help="differences shown per run (default %(default)s)")
    args = ap.parse_args(argv)
    if args.command == "record":
        names = [n.strip() for n in args.runs.split(",") if n.strip()]
        unknown = [n for n in names if n not in RUN_NAMES]
        if unknown:
            ap.error(f"--runs: unknown run(s) {', '.join(unknown)}; known: {', '.join(RUN_NAMES)}")
        record(args.out_dir, names, args.quick)
        return 0
    for d in (args.a_dir, args.b_dir):
        if not d.is_dir():
            ap.error(f"{d}: not a folder")
    report = compare(args.a_dir, args.b_dir, keep=max(1, args.max))
    if args.json:
        print(json.dumps(report, indent=2, default=repr))
    else:
        print_report(report)
    return 0 if report["identical"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
