"""Operator actions (campaign/operation/crew.py) on a real runner, and the console's address rules.

In-process simulated plant on a virtual clock with the fast spot sensor (no frames: these tests
are about who goes on a board, not about the vision), a real SQLite file. Requests are written to
the store's ``operator_actions`` table as the console writes them; the runner's tick applies them.
"""

from __future__ import annotations

import sqlite3
import subprocess
import sys

import pytest

from campaign_helpers import inprocess_campaign
from helicalib.campaign.operation.crew import OperatorDesk, check_request
from helicalib.store.history import replay
from helicalib.config import load_field_config
from helicalib.console.server import parse_address
from helicalib.errors import ConfigError
from helicalib.store.sqlite import Store

IDS = ["H0001", "H0002", "H0003", "H0021", "H0022", "H0023"]


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def _fast(cam, sim, target):
    from helicalib.sim.fast_sensor import fast_sensors

    return fast_sensors(sim, seed=1)[target.id]


def _runner(cfg, tmp_path, **kw):
    runner, sim, store, cid, _c = inprocess_campaign(cfg, tmp_path, 9, 3, IDS, camera=_fast, **kw)
    runner.state.operator = OperatorDesk(store, cid)
    runner.state.operator.restore(runner)
    return runner, sim, store, cid


def _ask(runner, kind, ids=(), who="crew lead (127.0.0.1)"):
    return runner.devices.store.request_action(campaign_id=runner.campaign_id, kind=kind, heliostat_ids=ids, who=who,
                                               requested_wall_s=0.0, requested_s=runner.devices.clock.now_s())


def _visits_since(store, cid, t):
    return [v for v in store.visits(campaign_id=cid) if v.started_s >= t]


def test_pause_stops_new_visits_until_resume_and_each_is_logged(cfg, tmp_path):
    runner, sim, store, cid = _runner(cfg, tmp_path)
    runner.run_until(sim.t_s + 600)
    assert store.visits(campaign_id=cid)  # calibrating
    _ask(runner, "pause")
    t_pause = sim.t_s
    runner.run_until(sim.t_s + 1800)
    paused = _visits_since(store, cid, t_pause + 1e-6)
    assert paused == [], [(v.heliostat_id, v.started_s) for v in paused]
    assert not runner.state.active  # the visits under way ended as usual
    _ask(runner, "resume", who="night shift (10.0.0.7)")
    t_resume = sim.t_s
    runner.run_until(sim.t_s + 900)
    assert _visits_since(store, cid, t_resume)
    ops = store.events(campaign_id=cid, kind="operator")
    assert [e.data["kind"] for e in ops] == ["pause", "resume"]
    assert "asked by crew lead (127.0.0.1)" in ops[0].reason and "night shift" in ops[1].reason
    assert all(a.done_s is not None and a.outcome for a in store.actions(cid))
    store.close()


def test_out_of_service_is_never_planned_and_lasts_across_a_restart(cfg, tmp_path):
    runner, sim, store, cid = _runner(cfg, tmp_path)
    _ask(runner, "out_of_service", ["H0002", "H0022"])
    t0 = sim.t_s
    runner.run_until(sim.t_s + 3 * 3600)
    visited = {v.heliostat_id for v in _visits_since(store, cid, t0)}
    assert visited and not visited & {"H0002", "H0022"}, visited
    assert {"H0001", "H0003", "H0021", "H0023"} <= visited  # the others still go
    store.close()
    # a restart of the controller: the standing actions are re-applied from the store
    runner, sim, store, cid = _runner(cfg, tmp_path, campaign_id=cid)
    assert runner.state.operator.standing.out_of_service == {"H0002", "H0022"}
    _ask(runner, "in_service", ["H0022"])
    t1 = sim.t_s
    runner.run_until(sim.t_s + 3 * 3600)
    visited = {v.heliostat_id for v in _visits_since(store, cid, t1)}
    assert "H0022" in visited and "H0002" not in visited
    store.close()


def test_a_recheck_goes_next_on_its_board(cfg, tmp_path):
    runner, sim, store, cid = _runner(cfg, tmp_path)
    runner.run_until(sim.t_s + 2 * 3600)  # everyone visited, in cool-down or accepted
    target = cfg.heliostat("H0003").target
    _ask(runner, "recheck", ["H0003"])
    t0 = sim.t_s
    runner.run_until(sim.t_s + 1800)
    on_board = [v for v in _visits_since(store, cid, t0) if v.target_id == target]
    assert on_board and on_board[0].heliostat_id == "H0003", [(v.heliostat_id, v.started_s) for v in on_board]
    (action,) = store.actions(cid)
    assert action.outcome == f"visit started: H0003 onto {target}"
    reasons = [e.reason for e in store.events(campaign_id=cid, kind="operator")]
    assert any("re-check of H0003 queued" in r for r in reasons)
    assert any(r.startswith("re-check of H0003") and f"onto {target} now" in r for r in reasons)
    store.close()


def test_repaired_resets_the_model_and_its_points_stay_dropped_after_a_restart(cfg, tmp_path):
    runner, sim, store, cid = _runner(cfg, tmp_path)
    runner.run_until(sim.t_s + 2 * 3600)
    assert runner.state.book.points("H0021")
    assert not runner.state.models["H0021"].params.tolist() == runner.state.nominal_of("H0021").params.tolist()
    _ask(runner, "repaired", ["H0021"])
    while "H0021" in runner.state.active:
        runner.run_until(sim.t_s + 60)  # a repair waits for a visit under way to end
    runner.tick(sim.t_s)
    t_fix = store.actions(cid)[0].done_s
    assert t_fix is not None and runner.state.book.points("H0021") == []
    assert runner.state.models["H0021"].params.tolist() == runner.state.nominal_of("H0021").params.tolist()
    verdict = store.latest_verdicts(cid)["H0021"]
    assert not verdict.accepted and verdict.n_points == 0 and "repaired" in verdict.reasons[0]
    runner.run_until(sim.t_s + 1800)
    after = [p.capture_time_s for p in runner.state.book.points("H0021")]
    store.close()
    runner, sim, store, cid = _runner(cfg, tmp_path, campaign_id=cid)
    kept = [p.capture_time_s for p in runner.state.book.points("H0021")]
    assert kept == after and all(t > t_fix for t in kept)  # the points before the repair no longer count
    assert replay(store.actions(cid)).repaired_s == {"H0021": t_fix}
    store.close()


@pytest.mark.parametrize("kind, ids, who, message", [
    ("launch", [], "a", "action 'launch': unknown"),
    ("recheck", [], "a", "action recheck: no heliostat named"),
    ("pause", ["H0001"], "a", "action pause: takes no heliostat"),
    ("recheck", ["H9999"], "a", "action recheck: heliostat 'H9999' is not in this campaign"),
    ("recheck", ["H0001"], "  ", "'who' is empty"),
])
def test_bad_requests_are_refused_with_one_line(kind, ids, who, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        check_request(kind, ids, {"H0001"}, who)


@pytest.mark.parametrize("text, public, expected", [
    ("8765", False, ("127.0.0.1", 8765)), ("127.0.0.1:0", False, ("127.0.0.1", 0)),
    ("[::1]:9000", False, ("::1", 9000)), ("0.0.0.0:8765", True, ("0.0.0.0", 8765)),
])
def test_console_addresses(text, public, expected):
    assert parse_address(text, public) == expected


@pytest.mark.parametrize("text, message", [
    ("0.0.0.0:8765", "listening beyond loopback needs --console-public"),
    ("192.168.1.5:80", "listening beyond loopback needs --console-public"),
    ("host:http", "expected \\[HOST:\\]PORT"), ("70000", "port 70000 is not in 0..65535"),
])
def test_console_addresses_refused(text, message):
    with pytest.raises(ConfigError, match=message):
        parse_address(text, public=False)


def test_run_refuses_a_public_console_before_touching_the_plant(demo_field_path, tmp_path):
    r = subprocess.run([sys.executable, "-m", "helicalib", "run", str(demo_field_path), "--console", "0.0.0.0:8765"],
                       capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].endswith(
        "--console '0.0.0.0:8765': listening beyond loopback needs --console-public (every request then needs the "
        "token printed at start)")


def test_a_version_2_database_gets_the_actions_table(tmp_path):
    path = tmp_path / "old.db"
    Store.open(path).close()
    conn = sqlite3.connect(path)
    conn.execute("DROP TABLE operator_actions")
    conn.execute("ALTER TABLE observations DROP COLUMN exposure_ms")  # as version 2 wrote it
    conn.execute("UPDATE schema_version SET version = 2")
    conn.commit()
    conn.close()
    with pytest.raises(ConfigError, match="a reader does not"):
        Store.open(path, readonly=True)  # a reader never migrates
    s = Store.open(path)
    cid = s.start_campaign(name="c", mode="live", started_s=1.0, heliostats=[("H0001", 0, "T1")])
    a = s.request_action(campaign_id=cid, kind="pause", who="x", requested_wall_s=2.0, requested_s=None)
    assert [(x.id, x.kind, x.done_s) for x in s.actions(cid, pending=True)] == [(a, "pause", None)]
    s.finish_action(a, done_s=3.0, outcome="paused")
    assert s.actions(cid, pending=True) == [] and s.actions(cid)[0].outcome == "paused"
    s.close()


def test_a_restart_requeues_only_the_rechecks_not_started_and_none_out_of_service(cfg, tmp_path):
    runner, sim, store, cid = _runner(cfg, tmp_path, spots_per_board=1)
    runner.run_until(sim.t_s + 2 * 3600)  # everyone visited, in cool-down or accepted
    asked = ["H0001", "H0002", "H0003"]  # one board (T2): they go one after another
    _ask(runner, "recheck", asked)
    started = []
    for _ in range(600):  # until the first of them is on the board
        runner.run_until(sim.t_s + 1)
        started = [e.heliostat_id for e in store.events(campaign_id=cid, kind="operator")
                   if e.reason.startswith("re-check of") and e.reason.endswith(" now")]
        if started:
            break
    assert len(started) == 1, started
    waiting = [h for h in asked if h not in started]
    _ask(runner, "out_of_service", [waiting[1]])
    runner.run_until(sim.t_s + 10)
    assert [h for h, _a in runner.state.operator.queue] == [waiting[0]]
    store.close()
    # a restart: the re-check that started is not repeated, the one out of service is not sent
    runner, sim, store, cid = _runner(cfg, tmp_path, campaign_id=cid)
    assert [h for h, _a in runner.state.operator.queue] == [waiting[0]]
    store.close()


def test_in_operation_a_crews_recheck_goes_before_the_services_own_checks(cfg, tmp_path):
    """``helicalib operate``'s runner: once the field is accepted the boards take checks of the
    service's choosing; a crew's re-check still goes next on its board, before any of them."""
    runner, sim, store, cid = _runner(cfg, tmp_path, operation="ranked")
    end = sim.t_s + 3 * 86400
    while sim.t_s < end and not runner.ops.checks:  # until the service has started checking accepted heliostats
        runner.run_until(sim.t_s + 1800)
    assert runner.ops.checks, "no operation check in three plant days"
    target = cfg.heliostat("H0023").target
    while any(v.target_id == target for v in runner.state.active.values()):  # the board free, so the next visit on it is a new choice
        runner.run_until(sim.t_s + 60)
    runner.state.book.h["H0023"].cooldown_until_s = 0.0
    _ask(runner, "recheck", ["H0023"])
    t0 = sim.t_s
    runner.run_until(sim.t_s + 1800)
    on_board = [v for v in _visits_since(store, cid, t0) if v.target_id == target]
    assert on_board and on_board[0].heliostat_id == "H0023", [(v.heliostat_id, v.started_s) for v in on_board]
    visits = [e for e in store.events(campaign_id=cid, kind="operator") if "H0023" in e.reason]
    assert any("onto" in e.reason for e in visits)
    store.close()
