"""One run of a sweep, as a worker executes it: a whole ``simulate_campaign`` in its own directory.

:func:`run_one` starts the run afresh (an unfinished or stale run folder is emptied first; a folder
that is not a run's own, :mod:`helicalib.outdir`, is refused and the run fails), keeps
the worker's stdout and stderr quiet (what the run prints goes to ``run.log`` beside its
database), adds the figures the sweep compares (:func:`run_figures`) and writes ``result.json``
atomically as its very last step: a run is finished exactly when that file exists with the
run's digest (:func:`finished_record`).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import sqlite3
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

from helicalib.app.cluster import TaskFailed, call_reporting
from helicalib.outdir import prepare
from helicalib.sweep.spec import Run, fidelity_supported

RESULT = "result.json"
RUN_OUTPUT = "sweep run"
"""The marker's word for one run's folder (:mod:`helicalib.outdir`): only such a folder is cleared."""
ACCEPTED_SHARE = 0.95
"""Share of the campaign's heliostats whose newest verdict must be an acceptance for ``days_to_95``."""


class RunFailed(TaskFailed):
    """A run raised (:class:`~helicalib.app.cluster.TaskFailed`: type, one-line message, the
    worker's traceback)."""


def run_one(run: Run, cfg, scenario) -> dict:
    """Run one simulation and return its record (also written to ``RUN_DIR/result.json``); any
    exception comes out as :class:`RunFailed`."""
    return call_reporting(_run, run, cfg, scenario, failure=RunFailed)


def _run(run: Run, cfg, scenario) -> dict:
    from helicalib.app.simulated import SimulationOptions, simulate_campaign

    # an interrupted or stale run starts afresh, never resumes; only a run folder is cleared
    out = prepare(run.run_dir, RUN_OUTPUT, replace=True, option="run folder",
                  advice="remove it or give the sweep another --out")
    extra = {"fidelity": run.fidelity} if fidelity_supported() else {}
    wall0, cpu0 = time.perf_counter(), time.process_time()
    with open(out / "run.log", "w", encoding="utf-8") as log, redirect_stdout(log), redirect_stderr(log):
        result = simulate_campaign(cfg, out, SimulationOptions(run.days, seed=run.sim_seed, scenario=scenario,
                                                               start_s=run.start_s, planner=run.planner,
                                                               heliostat_ids=list(run.heliostat_ids),
                                                               spots_per_board=run.spots_per_board, **extra))
    record = {"run": run.as_dict(), "digest": run.digest, "summary": result.summary,
              **run_figures(result.database, result.summary, len(cfg.targets)),
              "wall_s": round(time.perf_counter() - wall0, 1), "cpu_s": round(time.process_time() - cpu0, 1),
              "host": socket.gethostname(), "pid": os.getpid()}
    if not run.keep_frames:
        shutil.rmtree(out / "images", ignore_errors=True)
    tmp = out / (RESULT + ".tmp")
    tmp.write_text(json.dumps(record, indent=2), encoding="utf-8")
    os.replace(tmp, out / RESULT)
    return record


def finished_record(run: Run) -> dict | None:
    """The run's record if it finished with these settings (its ``result.json`` with the same digest)."""
    try:
        record = json.loads((Path(run.run_dir) / RESULT).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and record.get("digest") == run.digest else None


def has_result(run: Run) -> bool:
    """Whether a ``result.json`` is there at all (finished, perhaps with other settings)."""
    return (Path(run.run_dir) / RESULT).is_file()


def run_figures(db: Path, summary: dict, n_targets: int) -> dict:
    """The figures a sweep adds to the summary, read from the campaign's database.

    ``days_to_95``: plant days from the campaign start to the first verdict after which at least
    95 % of its heliostats (rounded up) have an accepted newest verdict; None if that never happens.
    ``visits_per_board_hour``: the summary's visits per target-hour counted over the boards the
    run's visits used instead of all the field's boards (a few heliostats use one or two boards).
    """
    # the campaign has closed its store (write-ahead log checkpointed): nothing changes the file now
    con = sqlite3.connect(f"file:{Path(db).resolve()}?mode=ro&immutable=1", uri=True)
    try:
        cid, start_s = con.execute("SELECT id, started_s FROM campaigns ORDER BY id DESC LIMIT 1").fetchone()
        n = con.execute("SELECT count(*) FROM heliostats WHERE campaign_id = ?", (cid,)).fetchone()[0]
        verdicts = con.execute("SELECT heliostat_id, time_s, accepted FROM verdicts WHERE campaign_id = ? ORDER BY id",
                               (cid,)).fetchall()
        boards = con.execute("SELECT count(DISTINCT target_id) FROM visits WHERE campaign_id = ?", (cid,)).fetchone()[0]
    finally:
        con.close()
    per_board = (summary["visits_per_target_hour"] * n_targets / boards) if boards else 0.0
    return {"days_to_95": days_to_share(verdicts, n, start_s, ACCEPTED_SHARE),
            "boards_used": int(boards), "visits_per_board_hour": round(per_board, 3)}


def days_to_share(verdicts, n: int, start_s: float, share: float) -> float | None:
    """Plant days from ``start_s`` to the first of ``verdicts`` ((heliostat, time [s], accepted) in
    the order recorded) after which ``ceil(share · n)`` heliostats have an accepted newest verdict."""
    need = math.ceil(share * n - 1e-9)
    newest: dict[str, bool] = {}
    count = 0
    for hid, t, accepted in verdicts:
        count += int(bool(accepted)) - int(newest.get(hid, False))
        newest[hid] = bool(accepted)
        if n and count >= need:
            return round((float(t) - start_s) / 86400.0, 4)
    return None
