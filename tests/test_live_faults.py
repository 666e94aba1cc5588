"""Faults found when the controller was attacked, each reproduced on real components.

In-process plant (virtual clock, real frames, real SQLite file) with one fault injected at the
device boundary, or the simulated plant served over loopback Modbus TCP for the live jobs:

* a camera whose clock is off (1 h behind; a capture time of 1e300);
* readers (``status``) on a database with frames in flight;
* frames orphaned by a visit killed after its before frame;
* a plant blackout mid-visit and a plant that refuses the return to tracking;
* a plant that stops answering under the live jobs, and a stop while it is down.
"""

from __future__ import annotations

import dataclasses
import hashlib
import threading
import time

import pytest

from campaign_helpers import inprocess_campaign
from helicalib.app import live
from helicalib.campaign.state import Returning
from helicalib.cli import main
from helicalib.config import load_field_config
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.devices.registers import HeliostatState
from helicalib.errors import PlantError
from helicalib.store.sqlite import Store


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


class _Skewed:
    """A camera whose capture time is ``offset_s`` off the plant clock (or always ``value``)."""

    def __init__(self, inner, offset_s=0.0, value=None):
        self.inner, self.offset_s, self.value = inner, offset_s, value

    def __getattr__(self, name):  # the simulated camera's flux factor and atmosphere
        return getattr(self.inner, name)

    def grab(self):
        f = self.inner.grab()
        t = f.capture_time_s + self.offset_s if self.value is None else self.value
        return dataclasses.replace(f, capture_time_s=t)


@pytest.mark.parametrize("skew", [{"offset_s": -3600.0}, {"value": 1e300}])
def test_frames_whose_capture_time_is_off_the_plant_clock_are_refused(cfg, tmp_path, skew):
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0001", "H0021"],
                                                        camera=lambda cam, _s, _t: _Skewed(cam, **skew))
    runner.run_until(sim.t_s + 3 * 3600)
    obs = store.observations(campaign_id=cid)
    visits = store.visits(campaign_id=cid)
    fits = store.fits(campaign_id=cid)
    written = store.events(campaign_id=cid, kind="tracking_written")
    frames = [p for p in (tmp_path / "img").rglob("*.png")]
    store.close()
    # several visits on both boards: the campaign went on, each measurement refused with the reason
    assert len(visits) >= 4, [v.outcome for v in visits]
    assert obs and all(not o.valid and o.reason == "capture_time" for o in obs), {o.reason for o in obs}
    assert "camera's clock" in obs[0].message
    # nothing was learnt from them, nothing sent to the plant's tracking
    assert not fits and not written
    # the frames are kept (each visit's before frame, the refused after frames), named without the camera's numbers
    assert frames and max(len(p.name) for p in frames) < 40
    assert not any("1000000" in str(p) or "e+" in str(p) for p in frames)


def test_a_camera_a_second_off_is_within_the_tolerance(cfg, tmp_path):
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0001"],
                                                        camera=lambda cam, _s, _t: _Skewed(cam, offset_s=-1.0))
    runner.run_until(sim.t_s + 1800)
    obs = store.observations(campaign_id=cid)
    store.close()
    assert any(o.valid for o in obs) and not any(o.reason == "capture_time" for o in obs)


def _tree(folder):
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_status_never_deletes_or_writes_anything(tmp_path, capsys):
    db = tmp_path / "campaign.db"
    store = Store.open(db, tmp_path / "images")
    store.start_campaign(name="t", mode="live", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    store.close()
    inflight = tmp_path / "images" / "c1" / "H0001" / ".v1_i0_after0.png.4242.tmp"
    inflight.parent.mkdir(parents=True)
    inflight.write_bytes(b"half a frame")
    before = _tree(tmp_path)
    for argv in (["status", str(db)], ["status", str(db), "--json"]):
        assert main(argv) == 0
    assert _tree(tmp_path) == before  # the frame in flight is still there, the database untouched
    assert "interrupted" in capsys.readouterr().out  # 'running' with no process on it


def test_report_on_a_running_campaign_leaves_its_frames_alone(cfg, tmp_path):
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path / "run", 9, 3, ["H0001"])
    runner.run_until(sim.t_s + 900)
    store.take_ownership("test campaign")  # as run/simulate hold it while they run
    inflight = store.images_dir / f"c{cid}" / "H0001" / ".v9_i0_after0.png.4242.tmp"
    inflight.write_bytes(b"half a frame")
    before = _tree(tmp_path / "run")
    try:
        assert main(["report", str(store.path), "--out", str(tmp_path / "report")]) == 0
        after = _tree(tmp_path / "run")  # while the campaign still holds its database
    finally:
        store.close()
    assert inflight.exists()
    # every file as it was (SQLite's shared-memory index, c.db-shm, is where WAL readers mark their reads)
    assert {k: v for k, v in after.items() if k != "c.db-shm"} == {k: v for k, v in before.items() if k != "c.db-shm"}
    assert (tmp_path / "report" / "index.html").is_file()


def test_status_on_an_empty_file_says_so_and_leaves_it_empty(tmp_path, capsys):
    empty = tmp_path / "empty.db"
    empty.write_bytes(b"")
    assert main(["status", str(empty)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "empty.db" in err and "empty database" in err
    assert empty.stat().st_size == 0 and sorted(p.name for p in tmp_path.iterdir()) == ["empty.db"]


def test_the_owner_removes_frames_no_observation_points_to(cfg, tmp_path):
    from helicalib.store.records import Observation

    db = tmp_path / "c.db"
    store = Store.open(db, "images")
    cid = store.start_campaign(name="t", mode="live", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    png = (tmp_path / "frame.png")
    import cv2
    import numpy as np

    cv2.imwrite(str(png), np.zeros((8, 8), np.uint8))
    data = png.read_bytes()
    v1 = store.begin_visit(cid, "H0001", "T1", 0.0)
    kept = store.save_frame(data, campaign_id=cid, heliostat_id="H0001", visit_id=v1, iteration=0,
                            capture_time_s=0.0, kind="before")
    store.record_observation(Observation(campaign_id=cid, heliostat_id="H0001", target_id="T1", visit_id=v1,
                                         iteration=0, capture_time_s=1.0, strokes_cmd_mm=(1.0, 1.0),
                                         strokes_read_mm=None, sun_enu=(0.0, 0.0, 1.0), sun_azimuth_deg=0.0,
                                         sun_elevation_deg=90.0, sun_rising=True, valid=False, reason="no_spot",
                                         message="", before_frame_path=kept), after_frames=[data])
    # a visit killed after its before frame, before its first observation
    v2 = store.begin_visit(cid, "H0001", "T1", 10.0)
    orphan = store.save_frame(data, campaign_id=cid, heliostat_id="H0001", visit_id=v2, iteration=0,
                              capture_time_s=10.0, kind="before")
    # a visit that ended in a fault after its before frame: its frame is evidence, never an orphan
    v3 = store.begin_visit(cid, "H0001", "T1", 5.0)
    failed = store.save_frame(data, campaign_id=cid, heliostat_id="H0001", visit_id=v3, iteration=0,
                              capture_time_s=5.0, kind="before")
    store.end_visit(v3, ended_s=6.0, outcome="fault", reason="plant_error")
    store.close()
    owner = Store.open(db, "images")
    owner.take_ownership("test")
    # while it owns the database, no second campaign process may open it; a reader sees who holds it
    with pytest.raises(Exception, match="in use by helicalib"):
        Store.open(db, "images").take_ownership("another")
    reader = Store.open(db, readonly=True)
    assert "test" in (reader.owner() or "")
    reader.close()
    owner.close_interrupted_visits(cid, 20.0)
    assert owner.remove_orphan_frames(cid) == 1
    owner.close()
    assert not (tmp_path / "images" / orphan).exists()
    assert (tmp_path / "images" / kept).exists() and (tmp_path / "images" / failed).exists()
    assert len(list((tmp_path / "images").rglob("*.png"))) == 3  # kept before + its after frame, the fault's


def test_a_failed_visits_record_points_to_its_before_frame(cfg, tmp_path):
    proxy = {}
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0001"],
                                                        plant=lambda s: proxy.setdefault("p", _Outage(s)))
    while not list((tmp_path / "img").rglob("*_before.png")):  # the visit's before frame is saved ...
        runner.run_until(sim.t_s + 1.0)
    proxy["p"].t0, proxy["p"].t1 = sim.t_s, sim.t_s + 25.0  # ... then the plant stops answering
    runner.run_until(sim.t_s + 300.0)
    failure = next(o for o in store.observations(campaign_id=cid) if o.iteration == -1)
    store.close()
    assert failure.reason == "plant_error" and failure.before_frame_path
    assert (tmp_path / "img" / failure.before_frame_path).is_file()


class _Outage:
    """The in-process plant, but every call fails while plant time is in [t0, t1) (a blackout: no
    answer, as the Modbus client says it), and ``track`` is refused for the first ``refuse_track``
    calls (a plant that answers but does not take the return)."""

    def __init__(self, sim, refuse_track: int = 0):
        self.sim, self.t0, self.t1, self.refuse_track = sim, float("inf"), float("inf"), refuse_track

    def __getattr__(self, name):
        attr = getattr(self.sim, name)
        if not callable(attr):
            return attr

        def call(*args, **kw):
            if self.t0 <= self.sim.t_s < self.t1:
                raise PlantUnreachableError("plant 127.0.0.1:5020 unit 1: no answer (blackout)")
            if name == "track" and self.refuse_track > 0:
                self.refuse_track -= 1
                raise PlantError("plant 127.0.0.1:5020 unit 1: write of tracking corrections refused")
            return attr(*args, **kw)

        return call


def test_a_blackout_mid_visit_does_not_leave_a_heliostat_off_tracking(cfg, tmp_path):
    proxy = {}
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0001"],
                                                        plant=lambda s: proxy.setdefault("p", _Outage(s)))
    outage, idx = proxy["p"], cfg.heliostat_index("H0001")
    end = sim.t_s + 3600
    while not runner.state.active and sim.t_s < end:  # until the first visit (no fitted model yet) is under way
        runner.run_until(sim.t_s + 2.0)
    runner.run_until(sim.t_s + 30.0)
    assert runner.state.active and sim.state[idx] in (HeliostatState.HOLDING, HeliostatState.MOVING)
    outage.t0, outage.t1 = sim.t_s, sim.t_s + 25.0  # 25 s with no answer, mid-visit
    runner.run_until(outage.t1 + 600.0)
    events = store.events(campaign_id=cid)
    store.close()
    assert sim.state[idx] == HeliostatState.TRACKING
    kinds = [e.kind for e in events if e.heliostat_id == "H0001"]
    assert "off_tracking" in kinds and "back_to_tracking" in kinds[kinds.index("off_tracking"):]


class _Recorder:
    """The in-process plant, recording every track command it is sent."""

    def __init__(self, sim):
        self.sim, self.tracked = sim, []

    def __getattr__(self, name):
        return getattr(self.sim, name)

    def track(self, index, corrections_mm):
        self.tracked.append(index)
        return self.sim.track(index, corrections_mm)


def _stranded_db(tmp_path):
    """A database whose first campaign (a check) left H0001 in a visit (killed) and H0002 off
    tracking; returns that campaign's id."""
    store = Store.open(tmp_path / "c.db", tmp_path / "img")
    first = store.start_campaign(name="old", mode="check", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    store.begin_visit(first, "H0001", "T1", 0.0)
    store.record_event(campaign_id=first, time_s=1.0, kind="off_tracking", heliostat_id="H0002", reason="H0002: x")
    store.close()
    return first


@pytest.mark.parametrize("stowed", [False, True])
def test_a_restart_sends_back_what_any_campaign_left_off_tracking_but_never_into_a_stow(cfg, tmp_path, stowed):
    from campaign_helpers import inprocess_campaign as make

    first = _stranded_db(tmp_path)
    rec = {}

    def plant(sim):
        return rec.setdefault("p", _Recorder(sim))

    if stowed:  # the new campaign's own wind stow, recorded before a kill
        s = Store.open(tmp_path / "c.db", tmp_path / "img")
        s.start_campaign(name="new", mode="simulate", started_s=0.0, heliostats=[("H0003", 2, "T1")])
        s.record_event(campaign_id=2, time_s=2.0, kind="stow", reason="wind 16 m/s")
        s.close()
    runner, sim, store, cid, _ = make(cfg, tmp_path, 9, 3, ["H0003"], plant=plant, campaign_id=2 if stowed else None)
    visits = store.visits(campaign_id=first)
    store.close()
    assert [v.outcome for v in visits] == ["interrupted"]  # closed, although another campaign resumed
    idx = {cfg.heliostat_index("H0001"), cfg.heliostat_index("H0002")}
    if stowed:
        assert rec["p"].tracked == [] and set(runner.state.returning) == {"H0001", "H0002"}
    else:
        assert set(rec["p"].tracked) == idx


def test_corrections_are_recorded_only_once_the_plant_took_them(cfg, tmp_path):
    proxy = {}
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0001"],
                                                        plant=lambda s: proxy.setdefault("p", _Outage(s, 1)))
    runner.run_until(sim.t_s + 2 * 3600)
    events = store.events(campaign_id=cid)
    visits = store.visits(campaign_id=cid)
    store.close()
    first_end = visits[0].ended_s
    assert visits[0].outcome == "converged"
    # the first visit's track command was refused: no 'tracking_written' for it, an off_tracking fault instead
    at_first = [e for e in events if e.kind in ("tracking_written", "off_tracking") and e.time_s <= first_end + 5.0]
    assert [e.kind for e in at_first] == ["off_tracking"], [(e.kind, e.reason) for e in at_first]
    # the retry delivered the very corrections the plant refused, and only then were they recorded
    written = [e for e in events if e.kind == "tracking_written"]
    assert written and written[0].time_s > at_first[0].time_s
    assert any(e.kind == "back_to_tracking" for e in events)
    assert sim.state[cfg.heliostat_index("H0001")] == HeliostatState.TRACKING


@pytest.fixture()
def served(cfg):
    """The simulated plant on loopback Modbus TCP + HTTP, with the real clients and the plant clock."""
    from contextlib import ExitStack

    from helicalib.app.simulated import _network_plant, default_start_s
    from helicalib.sim.scenario import Scenario

    with ExitStack() as stack:
        yield _network_plant(cfg, Scenario(seed=3), default_start_s(cfg) + 9 * 3600, 200.0, stack)


def _network_runner(cfg, tmp_path, served, ids):
    from helicalib.campaign.loop import CampaignRunner

    plant, cameras, clock, _sim, _server = served
    store = Store.open(tmp_path / "c.db", tmp_path / "img")
    cid = store.start_campaign(name="t", mode="live", started_s=clock.now_s(),
                               heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in ids])
    return CampaignRunner(cfg, plant, cameras, clock, store, cid, heliostat_ids=ids), store, cid


def _kill_plant(served):
    """Stop serving: connections refused from now on (the process of the plant is gone)."""
    served[-1].stop()


def test_a_dead_plant_gives_one_fault_line_stamped_by_the_controller_clock(cfg, tmp_path, served, capsys):
    runner, store, cid = _network_runner(cfg, tmp_path, served, ["H0001"])
    plant, _c, clock, _s, _srv = served
    _kill_plant(served)
    clock.resync_s = 0.0  # every read of plant time asks the (dead) plant
    lock = threading.Lock()
    live._tick_job(runner, lock)  # before: the handler asked the dead plant for its clock and raised
    live._weather_job(runner, lock)
    faults = store.events(campaign_id=cid, kind="fault")
    store.close()
    assert [f.reason.split(":")[0] for f in faults] == ["tick", "weather"]
    assert all(f.data.get("clock") == "controller" for f in faults)
    assert "Traceback" not in capsys.readouterr().err


def test_a_stop_while_the_plant_is_down_ends_within_seconds(cfg, tmp_path, served):
    runner, store, cid = _network_runner(cfg, tmp_path, served, ["H0001", "H0021"])
    stop = threading.Event()
    state = {}

    def watch():
        while not runner.state.active:
            time.sleep(0.05)
        time.sleep(0.5)
        _kill_plant(served)
        state["t"] = time.monotonic()
        stop.set()

    threading.Thread(target=watch, daemon=True).start()
    result = live.run_live(runner, runner.devices.clock.now_s() + 86400.0, stop_event=stop)
    took = time.monotonic() - state["t"]
    events = store.events(campaign_id=cid)
    store.close()
    assert result.reason == "stopped"
    assert took < 20.0, took  # a stuck stop took 90 s
    # every heliostat on a board is named as left off tracking, recorded for the next run to retry
    on_board = {e.heliostat_id for e in events if e.kind == "off_tracking"}
    assert on_board and set(result.off_tracking) <= on_board


class _BrokenOutput:
    """A view whose every call fails, as output to a pipe whose reader died with the same Ctrl-C."""

    def __getattr__(self, name):
        def fail(*_a, **_k):
            raise BrokenPipeError(32, "Broken pipe")

        return fail


def test_a_view_that_fails_never_stops_the_beams_leaving(cfg, tmp_path, served):
    runner, store, cid = _network_runner(cfg, tmp_path, served, ["H0001", "H0021"])
    sim = served[3]
    stop = threading.Event()

    def watch():
        while not runner.state.active:
            time.sleep(0.05)
        time.sleep(0.5)
        stop.set()

    threading.Thread(target=watch, daemon=True).start()
    result = live.run_live(runner, runner.devices.clock.now_s() + 86400.0, stop_event=stop, output=_BrokenOutput())
    visits = store.visits(campaign_id=cid)
    store.close()
    assert result.reason == "stopped" and result.off_tracking == [] and not runner.state.active
    assert visits and all(v.outcome != "running" for v in visits)
    for hid in ("H0001", "H0021"):  # every beam left its board and the plant tracks again
        assert sim.state[cfg.heliostat_index(hid)] in (HeliostatState.TRACKING, HeliostatState.MOVING)


class _Faulted(_Recorder):
    """A plant that takes track commands for H0001 but leaves it in FAULT (a jammed actuator)."""

    def status(self, index):
        st = self.sim.status(index)
        return dataclasses.replace(st, state=HeliostatState.FAULT) if index == 0 else st


def test_a_heliostat_that_never_tracks_is_not_commanded_every_few_seconds(cfg, tmp_path):
    rec = {}
    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0002"],
                                                    plant=lambda s: rec.setdefault("p", _Faulted(s)))
    runner.tracking.send_back("H0001", None, sim.t_s, why="test")
    runner.run_until(sim.t_s + 3 * 3600)
    off = [e for e in store.events(campaign_id=cid, kind="off_tracking") if e.heliostat_id == "H0001"]
    store.close()
    sent = rec["p"].tracked.count(0)
    # 3 h with back-off 10 s, 30 s, 60 s, ... up to 10 min: about 20 commands, not ~1000; one event
    assert 5 <= sent <= 30, sent
    assert len(off) == 1 and "H0001" in runner.state.returning


def test_a_stowed_field_with_returns_pending_does_not_stall_the_clock(cfg, tmp_path):
    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0002"])
    runner.state.returning["H0001"] = Returning(since_s=sim.t_s, next_check_s=sim.t_s)
    runner.state.stowed = True
    ticks = []
    runner.run_until(sim.t_s + 600.0, progress=ticks.append)
    store.close()
    assert len(ticks) < 200  # ticks come at the weather and planner rhythm, not every millisecond
