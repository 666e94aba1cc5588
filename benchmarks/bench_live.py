"""A live controller against a simulated plant on loopback: does it keep up at 10⁴ heliostats?

``helicalib sim-plant`` (a subprocess: Modbus TCP and HTTP cameras on 127.0.0.1, free ports) serves
a ``sim-field --n N --targets 8`` field at ``--rate`` plant seconds per real second (a field beyond
2016 heliostats in the ``plant-interface-1-units`` register map: 2000 heliostats per unit id), and
``helicalib run --arm`` runs in this process for ``--plant-hours`` from ``--start-local-h`` (solar
hours of 2026-06-01). The database is seeded first through the store's API: ``--calibrated``
heliostats get two located points of the day before (placed by the nominal model), so the tracking
refresh rewrites that many heliostats' corrections every 15 plant minutes.

Measured here (the controller's plant client and cameras are wrapped to time-stamp each call):

* **reading → next command**: for each move or track command of a heliostat in a visit, the real
  time since the last frame its board's camera delivered for that visit, × rate = plant seconds the
  plant waited on the controller; p50/p95/p99, and p99 against the median visit's plant time (goal
  ≤ 5 %). A visit's first command follows the board's previous visit's frames, and the previous
  heliostat's move off the board lies between: that time is reported apart (``turnover_plant_s``);
* **tracking refresh lag**: per calibrated heliostat and refresh, plant seconds from when its
  refresh was due to when its track command went out; max and p99 against the 15-minute period;
* **controller RSS**: this process's peak (``VmHWM``; goal < 2 GB), the plant's for reference;
* **plant rate achieved**: plant seconds per real second over the run, from the plant's clock;
* **the split of reading → command**: for a reading, its last frame → its spot (measured on the
  camera's thread) and the spot → the command (the tick's part); a before frame's apart;
* **CPU** cores used by the controller and the simulated plant over the run;
* **full garbage collections** in the controller's process: how many, the longest, when those over
  0.1 s began (a collection holds every thread, the tick's too).

Prints progress every ``--progress-s`` real seconds and a summary; writes JSON (``--out``).

    .venv/bin/python benchmarks/bench_live.py --n 10000 --rate 10 --plant-hours 2
    .venv/bin/python benchmarks/bench_live.py --n 1000 --rate 10 --plant-hours 2
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

SITE = "40.063,94.426,1267"
DAY = "2026-06-01"
ONE_UNIT_REACH = 2016
"""Heliostats ``plant-interface-1`` addresses on one unit id."""


def make_field(n: int, work: Path) -> Path:
    """``sim-field`` field of ``n`` heliostats on 8 boards in ``work`` (made once); beyond one unit
    id's reach ``sim-field`` writes the units map into it."""
    path = work / f"field{n}.yaml"
    if not path.exists():
        work.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "helicalib", "sim-field", "--n", str(n), "--targets", "8", "--site", SITE,
                        "--out", str(path)], check=True, stdout=subprocess.DEVNULL)
    if n > ONE_UNIT_REACH and "register_map: plant-interface-1-units" not in path.read_text(encoding="utf-8"):
        raise SystemExit(f"{path}: a field of {n} heliostats without the units map (plant.register_map)")
    return path


def served(field: Path, modbus_port: int, camera_port: int, db: Path) -> Path:
    """A copy of ``field`` pointing at the sim-plant's ports and the run's own database."""
    text = field.read_text(encoding="utf-8")
    text = re.sub(r"(scs: \{host: 127\.0\.0\.1, port: )\d+", rf"\g<1>{modbus_port}", text)
    text = text.replace("http://127.0.0.1:8081/", f"http://127.0.0.1:{camera_port}/")
    text = re.sub(r"storage: \{database: '[^']*', images_dir: [^}]*\}",
                  f"storage: {{database: 'sqlite:///{db.name}', images_dir: {db.stem}-images}}", text)
    text = text.replace(f"heliostats_csv: {field.stem}.csv", f"heliostats_csv: {field.resolve().with_suffix('.csv')}")
    out = db.with_name(f"{db.stem}-field.yaml")
    out.write_text(text, encoding="utf-8")
    return out


def seed(cfg, db: Path, start_s: float, calibrated: int) -> None:
    """A live armed campaign whose first ``calibrated`` heliostats hold two visits of the day before,
    a located point each (the nominal model's strokes for the board's centre, the spot on it): the
    refresh then rewrites their corrections. Rows through the store's own API."""
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.geometry.sun import SunTable
    from helicalib.store.records import Observation
    from helicalib.store.sqlite import Store

    store = Store.open(db, db.with_name(f"{db.stem}-images"), durable=False)
    try:
        ids = [h.id for h in cfg.heliostats]
        cid = store.start_campaign(name=f"live {cfg.site.name}", mode="live", started_s=start_s - 86400.0,
                                   heliostats=[(h.id, i, h.target) for i, h in enumerate(cfg.heliostats)],
                                   config_path=str(cfg.source), settings={"armed": True, "planner": "gaps",
                                                                          "refine": False})
        chosen = ids[:calibrated]
        model = HeliostatModel.from_config(cfg, chosen)
        centres = np.array([cfg.target(cfg.heliostat(h).target).center_enu_m for h in chosen], dtype=float)
        table = SunTable(cfg.site)
        for hours in (-24.0, -19.0):           # two sun positions of the day before (morning, afternoon)
            t = start_s + hours * 3600.0
            vec, az, el, rising = table.position(t)
            aim = model.strokes_for_aim(np.asarray(vec), centres)
            for k, hid in enumerate(chosen):
                if not aim.in_range[k]:
                    continue
                s = tuple(float(x) for x in aim.strokes_mm[k])
                visit = store.begin_visit(cid, hid, cfg.heliostat(hid).target, t - 120.0)
                store.end_visit(visit, ended_s=t + 60.0, outcome="converged", reason="ok", iterations=1,
                                first_error_mrad=0.5, final_error_mrad=0.5)
                store.record_observation(Observation(
                    campaign_id=cid, heliostat_id=hid, target_id=cfg.heliostat(hid).target, visit_id=visit,
                    iteration=0, capture_time_s=t, strokes_cmd_mm=s, strokes_read_mm=s,
                    sun_enu=tuple(float(x) for x in vec), sun_azimuth_deg=float(az), sun_elevation_deg=float(el),
                    sun_rising=bool(rising), valid=True, spot_enu_m=tuple(float(x) for x in centres[k]),
                    error_mrad=0.5, wind_ms=3.0, dni_wm2=850.0))
        store.flush()
    finally:
        store.close()


class GcPauses:
    """The garbage collector's full (generation 2) collections in this process: real time and
    duration of each (``gc.callbacks``); a pause holds every thread, the tick's too."""

    def __init__(self):
        self.pauses: list[tuple[float, float]] = []   # (real time, seconds)
        self._t0 = None

    def __call__(self, phase, info):
        if info.get("generation") != 2:
            return
        if phase == "start":
            self._t0 = time.monotonic()
        elif self._t0 is not None:
            self.pauses.append((self._t0, time.monotonic() - self._t0))
            self._t0 = None


class Meter:
    """Time stamps of the controller's camera frames, plant commands and tracking refreshes."""

    def __init__(self, rate: float):
        self.rate = rate
        self.lock = threading.Lock()
        self.runner = None
        self.last_frame: dict[str, float] = {}           # camera url → real time of its last frame
        self.seen_frame: dict[str, float] = {}           # heliostat → the frame its last command followed
        self.gaps_s: list[float] = []                    # real seconds, last frame of a reading → next command
        self.refresh_lags_s: list[float] = []            # plant seconds, due → sent
        self.refreshes = 0
        self.commands = 0
        self.refresh_due_s = float("nan")
        self.rss_peak_mb = 0.0
        self.profile = None
        self.gap_log: list[tuple[float, str, str, float]] = []  # (real time, heliostat, command, gap real s)
        self.spot_done: dict[str, float] = {}           # camera thread → real time its last spot was measured
        self.split: list[tuple[str, float, float]] = []  # per gap: "reading" or "before", frame → spot, spot → command
        self.visit_seen: dict[int, float] = {}           # visit id → real time of its first command
        self.turnover_s: list[float] = []                # real seconds, a board's last frame → the next visit's first command

    def install(self):
        """Wrap the classes the run builds (undone by the returned function)."""
        from helicalib.campaign import sensor, tracking
        from helicalib.campaign.loop import CampaignRunner
        from helicalib.devices.camera_http import HttpCamera
        from helicalib.devices.modbus import ModbusPlant

        saved = [(HttpCamera, "grab", HttpCamera.grab), (ModbusPlant, "_command", ModbusPlant._command),
                 (CampaignRunner, "__init__", CampaignRunner.__init__),
                 (tracking.Tracking, "refresh", tracking.Tracking.refresh),
                 (sensor, "measure_spot", sensor.measure_spot)]
        meter = self

        def measure_spot(*a, **kw):
            out = saved[4][2](*a, **kw)
            with meter.lock:
                meter.spot_done[threading.current_thread().name] = time.monotonic()
            return out

        def grab(cam, *a, **kw):
            frame = saved[0][2](cam, *a, **kw)
            with meter.lock:
                meter.last_frame[cam.url] = time.monotonic()
            return frame

        def command(plant, index, cmd, fields, *a, **kw):
            t = time.monotonic()
            out = saved[1][2](plant, index, cmd, fields, *a, **kw)
            meter.on_command(index, t, cmd.name)
            return out

        def init(runner, *a, **kw):
            saved[2][2](runner, *a, **kw)
            meter.runner = runner
            if meter.profile is not None:            # the ticks run in the scheduler's threads, one at a time
                tick = runner.tick

                def profiled(now):
                    meter.profile.enable()
                    try:
                        return tick(now)
                    finally:
                        meter.profile.disable()
                runner.tick = profiled

        def refresh(tr, now):
            due = tr.state.last_refresh_s + tracking.verdicts.TRACKING_REFRESH_S
            meter.refresh_due_s = due if np.isfinite(due) else now
            meter.refreshes += 1
            saved[3][2](tr, now)

        HttpCamera.grab, ModbusPlant._command, CampaignRunner.__init__ = grab, command, init
        tracking.Tracking.refresh = refresh
        sensor.measure_spot = measure_spot

        def undo():
            for cls, name, fn in saved:
                setattr(cls, name, fn)
        return undo

    def on_command(self, index: int, t: float, what: str = "") -> None:
        self.commands += 1
        runner = self.runner
        if runner is None:
            return
        hid = runner.cfg.heliostats[index].id
        visit = runner.state.active.get(hid)
        if visit is None:                       # a refresh's write (a round is going out), or a return
            if what == "TRACK" and runner.state.refresh_round is not None:
                self.refresh_lags_s.append(runner.devices.clock.estimate_s() - self.refresh_due_s)
            return
        cam = next((c.url for c in runner.cfg.cameras if c.target == visit.target_id), None)
        first = self.visit_seen.setdefault(visit.ctx.visit_id, t)   # the visit's first command: before its frames
        with self.lock:
            last = self.last_frame.get(cam)
            spot = self.spot_done.get(f"helicalib-camera-{visit.target_id}_0")
        if last is not None and self.seen_frame.get(hid) != last and last <= t:
            self.seen_frame[hid] = last
            if last < first:  # the board's last frame is an earlier visit's: the board changed hands
                self.turnover_s.append(t - last)
                return
            self.gaps_s.append(t - last)
            self.gap_log.append((t, hid, what, t - last))
            if spot is not None and last <= spot <= t:   # a reading's spot, measured on the camera's thread
                self.split.append(("reading", spot - last, t - spot))
            else:                                         # a before frame's (or a spot measured on the tick)
                self.split.append(("before", float("nan"), t - last))


def rss_mb(pid: str | int = "self", key: str = "VmRSS") -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (0 when it cannot be read)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def split_figures(split, rate: float) -> dict:
    """Reading → command split: for a reading, the camera's last frame → its spot measured (on the
    camera's thread) and the spot → the command (the tick's part); apart, a before frame → the
    first placement's command. Plant seconds, p50/p99."""
    out = {}
    for kind in ("reading", "before"):
        rows = [(v, r) for k, v, r in split if k == kind]
        if not rows:
            continue
        vision = np.asarray([v for v, _r in rows]) * rate
        rest = np.asarray([r for _v, r in rows]) * rate
        out[kind] = {"n": len(rows), "tick_part_p50": pct(rest, 50), "tick_part_p99": pct(rest, 99)}
        if kind == "reading":
            out[kind].update(vision_p50=pct(vision, 50), vision_p99=pct(vision, 99),
                             total_p99=pct(vision + rest, 99))
    return out


def pct(values, q) -> float | None:
    return None if not len(values) else round(float(np.percentile(values, q)), 3)


def start_plant(field: Path, rate: float, start_iso: str, log: Path) -> tuple[subprocess.Popen, int, int]:
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", "sim-plant", str(field), "--rate", str(rate),
                             "--start", start_iso, "--port", "0", "--camera-port", "0", "--seed", "1"],
                            stdout=open(log, "w"), stderr=subprocess.STDOUT)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 300:
        text = log.read_text(encoding="utf-8") if log.exists() else ""
        modbus = re.search(r"Modbus TCP\s+127\.0\.0\.1:(\d+)", text)
        camera = re.search(r"http://127\.0\.0\.1:(\d+)/", text)
        if modbus and camera and "Ctrl-C" in text:
            return proc, int(modbus.group(1)), int(camera.group(1))
        if proc.poll() is not None:
            raise SystemExit(f"sim-plant exited: {text}")
        time.sleep(0.5)
    proc.terminate()
    raise SystemExit("sim-plant did not start within 300 s")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="heliostats (default 10000)")
    ap.add_argument("--rate", type=float, default=10.0, help="plant seconds per real second (default 10)")
    ap.add_argument("--plant-hours", type=float, default=2.0, help="plant hours the controller runs (default 2)")
    ap.add_argument("--start-local-h", type=float, default=9.5, help="start, solar hours of 2026-06-01 (default 9.5)")
    ap.add_argument("--calibrated", type=int, default=None, help="heliostats seeded with points (default all)")
    ap.add_argument("--work", type=Path, default=Path("benchmarks/out/live"))
    ap.add_argument("--progress-s", type=float, default=30.0)
    ap.add_argument("--profile", type=Path, default=None, help="write a cProfile of the controller's ticks here")
    ap.add_argument("--out", type=Path, default=None, help="JSON (default benchmarks/out/bench_live_<n>.json)")
    a = ap.parse_args(argv)
    out_json = a.out or Path(f"benchmarks/out/bench_live_{a.n}.json")

    from helicalib.app.simulated import default_start_s
    from helicalib.cli import main as cli
    from helicalib.config import load_field_config
    from helicalib.store.sqlite import Store

    field = make_field(a.n, a.work)
    cfg = load_field_config(field)
    start_s = default_start_s(cfg) + a.start_local_h * 3600.0
    iso = lambda t: time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime(t))  # noqa: E731
    run_dir = a.work / f"run{a.n}"
    shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.mkdir(parents=True)
    db = run_dir / "live.db"
    calibrated = a.n if a.calibrated is None else min(a.calibrated, a.n)
    t = time.monotonic()
    print(f"bench_live: N={a.n}, rate {a.rate}x, {a.plant_hours} plant h from {iso(start_s)}; seeding "
          f"{calibrated} calibrated heliostats ...", flush=True)
    seed(cfg, db, start_s, calibrated)
    print(f"  seeded in {time.monotonic() - t:.1f} s", flush=True)
    proc, modbus_port, camera_port = start_plant(field, a.rate, iso(start_s), run_dir / "sim-plant.log")
    print(f"  sim-plant up (Modbus {modbus_port}, cameras {camera_port})", flush=True)
    meter = Meter(a.rate)
    undo = meter.install()
    gc_pauses = GcPauses()
    gc.callbacks.append(gc_pauses)
    cpu0, plant_cpu0 = time.process_time(), cpu_s(proc.pid)
    stop = threading.Event()
    wall0 = time.monotonic()
    plant_t0 = None
    out = sys.stdout

    def progress():
        while not stop.wait(a.progress_s):
            r = meter.runner
            meter.rss_peak_mb = max(meter.rss_peak_mb, rss_mb())
            if r is None:
                print(f"  [{time.monotonic() - wall0:6.0f} s] opening the campaign (resume of {a.n} heliostats), "
                      f"RSS {rss_mb():.0f} MB", file=out, flush=True)
                continue
            try:
                now = r.devices.clock.estimate_s()
            except Exception:  # noqa: BLE001 - a progress line never stops the run
                now = float("nan")
            print(f"  [{time.monotonic() - wall0:6.0f} s] load {os.getloadavg()[0]:.1f}, plant {iso(now)[11:19]}, "
                  f"visits {r.state.stats.visits}, "
                  f"in visit {len(r.state.active)}, commands {meter.commands}, refreshes {meter.refreshes}, "
                  f"gaps {len(meter.gaps_s)} (p99 {pct(meter.gaps_s, 99)} s real), RSS {rss_mb():.0f} MB", file=out,
                  flush=True)

    if a.profile is not None:
        import cProfile

        meter.profile = cProfile.Profile()
    th = threading.Thread(target=progress, daemon=True)
    th.start()
    field_run = served(field, modbus_port, camera_port, db)
    log = run_dir / "run.log"
    status = None
    try:
        with open(log, "w", encoding="utf-8") as fh, contextlib.redirect_stdout(fh), contextlib.redirect_stderr(fh):
            status = cli(["run", str(field_run), "--arm", "--until", iso(start_s + a.plant_hours * 3600.0)])
    finally:
        stop.set()
        undo()
        gc.callbacks.remove(gc_pauses)
        wall = time.monotonic() - wall0
        cpu, plant_cpu = time.process_time() - cpu0, cpu_s(proc.pid) - plant_cpu0
        plant_rss = rss_mb(proc.pid, "VmHWM")
        proc.terminate()
        proc.wait(30)
    meter.rss_peak_mb = max(meter.rss_peak_mb, rss_mb("self", "VmHWM"))
    if meter.profile is not None:
        meter.profile.dump_stats(str(a.profile))
        print(f"wrote the ticks' profile to {a.profile}")
    (run_dir / "gaps.json").write_text(json.dumps([(round(t - wall0, 2), h, w, round(g * a.rate, 2))
                                                   for t, h, w, g in meter.gap_log]), encoding="utf-8")
    r = meter.runner
    with Store.open(db, readonly=True) as store:
        visits = [v for v in store.visits() if v.ended_s is not None and v.started_s >= start_s
                  and v.outcome not in ("aborted", "interrupted")]            # this run's, not the seeded ones
        durations = [v.ended_s - v.started_s for v in visits]
        events = store.events()
    opened = next((e for e in events if e.kind == "campaign"), None)
    plant_t0 = opened.time_s if opened is not None else start_s
    plant_end = r.journal.safe_now()[0] if r is not None else float("nan")
    gaps_plant = np.asarray(meter.gaps_s) * a.rate
    turnover = np.asarray(meter.turnover_s) * a.rate
    both = np.concatenate([gaps_plant, turnover])      # a visit's first command included: one figure, as first measured
    visit_plant = float(np.median(durations)) if durations else None
    p99 = pct(gaps_plant, 99)
    lags = np.asarray(meter.refresh_lags_s)
    result = {
        "date": time.strftime("%Y-%m-%d"), "n": a.n, "rate": a.rate, "plant_hours": a.plant_hours,
        "calibrated": calibrated, "run_status": status, "wall_s": round(wall, 1),
        "plant_rate_achieved": round((plant_end - plant_t0) / wall, 2) if r is not None else None,
        "visits_ended": len(durations), "visit_plant_s_median": None if visit_plant is None else round(visit_plant, 1),
        "commands": meter.commands, "readings_to_command": len(gaps_plant),
        "reading_to_command_plant_s": {"p50": pct(gaps_plant, 50), "p95": pct(gaps_plant, 95), "p99": p99,
                                       "max": None if not len(gaps_plant) else round(float(gaps_plant.max()), 3)},
        "reading_to_command_p99_over_visit": None if (p99 is None or not visit_plant) else round(p99 / visit_plant, 4),
        "turnover_plant_s": {"n": len(turnover), "p50": pct(turnover, 50), "p99": pct(turnover, 99)},
        "with_turnover_plant_s": {"p50": pct(both, 50), "p95": pct(both, 95), "p99": pct(both, 99)},
        "refreshes": meter.refreshes, "refresh_writes": int(len(lags)),
        "refresh_lag_plant_s": {"p99": pct(lags, 99), "max": None if not len(lags) else round(float(lags.max()), 1),
                                "period": 900.0},
        "gap_split_plant_s": split_figures(meter.split, a.rate),
        "cpu_cores_used": {"controller": round(cpu / wall, 2), "sim_plant": round(plant_cpu / wall, 2)},
        "gc_full_collections": {"n": len(gc_pauses.pauses),
                                "max_s": round(max((d for _t, d in gc_pauses.pauses), default=0.0), 3),
                                "total_s": round(sum(d for _t, d in gc_pauses.pauses), 2),
                                "at_s": [round(t - wall0, 1) for t, d in gc_pauses.pauses if d > 0.1]},
        "controller_rss_peak_mb": round(meter.rss_peak_mb, 1), "plant_rss_peak_mb": round(plant_rss, 1),
        "load_average_1min_end": round(os.getloadavg()[0], 1), "cpus": os.cpu_count(),
    }
    print(json.dumps(result, indent=1))
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(result, indent=1), encoding="utf-8")
    print(f"wrote {out_json} (run log {log})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
