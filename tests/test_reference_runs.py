"""``benchmarks/reference_runs.py compare``: two recordings, compared table by table, row for row.

Real SQLite databases made with the store, in two recording folders laid out as ``record`` lays
them out (``<dir>/<run>/sim/helicalib.db`` beside the printed JSON summary). A changed value is
found and named by table, row and column; a changed wall-clock column or the recording's own
folder in a path is not a difference.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
import sqlite3
import sys
from pathlib import Path

import pytest

from helicalib.store.sqlite import Store

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "reference_runs.py"


@pytest.fixture(scope="module")
def rr():
    spec = importlib.util.spec_from_file_location("reference_runs", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def _recording(root: Path, *, wall_s: float = 1000.0, summary_wall_s: float = 12.5) -> Path:
    """One recording of a run ``tiny``: a database (a campaign, a visit, an observation-free event
    trail, a verdict and a crew action with a wall-clock time) and its JSON summary."""
    run = root / "tiny"
    sim = run / "sim"
    with Store.open(sim / "helicalib.db", durable=False) as store:
        cid = store.start_campaign(name="tiny", mode="simulate", started_s=1.78e9,
                                   heliostats=[("H0001", 0, "T1"), ("H0002", 1, "T1")],
                                   config_path=str(run / "field.yaml"), settings={"seed": 1})
        vid = store.begin_visit(cid, "H0001", "T1", 1.78e9 + 60.0)
        store.end_visit(vid, ended_s=1.78e9 + 90.0, outcome="converged", reason="ok", iterations=2,
                        first_error_mrad=3.25, final_error_mrad=0.1 + 0.2)
        store.record_event(campaign_id=cid, time_s=1.78e9 + 30.0, kind="ungated", reason="calibration allowed")
        store.record_verdict(campaign_id=cid, heliostat_id="H0001", time_s=1.78e9 + 90.0, accepted=False,
                             n_points=1, rms_mrad=0.3, reasons=["1 valid point, 5 needed"])
        store.request_action(campaign_id=cid, kind="pause", who="crew", requested_wall_s=wall_s,
                             requested_s=1.78e9 + 100.0)
    summary = {"heliostats": 2, "visits": 1, "outcomes": {"converged": 1}, "wall_s": summary_wall_s,
               "database": "sim/helicalib.db"}
    (run / "simulate.stdout").write_text(json.dumps(summary, indent=2))
    (run / "simulate.stderr").write_text(f"simulate: done, day 0.30 of 0.3, 1 visits, elapsed {summary_wall_s:g} s\n")
    return root


def _set(db: Path, sql: str, *params) -> None:
    con = sqlite3.connect(db)
    with con:
        con.execute(sql, params)
    con.close()


def test_two_recordings_of_the_same_behaviour_are_identical(rr, tmp_path, capsys):
    # different folders, different wall clocks (database column, summary key, progress line)
    a = _recording(tmp_path / "a", wall_s=1000.0, summary_wall_s=12.5)
    b = _recording(tmp_path / "b", wall_s=2000.0, summary_wall_s=31.0)
    assert rr.main(["compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "tiny: identical" in out and "all identical" in out
    report = rr.compare(a, b)
    compared = report["runs"]["tiny"]["compared"]
    # every table was read, with its rows (not an empty comparison that passes by reading nothing)
    assert compared["helicalib.db:visits"] == 1 and compared["helicalib.db:operator_actions"] == 1
    assert compared["helicalib.db:heliostats"] == 2 and compared["files"] == 2  # simulate.stdout, .stderr


def test_one_changed_float_is_named_by_table_row_and_column(rr, tmp_path, capsys):
    a, b = _recording(tmp_path / "a"), _recording(tmp_path / "b")
    db = b / "tiny" / "sim" / "helicalib.db"
    # the last bit only: 0.1 + 0.2 stored, 0.3 written over it; equal to 15 digits, not bit for bit
    _set(db, "UPDATE visits SET final_error_mrad = ? WHERE id = 1", 0.3)
    assert rr.main(["compare", str(a), str(b)]) == 1
    out = capsys.readouterr().out
    assert "tiny: 1 difference(s)" in out
    assert "visits, row 1, final_error_mrad: A 0.30000000000000004 | B 0.3" in out
    assert "NOT identical" in out


def test_json_report_counts_every_difference_and_names_them(rr, tmp_path, capsys):
    a, b = _recording(tmp_path / "a"), _recording(tmp_path / "b")
    db = b / "tiny" / "sim" / "helicalib.db"
    _set(db, "UPDATE verdicts SET accepted = 1 WHERE id = 1")
    _set(db, "UPDATE operator_actions SET requested_s = requested_s + 1 WHERE id = 1")  # plant time: compared
    _set(db, "INSERT INTO events (campaign_id, time_s, kind, reason) VALUES (1, 1.78e9, 'gated', 'wind')")
    summary = json.loads((b / "tiny" / "simulate.stdout").read_text())
    summary["outcomes"]["converged"] = 2
    (b / "tiny" / "simulate.stdout").write_text(json.dumps(summary))
    assert rr.main(["compare", str(a), str(b), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    tiny = report["runs"]["tiny"]
    # the extra event shows twice: the events' row count, and SQLite's own counter of their ids
    assert report["identical"] is False and tiny["count"] == 5
    where = {(d["table"], d["column"]) for d in tiny["differences"]}
    assert where == {("verdicts", "accepted"), ("operator_actions", "requested_s"), ("events", "(row count)"),
                     ("sqlite_sequence", "seq"), ("file:simulate.stdout", "outcomes.converged")}
    assert {d["row"] for d in tiny["differences"] if d["table"] in ("verdicts", "operator_actions")} == {1}


def test_a_missing_table_file_or_run_is_a_difference_or_named(rr, tmp_path, capsys):
    a, b = _recording(tmp_path / "a"), _recording(tmp_path / "b")
    _set(b / "tiny" / "sim" / "helicalib.db", "DROP TABLE operator_actions")
    (b / "tiny" / "simulate.stderr").write_text("simulate: warning: something new\n")
    shutil.copytree(a / "tiny", a / "extra")
    assert rr.main(["compare", str(a), str(b)]) == 1
    out = capsys.readouterr().out
    assert "operator_actions, (table): A 'present' | B 'missing'" in out
    assert "file:simulate.stderr, row 1, (line): A '(missing)' | B 'simulate: warning: something new'" in out
    assert "only in A" in out and "extra" in out


def test_the_live_run_is_judged_by_its_verdicts_not_by_its_real_time_counts(rr, tmp_path, capsys):
    def live(root: Path, accepted: bool, observations: int) -> Path:
        run = root / "live-arm"
        with Store.open(run / "campaign.db", durable=False) as store:
            cid = store.start_campaign(name="live", mode="live", started_s=1.78e9, heliostats=[("H0001", 0, "T1")])
            vid = store.begin_visit(cid, "H0001", "T1", 1.78e9)
            store.end_visit(vid, ended_s=1.78e9 + 60.0 * observations, outcome="converged", reason="ok", iterations=2)
            # plant times differ with the machine's speed: only the verdict itself counts
            store.record_verdict(campaign_id=cid, heliostat_id="H0001", time_s=1.78e9 + 90.0 * observations,
                                 accepted=accepted, n_points=observations, rms_mrad=0.3, reasons=[])
        summary = {"event": "summary", "status": "finished", "heliostats": 1, "observations": observations}
        (run / "run.stdout").write_text(json.dumps(summary) + "\n")
        return root

    a = live(tmp_path / "a", False, 5)
    assert rr.main(["compare", str(a), str(live(tmp_path / "b", False, 3))]) == 0
    assert "live-arm: identical" in capsys.readouterr().out
    assert rr.main(["compare", str(a), str(live(tmp_path / "c", True, 5))]) == 1
    assert "live, final_verdict_accepted.H0001: A False | B True" in capsys.readouterr().out


def test_recordings_of_different_commands_are_not_identical(rr, tmp_path, capsys):
    # a --quick recording against a full one: the same tables, other runs; the manifests tell
    a, b = _recording(tmp_path / "a"), _recording(tmp_path / "b")
    for root, days in ((a, "0.28"), (b, "1")):
        argv = ["/x/.venv/bin/python", "-m", "helicalib", "simulate", f"{root}/demo.yaml", "--days", days]
        (root / "manifest.json").write_text(json.dumps({"repo": str(root), "runs": {"tiny": {"steps": [{"argv": argv}]}}}))
    assert rr.main(["compare", str(a), str(b)]) == 1
    out = capsys.readouterr().out
    assert "manifest, (commands): A ['helicalib simulate <repo>/demo.yaml --days 0.28'] | B" in out
    assert "tiny: 1 difference(s)" in out


def test_the_same_row_under_another_id_is_a_difference(rr, tmp_path, capsys):
    a, b = _recording(tmp_path / "a"), _recording(tmp_path / "b")
    db = b / "tiny" / "sim" / "helicalib.db"
    _set(db, "UPDATE verdicts SET id = 7 WHERE id = 1")  # every value alike, the row count too
    assert rr.main(["compare", str(a), str(b)]) == 1
    assert "verdicts, row 1, (row id): A 1 | B 7" in capsys.readouterr().out
