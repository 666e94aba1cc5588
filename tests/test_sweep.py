"""helicalib sweep: a real 2-worker Dask LocalCluster on 127.0.0.1 runs real simulated campaigns.

One sweep (2 planners x 2 seeds, 2 heliostats of the demo field, 2.4 plant hours from 09:00
local time) is run with one run's directory blocked by a file, so that task fails inside the
worker; then it is run again with the block removed.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import stats

from helicalib.cli import main
from helicalib.outdir import prepare
from helicalib.sweep.spec import load_sweep
from helicalib.sweep.task import days_to_share

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"
SWEEP = {"field": str(FIELD), "days": 0.1, "seeds": [3, 7], "planners": ["gaps", "round-robin"],
         "starts": ["2026-06-01T09:00:00+06:18"], "heliostats": 2}


def _write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """The sweep run once with one run blocked, then again unblocked; what each run said."""
    tmp = tmp_path_factory.mktemp("sweep")
    sweep_file = _write(tmp / "sweep.yaml", SWEEP)
    out = tmp / "out"
    runs = load_sweep(sweep_file).runs(out)
    blocked = next(r for r in runs if r.planner == "gaps" and r.seed == 7)
    prepare(out, "sweep")                                     # a sweep's own folder (any other is refused)
    Path(blocked.run_dir).parent.mkdir(parents=True)
    Path(blocked.run_dir).write_text("not a directory")       # the worker cannot make the run's directory
    first = _sweep(sweep_file, out)
    results = {r.run_dir: Path(r.run_dir) / "result.json" for r in runs if r is not blocked}
    mtimes = {k: p.stat().st_mtime_ns for k, p in results.items()}
    table1 = pd.read_csv(out / "results.csv")
    failures = (out / "failures.txt").read_text()
    Path(blocked.run_dir).unlink()
    second = _sweep(sweep_file, out)
    return {"file": sweep_file, "out": out, "runs": runs, "blocked": blocked, "first": first, "second": second,
            "table1": table1, "failures": failures, "mtimes": mtimes, "results": results}


def _sweep(sweep_file: Path, out: Path) -> dict:
    import contextlib
    import io

    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        status = main(["sweep", str(sweep_file), "--out", str(out), "--workers", "2", "--json"])
    return {"status": status, "doc": json.loads(stdout.getvalue()), "stderr": stderr.getvalue()}


def test_a_failed_run_is_reported_in_one_line_while_the_others_finish(swept):
    first, blocked = swept["first"], swept["blocked"]
    assert first["status"] == 1
    assert first["doc"]["runs"] == {"total": 4, "skipped": 0, "submitted": 4, "rerun_stale": 0, "finished": 3,
                                    "failed": 1}
    reason = f"cell {blocked.cell}, seed 7: ConfigError: "
    lines = [ln for ln in first["stderr"].splitlines() if "failed: cell" in ln]
    assert len(lines) == 1 and lines[0].startswith(f"sweep: failed: {reason}"), first["stderr"]
    table = swept["table1"]
    assert len(table) == 4
    bad = table[(table.planner == "gaps") & (table.seed == 7)].iloc[0]
    assert bad.status == "failed" and bad.error.startswith(reason)
    assert math.isnan(bad.true_sky_rms_mrad)
    ok = table[table.status == "ok"]
    assert len(ok) == 3 and ok.error.isna().all() and (ok.heliostats == 2).all() and (ok.visits > 0).all()
    assert swept["failures"].startswith(reason) and "Traceback" in swept["failures"]
    assert f"run folder {blocked.run_dir}: is a file, not a folder" in lines[0]


def test_a_rerun_submits_only_the_runs_not_finished(swept):
    second = swept["second"]
    assert second["status"] == 0, second["stderr"]
    assert second["doc"]["runs"] == {"total": 4, "skipped": 3, "submitted": 1, "rerun_stale": 0, "finished": 4,
                                     "failed": 0}
    for key, path in swept["results"].items():
        assert path.stat().st_mtime_ns == swept["mtimes"][key], key      # not written again
    assert (Path(swept["blocked"].run_dir) / "result.json").is_file()
    table = pd.read_csv(swept["out"] / "results.csv")
    assert (table.status == "ok").all() and len(table) == 4
    assert not (swept["out"] / "failures.txt").exists()


def test_cell_means_and_t_intervals_recomputed_from_the_runs(swept):
    records = [json.loads(p.read_text()) for p in
               (Path(r.run_dir) / "result.json" for r in swept["runs"])]
    cells = {c["cell"]: c for c in swept["second"]["doc"]["cells"]}
    assert len(cells) == 2
    checked = 0
    for key, cell in cells.items():
        mine = [r for r in records if r["run"]["cell"] == key]
        assert cell["finished"] == len(mine) == 2
        for figure, values in (("true_sky_rms_mrad", [r["summary"]["true_sky_rms_mrad"] for r in mine]),
                               ("acceptance_rate", [r["summary"]["acceptance_rate"] for r in mine]),
                               ("visits_per_board_hour", [r["visits_per_board_hour"] for r in mine])):
            got = cell["figures"][figure]
            x = np.array(values, dtype=float)
            mean, s = x.mean(), x.std(ddof=1)
            t = stats.t.ppf(0.975, df=len(x) - 1)
            if figure == "acceptance_rate":       # a share: the t-interval cut to [0, 1]
                half = t * s / np.sqrt(len(x))
                want = [max(mean - half, 0.0), min(mean + half, 1.0)]
            else:                                 # positive, two seeds: the t-interval cut at 0 (three and
                half = t * s / np.sqrt(len(x))    # more get the log-scale one: test_sweep_intervals.py)
                want = [max(mean - half, 0.0), mean + half]
            assert got["n"] == 2 and got["mean"] == pytest.approx(mean)
            assert got["ci95"] == pytest.approx(want)
            checked += s > 0
    assert checked >= 2          # the seeds did give different figures: the intervals have a width
    assert "log-scale t-interval" in swept["second"]["doc"]["interval"]


def test_seeds_follow_the_documented_formula_and_not_the_order(swept, tmp_path):
    table = pd.read_csv(swept["out"] / "results.csv")
    for r in table.itertuples():
        number = int.from_bytes(hashlib.sha256(r.cell.encode()).digest()[:8], "big")
        want = np.random.SeedSequence(0, spawn_key=(number, r.seed)).generate_state(1, dtype=np.uint32)[0]
        assert r.sim_seed == want
    assert table.sim_seed.nunique() == 4
    reordered = _write(tmp_path / "reordered.yaml", {**SWEEP, "seeds": [7, 3], "planners": ["round-robin", "gaps"]})
    again = {(r.cell, r.seed): r.sim_seed for r in load_sweep(reordered).runs(tmp_path / "o")}
    assert again == {(r.cell, r.seed): r.sim_seed for r in table.itertuples()}


def test_a_run_alone_gives_the_summary_it_gave_in_the_sweep(swept, tmp_path):
    from helicalib.app.simulated import SimulationOptions, simulate_campaign
    from helicalib.config import load_field_config

    run = next(r for r in swept["runs"] if r.planner == "round-robin" and r.seed == 3)
    record = json.loads((Path(run.run_dir) / "result.json").read_text())
    alone = simulate_campaign(load_field_config(FIELD), tmp_path / "alone",
                              SimulationOptions(0.1, seed=run.sim_seed, start_s=run.start_s, planner="round-robin",
                                                heliostat_ids=["H0001", "H0002"]))
    drop = ("wall_s", "database")
    assert {k: v for k, v in alone.summary.items() if k not in drop} == \
           {k: v for k, v in record["summary"].items() if k not in drop}


def test_fidelity_fast_reaches_the_simulation(tmp_path):
    from helicalib.sweep.spec import fidelity_supported
    from helicalib.sweep.task import run_one

    if not fidelity_supported():
        pytest.skip("simulate_campaign has no fidelity parameter")
    render = load_sweep(_write(tmp_path / "render.yaml", SWEEP)).runs(tmp_path / "o")
    sweep = load_sweep(_write(tmp_path / "fast.yaml", {**SWEEP, "fidelity": "fast", "seeds": [3]}))
    fast = sweep.runs(tmp_path / "o")
    assert fast[0].sim_seed == render[0].sim_seed and fast[0].digest != render[0].digest  # a render result is stale
    record = run_one(fast[0], sweep.cfg, sweep.scenarios[fast[0].scenario])
    assert record["summary"]["fidelity"] == "fast" and record["summary"]["visits"] > 0
    assert not (Path(fast[0].run_dir) / "images").exists()


def test_days_to_95_counts_the_newest_verdict_of_each_heliostat():
    t0 = 1000.0
    verdicts = [("A", t0 + 86400, 1), ("A", t0 + 2 * 86400, 0),   # A refused again: no longer counts
                ("B", t0 + 3 * 86400, 1), ("A", t0 + 4 * 86400, 1)]
    assert days_to_share(verdicts, 2, t0, 0.95) == 4.0
    assert days_to_share(verdicts, 2, t0, 0.5) == 1.0
    assert days_to_share(verdicts[:3], 2, t0, 0.95) is None
    assert days_to_share(verdicts, 40, t0, 0.95) is None          # 38 of 40 needed
    assert days_to_share([], 0, t0, 0.95) is None


def test_sweep_file_problems_are_one_line_naming_file_and_key(tmp_path, capsys):
    no_planners = _write(tmp_path / "bad.yaml", {k: v for k, v in SWEEP.items() if k != "planners"})
    assert main(["sweep", str(no_planners), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"helicalib sweep: error: {no_planners}: planners: missing required key"]
    unknown = _write(tmp_path / "unknown.yaml", {**SWEEP, "heliostats": ["H0001", "X9"], "planners": ["gaps", "best"]})
    assert main(["sweep", str(unknown), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err == f"helicalib sweep: error: {unknown}: planners: [1] 'best' is not a planner; choose from gaps, " \
                  "round-robin, round-robin-shared\n"
    ids = _write(tmp_path / "ids.yaml", {**SWEEP, "heliostats": ["H0001", "X9"]})
    assert main(["sweep", str(ids), "--out", str(tmp_path / "o")]) == 1
    assert f"{ids}: heliostats[1]: 'X9' is not a heliostat" in capsys.readouterr().err
    from helicalib.sweep.spec import fidelity_supported

    if not fidelity_supported():
        fast = _write(tmp_path / "fast.yaml", {**SWEEP, "fidelity": "fast"})
        assert main(["sweep", str(fast), "--out", str(tmp_path / "o")]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "fidelity: 'fast' is not available yet" in err[0]
    assert not (tmp_path / "o").exists()       # nothing started


def test_workers_of_another_version_or_with_several_threads_are_refused():
    from helicalib import __version__
    from helicalib.errors import ConfigError
    from helicalib.sweep.engine import check_workers

    check_workers("tcp://127.0.0.1:8786", {"w1": __version__, "w2": __version__}, {"w1": 1, "w2": 1})
    with pytest.raises(ConfigError, match="runs helicalib 0.0.1"):
        check_workers("tcp://127.0.0.1:8786", {"w1": __version__, "w2": "0.0.1"}, {"w1": 1, "w2": 1})
    with pytest.raises(ConfigError, match="w2 has 4 threads; start the workers with --nthreads 1"):
        check_workers("tcp://127.0.0.1:8786", {"w1": __version__, "w2": __version__}, {"w1": 1, "w2": 4})
