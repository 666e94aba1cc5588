"""A plant clock that jumps: refused on resume (one line naming both times) unless the crew says
``--accept-clock-jump``; during a run one line, the run stops and every beam goes back to tracking.

The simulated plant is served on loopback (Modbus TCP + HTTP); the real clients, the plant clock
and the CLI run against it, on a real SQLite file.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import yaml

from test_live_faults import served  # noqa: F401 - a fixture
from helicalib.app import live
from helicalib.cli import main
from helicalib.config import load_field_config
from helicalib.devices.registers import HeliostatState
from helicalib.app.simulated import default_start_s
from helicalib.store.sqlite import Store


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def test_a_clock_that_jumps_back_during_a_run_is_one_line_and_the_beams_go_back(cfg, tmp_path, served):
    from helicalib.campaign.loop import CampaignRunner

    plant, cameras, clock, sim, _server = served
    ids = ["H0001", "H0021"]
    store = Store.open(tmp_path / "c.db", tmp_path / "img")
    cid = store.start_campaign(name="t", mode="live", started_s=clock.now_s(),
                               heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in ids])
    runner = CampaignRunner(cfg, plant, cameras, clock, store, cid, heliostat_ids=ids)
    lines, state = [], {}
    runner.journal.listeners.append(lines.append)
    real_time = plant.plant_time
    sent = _record_commands(plant, clock)

    def watch():
        while not runner.state.active:
            time.sleep(0.05)
        time.sleep(0.3)
        # the plant restarted at an earlier date: its time now reads a day back
        state["on_board"] = {hid: v.target_id for hid, v in list(runner.state.active.items())}
        state["n"] = len(sent)
        plant.plant_time = lambda: (real_time()[0] - 86400.0, real_time()[1])
        clock.resync_s = 0.0
        state["t"] = time.monotonic()
        stop.wait(30.0)  # (a run that never notices would otherwise go on for a plant day)
        stop.set()

    stop = threading.Event()
    threading.Thread(target=watch, daemon=True).start()
    t0 = time.monotonic()
    result = live.run_live(runner, clock.now_s() + 86400.0, stop_event=stop)
    stop.set()
    took = time.monotonic() - state.get("t", t0)
    events = store.events(campaign_id=cid)
    visits = store.visits(campaign_id=cid)
    store.close()
    assert result.reason == "clock_jump" and took < 20.0, (result, took)
    said = [e for e in lines if "went backwards" in e.reason and e.kind != "visit_end"]
    assert len(said) == 1, [e.reason for e in said]  # one line, not one per tick (736 in 45 s)
    # beside it, at most the end of each visit the jump cut short
    assert len([e for e in lines if "went backwards" in e.reason]) <= 1 + len(ids)
    assert "--accept-clock-jump" in said[0].reason
    assert [e.kind for e in events if "went backwards" in e.reason] == ["fault"]
    assert visits and all(v.outcome != "running" for v in visits)
    for hid in ids:  # every beam left its board and the plant tracks again
        assert sim.state[cfg.heliostat_index(hid)] in (HeliostatState.TRACKING, HeliostatState.MOVING), hid
    # ... via its standby point: the last move before its track command aims at the standby point
    assert state["on_board"]
    for hid, tid in state["on_board"].items():
        _assert_left_via_standby(runner, cfg, hid, tid, sent[state["n"]:])


def _record_commands(plant, clock):
    """Every move and track command sent to ``plant``: (kind, index, strokes, controller's plant time)."""
    sent = []
    move_to, track = plant.move_to, plant.track

    def recording_move(index, strokes_mm):
        sent.append(("move", index, np.asarray(strokes_mm, dtype=float), clock.estimate_s()))
        return move_to(index, strokes_mm)

    def recording_track(index, corrections_mm):
        sent.append(("track", index, None, clock.estimate_s()))
        return track(index, corrections_mm)

    plant.move_to, plant.track = recording_move, recording_track
    return sent


def _assert_left_via_standby(runner, cfg, hid, target_id, sent):
    """``hid``'s first track command in ``sent`` follows a move to its standby point on ``target_id``
    (never a track command from the board)."""
    index = cfg.heliostat_index(hid)
    mine = [c for c in sent if c[1] == index]
    k = next(i for i, c in enumerate(mine) if c[0] == "track")
    assert k > 0 and mine[k - 1][0] == "move", (hid, [c[0] for c in mine])
    _kind, _i, strokes, t = mine[k - 1]
    target = cfg.target(target_id)
    standby = target.uvw_to_enu(np.asarray(target.standby_uvw_m))
    sun = runner.sun(t)[0]
    at_standby = runner.state.models[hid].strokes_for_aim(sun, standby).strokes_mm[0]
    at_centre = runner.state.models[hid].strokes_for_aim(sun, np.asarray(target.center_enu_m)).strokes_mm[0]
    off = float(np.max(np.abs(strokes - at_standby)))
    assert off < 0.2 * float(np.max(np.abs(at_centre - at_standby))), (hid, strokes, at_standby, at_centre)


def test_a_clock_step_back_within_the_tolerance_is_absorbed():
    from helicalib.devices.clock import STEP_BACK_TOLERANCE_S, PlantClock

    class Plant:
        t = 1000.0

        def plant_time(self):
            return self.t, 1.0

    real = [0.0]
    plant = Plant()
    clock = PlantClock(plant, resync_s=1.0, source=lambda: real[0], sleeper=lambda s: None)
    assert clock.now_s() == 1000.0
    plant.t, real[0] = 1005.0 - STEP_BACK_TOLERANCE_S / 2, 5.0  # a time server stepped the plant's clock back
    assert clock.now_s() == 1000.0  # held (never decreasing) until the plant's time catches up: no error
    plant.t, real[0] = 1100.0, 100.0
    assert clock.now_s() == 1100.0


# ---------------------------------------------------------------------------------------------------------
# resuming on a plant clock that jumped

def served_field(tmp_path, cfg, demo_data, hours: float = 9.0):
    """A field config served by the simulated plant on loopback (200x, from ``hours`` after local
    midnight), storage in tmp_path; yields (field path, plant time at the start, simulated plant)."""
    from helicalib.sim.clock import RateClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario
    from helicalib.sim.server import PlantServer

    start = default_start_s(cfg) + hours * 3600
    sim = SimulatedPlant(cfg, Scenario(seed=3), start_s=start, rate=200.0)
    server = PlantServer(sim, RateClock(start, 200.0, time.monotonic, time.sleep), modbus_port=0, camera_port=0)
    with server:
        demo_data["plant"]["scs"]["port"] = server.modbus_port
        for cam in demo_data["cameras"]:
            cam["url"] = server.camera_url(cam["id"])
        demo_data["storage"] = {"database": "sqlite:///c.db", "images_dir": "img"}
        path = tmp_path / "field.yaml"
        path.write_text(yaml.safe_dump(demo_data, sort_keys=False))
        yield path, start, sim


@pytest.fixture()
def field(tmp_path, cfg, demo_data):
    """:func:`served_field` in daylight."""
    yield from served_field(tmp_path, cfg, demo_data)


def _campaign_last_at(db, t_s: float) -> None:
    store = Store.open(db, db.parent / "img")
    cid = store.start_campaign(name="live", mode="live", started_s=t_s - 3600.0, settings={"armed": True},
                               heliostats=[("H0001", 0, "T2")])
    store.record_event(campaign_id=cid, time_s=t_s, kind="note", reason="the campaign's last record")
    store.finish_campaign(cid, t_s, status="stopped")
    store.close()


@pytest.mark.parametrize("offset_days, words", [(1.0, "lies before"), (-30.0, "days after")],
                         ids=["plant-behind", "plant-far-ahead"])
def test_a_resume_on_a_plant_clock_that_jumped_is_refused_in_one_line(field, capsys, offset_days, words):
    from helicalib.campaign.events import iso_utc

    path, start, _sim = field
    db = path.parent / "c.db"
    last = start + offset_days * 86400.0
    _campaign_last_at(db, last)
    argv = ["run", str(path), "--arm", "--heliostats", "H0001", "--days", "0.001"]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refusing to resume" in err[0] and words in err[0], err
    assert iso_utc(last) in err[0] and iso_utc(start)[:13] in err[0]  # both times named
    assert "--accept-clock-jump" in err[0]
    store = Store.open(db, readonly=True)
    assert [c.status for c in store.campaigns()] == ["stopped"]  # untouched
    store.close()
    # the crew's explicit choice: resumed from the plant's time, and the first line says so
    assert main([*argv, "--accept-clock-jump"]) == 0
    out = capsys.readouterr()
    assert "--accept-clock-jump" in out.out + out.err
    store = Store.open(db, readonly=True)
    first = store.events(campaign_id=1, kind="campaign")[-1].reason
    store.close()
    assert "resumed" in first and "--accept-clock-jump" in first


def test_a_resume_on_a_consistent_clock_goes_on(field, capsys):
    path, start, _sim = field
    db = path.parent / "c.db"
    _campaign_last_at(db, start - 1800.0)
    assert main(["run", str(path), "--arm", "--heliostats", "H0001", "--days", "0.001"]) == 0
    assert "refusing" not in capsys.readouterr().err
