"""A simulation split over a Dask cluster: groups of boards, one task each, merged into one campaign.

Real parts throughout: a 2-worker ``LocalCluster`` on 127.0.0.1, the simulated plant, real SQLite
files, the ``status`` and ``report`` command handlers reading the merged database. The failing
group is a real task that raises on its worker (the test module is shipped to the workers by
value, as Dask does for code the workers cannot import).
"""

from __future__ import annotations

import json
import sqlite3
import sys

import cloudpickle
import numpy as np
import pytest

from helicalib.app.simulated import SimulationOptions
from helicalib.app.split import Group, plan_groups, run_group, simulate_split
from helicalib.cli import main
from helicalib.commands.simulate import with_drift_share
from helicalib.config import load_field_config
from helicalib.geometry.sun import parse_time, to_unix_seconds
from helicalib.sim.scenario import Scenario
from helicalib.store.merge import merge_campaigns
from helicalib.store.sqlite import Store

from conftest import DEMO_FIELD, ROOT

BENCH500 = ROOT / "simulations" / "fields" / "bench500.yaml"
START = "2026-09-22T09:00:00+06:18"
DAYS = 0.12
PER_BOARD = 3


def _chosen(cfg) -> list[str]:
    """The first few heliostats of each board of the demo field (a quick campaign of both boards)."""
    out = []
    for t in cfg.targets:
        out += [h.id for h in cfg.heliostats if h.target == t.id][:PER_BOARD]
    return out


def _rows(db, sql, *params):
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return con.execute(sql, params).fetchall()
    finally:
        con.close()


def test_groups_are_whole_boards_with_the_heliostats_they_serve():
    cfg = load_field_config(BENCH500)
    groups = plan_groups(cfg, 2)
    assert [g.boards for g in groups] == [("T1", "T2"), ("T3", "T4")]
    seen = [h for g in groups for h in g.heliostats]
    assert sorted(seen) == sorted(h.id for h in cfg.heliostats)          # each heliostat exactly once
    for g in groups:
        assert {cfg.heliostat(h).target for h in g.heliostats} == set(g.boards)
    assert [len(g.boards) for g in plan_groups(cfg, 9)] == [1, 1, 1, 1]  # never more groups than boards
    only = [h.id for h in cfg.heliostats if h.target == "T3"][:5]
    assert plan_groups(cfg, 2, only) == [Group(1, ("T3",), tuple(only))]


@pytest.fixture(scope="module")
def cluster():
    """A client of a 2-worker ``LocalCluster`` on 127.0.0.1 (one thread per worker), shared by the
    module's split runs: the command joins it with ``--scheduler``."""
    from helicalib.app.cluster import embedded_cluster

    with embedded_cluster(2) as client:
        yield client


def test_split_run_merges_into_one_campaign_that_status_and_report_read(tmp_path, capsys, cluster):
    cfg = load_field_config(DEMO_FIELD)
    ids = _chosen(cfg)
    out = tmp_path / "split"
    address = cluster.scheduler.address
    assert address.startswith("tcp://127.0.0.1:")
    status = main(["simulate", str(DEMO_FIELD), "--days", str(DAYS), "--start", START, "--fidelity", "fast",
                   "--heliostats", ",".join(ids), "--drift-share", "0.5", "--scheduler", address, "--out", str(out),
                   "--json"])
    assert status == 0
    summary = json.loads(capsys.readouterr().out)
    db = out / "helicalib.db"
    assert summary["split"]["groups"] == 2 and summary["split"]["failed"] == []
    assert summary["heliostats"] == len(ids)
    # one campaign; every group's observations, visits, fits and verdicts in it, ids renumbered
    assert _rows(db, "SELECT count(*), min(status) FROM campaigns") == [(1, "finished")]
    settings = json.loads(_rows(db, "SELECT settings_json FROM campaigns")[0][0])
    assert settings["split"]["boards"] == [["T1"], ["T2"]]
    for table in ("visits", "observations", "fits", "verdicts"):
        merged = _rows(db, f"SELECT count(*) FROM {table}")[0][0]
        parts = sum(_rows(out / "groups" / g / "helicalib.db", f"SELECT count(*) FROM {table}")[0][0]
                    for g in ("g1", "g2"))
        assert merged == parts > 0, table
    boards_seen = {t for (t,) in _rows(db, "SELECT DISTINCT target_id FROM observations")}
    assert boards_seen == {"T1", "T2"}
    # an observation's visit is the merged visit of the same heliostat, and the visits run in time order
    assert _rows(db, "SELECT count(*) FROM observations o JOIN visits v ON v.id = o.visit_id "
                     "WHERE v.heliostat_id != o.heliostat_id") == [(0,)]
    starts = [t for (t,) in _rows(db, "SELECT started_s FROM visits ORDER BY id")]
    assert starts == sorted(starts)
    assert summary["visits"] == _rows(db, "SELECT count(*) FROM visits")[0][0]

    # the same truth for each heliostat as the unsplit plant: its drift, drawn by its row of the field
    scenario = with_drift_share(Scenario(), 0.5, DAYS).model_copy(update={"seed": 1})
    start_s = float(to_unix_seconds([parse_time(START)])[0])
    from helicalib.sim.plant import SimulatedPlant

    whole = SimulatedPlant(cfg, scenario, start_s=start_s)
    expected = [e.to_dict() for e in whole.truth.drift_events if e.heliostat_id in ids and e.start_s < start_s
                + DAYS * 86400.0]
    assert expected, "the scenario drifts some of the chosen heliostats"
    key = lambda e: e["heliostat_id"]  # noqa: E731
    assert sorted(summary["drift_events"], key=key) == sorted(expected, key=key)

    # the readers take it for one run
    assert main(["status", str(db), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert {h["heliostat_id"] for h in shown["heliostats"]} == set(ids)
    assert all(h["observations"] > 0 for h in shown["heliostats"])
    assert main(["report", str(db), "--out", str(tmp_path / "report")]) == 0
    page = (tmp_path / "report" / "index.html").read_text(encoding="utf-8")
    assert all(h in page for h in ids)


def test_a_group_plant_draws_each_heliostat_truth_from_its_row_of_the_whole_field():
    """What a group's task builds (the field file, whole) against the unsplit plant: row for row."""
    from helicalib.sim.plant import SimulatedPlant

    cfg = load_field_config(BENCH500)
    scenario = Scenario().model_copy(update={"seed": 7})
    whole = SimulatedPlant(cfg, scenario, start_s=1.79e9)
    group = plan_groups(cfg, 2)[1]
    part = SimulatedPlant(load_field_config(BENCH500), scenario, start_s=1.79e9)
    rows = [cfg.heliostat_index(h) for h in group.heliostats]
    assert rows[0] > 0  # a later group: a renumbered plant would start its rows at 0
    np.testing.assert_array_equal(part.truth.params0[rows], whole.truth.params0[rows])
    np.testing.assert_array_equal(part.truth.backlash_mm[rows], whole.truth.backlash_mm[rows])
    np.testing.assert_array_equal(part.truth.sag_mrad[rows], whole.truth.sag_mrad[rows])
    # and not the truth a plant of the group's heliostats alone, renumbered from 0, would draw
    assert not np.array_equal(whole.truth.params0[rows], whole.truth.params0[: len(rows)])


def failing_second_group(field_path, group, options, out_dir):
    """Group 2's worker loses its disk; the others run as usual."""
    if group.index == 2:
        raise OSError(f"[Errno 28] No space left on device: '{out_dir}/helicalib.db'")
    return run_group(field_path, group, options, out_dir)


def test_a_failed_group_is_reported_with_its_reason_and_the_others_merge(tmp_path, cluster):
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    cfg = load_field_config(DEMO_FIELD)
    ids = _chosen(cfg)
    start_s = float(to_unix_seconds([parse_time(START)])[0])
    options = SimulationOptions(DAYS, seed=1, start_s=start_s, fidelity="fast", heliostat_ids=ids)
    result = simulate_split(cfg, str(DEMO_FIELD), tmp_path, options, cluster, 2, task=failing_second_group)
    assert list(result.failures) == [2]
    assert result.failures[2].startswith("group 2 (boards T2): OSError: [Errno 28] No space left on device")
    assert result.summary["split"]["failed"] == [{"group": 2, "reason": result.failures[2]}]
    assert result.summary["split"]["missing_heliostats"] == PER_BOARD
    assert "No space left" in (tmp_path / "failed_groups.log").read_text(encoding="utf-8")
    db = result.database
    assert _rows(db, "SELECT status FROM campaigns") == [("stopped",)]
    # group 1's records are all there; group 2's heliostats are in the campaign, unvisited
    assert {t for (t,) in _rows(db, "SELECT DISTINCT target_id FROM visits")} == {"T1"}
    assert _rows(db, "SELECT count(*) FROM heliostats")[0][0] == len(ids)
    assert result.summary["heliostats"] == len(ids)
    assert _rows(db, "SELECT count(*) FROM observations")[0][0] == \
        _rows(tmp_path / "groups" / "g1" / "helicalib.db", "SELECT count(*) FROM observations")[0][0] > 0


def _frame(value: int) -> np.ndarray:
    return np.full((8, 8), value, dtype=np.uint8)


def test_merge_interleaves_by_time_renumbers_ids_and_moves_frames(tmp_path):
    from helicalib.store.records import Observation

    def source(name: str, hid: str, target: str, t0: float, value: int):
        with Store.open(tmp_path / name / "helicalib.db", owner="test") as s:
            cid = s.start_campaign(name="g", mode="simulate", started_s=0.0, heliostats=[(hid, 0, target)])
            for k in range(2):
                vid = s.begin_visit(cid, hid, target, t0 + 100.0 * k)
                obs = Observation(campaign_id=cid, heliostat_id=hid, target_id=target, visit_id=vid, iteration=0,
                                  capture_time_s=t0 + 100.0 * k + 1, strokes_cmd_mm=(300.0, 310.0),
                                  strokes_read_mm=(300.0, 310.0), sun_enu=(0.0, 0.6, 0.8), sun_azimuth_deg=180.0,
                                  sun_elevation_deg=53.0, valid=True, reason="ok", message="")
                s.record_observation(obs, before_frame=_frame(value + k), after_frames=[_frame(value + k + 10)])
                s.end_visit(vid, ended_s=t0 + 100.0 * k + 50, outcome="converged")
                s.record_event(campaign_id=cid, time_s=t0 + 100.0 * k, kind="check", heliostat_id=hid,
                               reason=f"{hid}: visit {vid} is a check", data={"visit_id": vid, "after_frames": 10})
            s.record_event(campaign_id=cid, time_s=5.0, kind="stow", reason="wind 16 m/s")
            s.finish_campaign(cid, 1000.0)
        return tmp_path / name / "helicalib.db"

    a = source("a", "H1", "T1", 10.0, 1)
    b = source("b", "H2", "T2", 60.0, 50)
    dest = tmp_path / "out" / "helicalib.db"
    result = merge_campaigns([a, b], dest, name="m", mode="simulate", started_s=0.0, ended_s=1000.0,
                             heliostats=[("H1", 0, "T1"), ("H2", 1, "T2")], settings={"split": {"groups": 2}})
    assert result.rows["visits"] == 4 and result.rows["observations"] == 4
    assert result.duplicate_events == 1  # the field-wide stow both sources recorded alike, kept once
    with Store.open(dest, readonly=True) as s:
        visits = s.visits(campaign_id=result.campaign_id)
        assert [(v.heliostat_id, v.started_s) for v in visits] == [("H1", 10.0), ("H2", 60.0), ("H1", 110.0),
                                                                    ("H2", 160.0)]
        observations = s.observations(campaign_id=result.campaign_id)
        assert [o.visit_id for o in observations] == [v.id for v in visits]
        images = s.campaign_images_dir(result.campaign_id)
        for o, value in zip(observations, (1, 50, 2, 51)):
            assert o.before_frame_path == f"c{result.campaign_id}/{o.heliostat_id}/v{o.visit_id}_i0_before.png"
            from PIL import Image

            assert np.asarray(Image.open(images / o.before_frame_path)).max() == value
            assert (images / o.after_frame_paths[0]).is_file()
        events = s.events(campaign_id=result.campaign_id)
        assert len([e for e in events if e.kind == "stow"]) == 1
        checks = [e for e in events if e.kind == "check"]  # a check's visit is the merged visit
        assert [(e.heliostat_id, e.data["visit_id"]) for e in checks] == [(v.heliostat_id, v.id) for v in visits]
        assert s.campaign(result.campaign_id).settings["split"] == {"groups": 2}


def test_split_options_that_cannot_work_are_refused_in_one_line(tmp_path, capsys):
    base = ["simulate", str(DEMO_FIELD), "--days", "0.1", "--out", str(tmp_path / "o")]
    assert main([*base, "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]) == 1
    assert "--workers sizes an embedded cluster" in capsys.readouterr().err
    assert main([*base, "--groups", "2"]) == 1
    assert "add --workers N or --scheduler ADDR" in capsys.readouterr().err
    assert main([*base, "--workers", "2", "--over-network"]) == 1
    assert "cannot be split" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
