"""A live reading's vision off the tick's thread (campaign/frames.py, campaign/sensor.py).

Against real HTTP cameras on loopback (test_live_frames's camera servers: real PNG frames after a
delay) and, end to end, the simulated plant served over loopback Modbus TCP + HTTP under
``run_live``: ``measure_spot`` is wrapped to record the thread it runs in (and, where said, to wait
for another board's or to fail). The spot of a reading's last after frame is measured on the
camera's thread; two boards' spots are measured at once; the tick steps another board while one
is measured; an error of the vision makes the visit's measurement invalid with its reason.
"""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from test_live_faults import served  # noqa: F401 - a fixture
from test_live_frames import cameras, drive, sensor_of  # noqa: F401 - a fixture
from helicalib.campaign import sensor as sensor_module
from helicalib.campaign.exposure import BeforeState
from helicalib.campaign.frames import FRAME_POLL_S, FrameWait
from helicalib.campaign.sensor import frames_off_thread
from helicalib.campaign.state import RunningVisit
from helicalib.config import load_field_config
from helicalib.devices.protocols import Before, Reading

WAIT_S = 5.0
"""Real seconds a wrapped vision waits for what the test expects to happen meanwhile (a failure
shows as a time-out, never as a hang)."""


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


class Recorder:
    """``measure_spot`` wrapped: the thread each call ran in, and ``hook(call)`` before the real one."""

    def __init__(self, hook=None):
        self.real, self.hook = sensor_module.measure_spot, hook
        self.threads: list[str] = []
        self.lock = threading.Lock()

    def __call__(self, *args, **kwargs):
        with self.lock:
            self.threads.append(threading.current_thread().name)
            call = len(self.threads)
        if self.hook is not None:
            self.hook(call)
        return self.real(*args, **kwargs)


def ctx_of(cfg, hid: str):
    """A visit's context as the sensor reads it: plant time (the real clock, as at rate 1), the
    board, the heliostat's pivot, the spot settings."""
    h = cfg.heliostat(hid)
    settings = SimpleNamespace(max_capture_skew_s=5.0, after_frames=2, max_jitter_mrad=2.0,
                               spot_method="grlm-centroid")
    model = SimpleNamespace(pivots_enu=np.asarray([h.position_enu_m], dtype=float))
    return SimpleNamespace(now=time.time, settings=settings, time_slack_s=None, heliostat_id=hid,
                           target=cfg.target(h.target), model=model)


def before_of(cam) -> Before:
    """The board's before frame as the sensor keeps it (the camera's own image, no marks found yet)."""
    return Before(capture_time_s=time.time(), data=cam.body, state=BeforeState(cam.image, None))


def test_a_reading_s_spot_is_measured_on_the_camera_s_thread(cfg, cameras, monkeypatch):
    cam = cameras("ok", 3)
    rec = Recorder()
    monkeypatch.setattr(sensor_module, "measure_spot", rec)
    sensor = sensor_of(cam)
    stop = frames_off_thread({"T": sensor})
    try:
        values, waits = drive({"T": sensor.after(ctx_of(cfg, "H0001"), before_of(cam))})
    finally:
        stop()
    live = values["T"]
    assert rec.threads == ["helicalib-camera-T_0"]         # once, on the camera's thread
    assert waits["T"] and all(isinstance(w, FrameWait) or w == 1.0 for w in waits["T"])
    # the same frames judged on the caller's thread (the simulations' path) give the same reading
    plain = sensor_of(cam)
    values, _ = drive({"T": plain.after(ctx_of(cfg, "H0001"), before_of(cam))})
    assert rec.threads[1:] == [threading.current_thread().name]
    same = values["T"]
    assert isinstance(live, Reading) and (live.valid, live.reason, live.message) == (same.valid, same.reason,
                                                                                      same.message)
    assert len(live.frames) == 2


def test_two_boards_spots_are_measured_at_once(cfg, cameras, monkeypatch):
    started = {1: threading.Event(), 2: threading.Event()}
    met = []

    def both(call):  # the first call waits for the second to begin: they overlap, or this times out
        started[call].set()
        met.append(started[3 - call].wait(WAIT_S))

    rec = Recorder(both)
    monkeypatch.setattr(sensor_module, "measure_spot", rec)
    cams = {"A": cameras("ok", 1), "B": cameras("ok", 2)}
    sensors = {t: sensor_of(c) for t, c in cams.items()}
    stop = frames_off_thread(sensors)
    try:
        values, _ = drive({t: s.after(ctx_of(cfg, "H0001"), before_of(cams[t])) for t, s in sensors.items()})
    finally:
        stop()
    assert met == [True, True], met
    assert sorted(rec.threads) == ["helicalib-camera-A_0", "helicalib-camera-B_0"]
    assert all(isinstance(r, Reading) for r in values.values())


def test_the_tick_steps_another_board_while_one_spot_is_measured(cfg, cameras, monkeypatch, tmp_path,
                                                                 demo_field_path):
    from campaign_helpers import inprocess_campaign

    runner = inprocess_campaign(cfg, tmp_path, 10, 2, [cfg.heliostats[0].id])[0]
    runner.frame_passes = 3
    measuring, stepped = threading.Event(), threading.Event()
    seen = {}

    def hold(_call):  # the spot is measured until the tick has stepped board B meanwhile
        measuring.set()
        seen["stepped"] = stepped.wait(WAIT_S)

    monkeypatch.setattr(sensor_module, "measure_spot", Recorder(hold))
    cam = cameras("ok", 4)
    sensor = sensor_of(cam)
    stop = frames_off_thread({"A": sensor})
    readings = []

    def visit_a():
        readings.append((yield from sensor.after(ctx_of(cfg, "H0001"), before_of(cam))))
        yield 3600.0

    def visit_b():  # another board's visit, its frame on its way as long as A's spot is measured
        while not readings:
            if measuring.is_set():
                stepped.set()
            yield FrameWait(FRAME_POLL_S)
        yield 3600.0

    now = time.time()  # plant time = real time here (the visits' contexts read it)
    runner.state.active = {"A": RunningVisit("A", "T1", visit_a(), None, now, frame=True),
                           "B": RunningVisit("B", "T2", visit_b(), None, now, frame=True)}
    try:
        end = time.monotonic() + 3 * WAIT_S
        while not readings and time.monotonic() < end:  # the tick's visit steps: the due ones, then the waiting
            now = time.time()
            for hid in [h for h, v in runner.state.active.items() if v.wake_s <= now]:
                runner._step(hid, now)
            runner._frames_in(now)
            time.sleep(0.01)
    finally:
        stop()
        runner.state.active = {}
    assert seen.get("stepped") is True, seen
    assert readings and isinstance(readings[0], Reading)


class _Broken(Exception):
    pass


def test_an_error_of_the_vision_is_raised_where_the_visit_waits(cfg, cameras, monkeypatch):
    def fail(_call):
        raise _Broken("the spot finder broke on this frame")

    monkeypatch.setattr(sensor_module, "measure_spot", Recorder(fail))
    cam = cameras("ok", 5)
    sensor = sensor_of(cam)
    stop = frames_off_thread({"T": sensor})
    try:
        with pytest.raises(_Broken, match="spot finder broke"):
            drive({"T": sensor.after(ctx_of(cfg, "H0001"), before_of(cam))})
    finally:
        stop()


@pytest.mark.parametrize("broken", [False, True])
def test_a_live_run_measures_spots_off_the_tick_and_a_vision_error_is_an_invalid_measurement(
        cfg, tmp_path, served, monkeypatch, broken):  # noqa: F811 - the fixture
    """``run_live`` against the simulated plant on loopback: every spot is measured on a camera's
    thread; a vision that raises makes each measurement invalid with the error as its reason, and
    the run goes on (more visits start, the stop is clean)."""
    from helicalib.app import live
    from test_live_faults import _network_runner

    def fail(_call):
        raise _Broken("the spot finder broke")

    rec = Recorder(fail if broken else None)
    monkeypatch.setattr(sensor_module, "measure_spot", rec)
    ids = ["H0001", "H0021"]
    runner, store, cid = _network_runner(cfg, tmp_path, served, ids)
    stop = threading.Event()
    recorded = []  # the measurements the tick has recorded (a spot measured is recorded on a later step)
    record = runner.host.record

    def counted(ctx, observation, frames):
        if observation.iteration >= 0 or observation.reason.startswith("error_"):
            recorded.append(observation.reason)
        return record(ctx, observation, frames)

    runner.host.record = counted

    def enough():  # (broken: a failed spot recorded, not only a reading that failed before its vision)
        got = "error__Broken" in recorded if broken else bool(recorded)
        return len(rec.threads) >= 2 and runner.state.stats.visits >= 2 and got

    def watch():
        end = time.monotonic() + 60.0
        while not enough() and time.monotonic() < end:
            time.sleep(0.05)
        stop.set()

    threading.Thread(target=watch, daemon=True).start()
    try:
        result = live.run_live(runner, runner.devices.clock.now_s() + 86400.0, stop_event=stop)
        store.flush()
        obs = store.observations(campaign_id=cid)
    finally:
        store.close()
    assert result.reason == "stopped" and enough(), (len(rec.threads), runner.state.stats.visits)
    assert rec.threads and all(t.startswith("helicalib-camera-") for t in rec.threads), rec.threads
    measured = [o for o in obs if o.iteration >= 0 or o.reason.startswith("error_")]
    assert measured
    if broken:
        failed = [o for o in obs if o.reason == "error__Broken"]
        assert failed and all(not o.valid and "spot finder broke" in o.message for o in failed), \
            [(o.reason, o.message) for o in obs]


def test_a_frame_in_asks_for_the_tick_at_once(cfg, cameras, tmp_path):
    """A camera's frame that a visit waits for moves the tick job's next run to now (a real, not
    started, APScheduler); one that comes in during a tick runs the next tick straight after it."""
    import datetime as dt

    from apscheduler.schedulers.background import BackgroundScheduler

    from campaign_helpers import inprocess_campaign
    from helicalib.app import live

    runner = inprocess_campaign(cfg, tmp_path, 10, 2, [cfg.heliostats[0].id])[0]
    scheduler = BackgroundScheduler(timezone=dt.timezone.utc)
    later = dt.datetime.now(dt.timezone.utc) + dt.timedelta(hours=1)
    scheduler.add_job(lambda: None, "interval", seconds=3600, id="helicalib-tick", next_run_time=later)
    kick = live._Kick(scheduler, runner)
    next_run = lambda: scheduler.get_job("helicalib-tick").next_run_time  # noqa: E731
    cam = cameras("ok", 6)
    sensor = sensor_of(cam)
    stop = frames_off_thread({"T": sensor}, on_done=kick)
    try:
        drive({"T": sensor._grab_waiting(ctx_of(cfg, "H0001"))})
    finally:
        stop()
    # (a future is done just before its callbacks run: the kick may come a moment after the frame)
    assert kick.asked.wait(WAIT_S)
    end = time.monotonic() + WAIT_S
    while next_run() >= later - dt.timedelta(minutes=59) and time.monotonic() < end:
        time.sleep(0.01)
    assert next_run() < later - dt.timedelta(minutes=59)
    # a frame in while a tick runs: after it the next one is asked at once; none in: none asked
    scheduler.modify_job("helicalib-tick", next_run_time=later)
    tick, ticks = runner.tick, []
    runner.tick = lambda now: (kick.asked.set(), ticks.append(now), tick(now))[2]
    live._tick_job(runner, threading.Lock(), kick)
    assert len(ticks) == live.KICKED_TICKS                  # the job ran the next ticks itself, then
    assert next_run() < later - dt.timedelta(minutes=59)   # asked for the next job at once
    scheduler.modify_job("helicalib-tick", next_run_time=later)
    ticks.clear()
    runner.tick = lambda now: (ticks.append(now), kick.asked.set() if len(ticks) == 1 else None, tick(now))[2]
    live._tick_job(runner, threading.Lock(), kick)
    assert len(ticks) == 2 and next_run() == later         # one frame in during the first: one more tick
    scheduler.modify_job("helicalib-tick", next_run_time=later)
    runner.tick = tick
    live._tick_job(runner, threading.Lock(), kick)
    assert next_run() == later and not kick.asked.is_set()


class _Plant:
    """The plant's answers a measurement reads (weather, a heliostat's status), each call logged."""

    def __init__(self, log):
        self.log = log

    def weather(self):
        self.log.append("weather")
        return SimpleNamespace(wind_ms=3.0, wind_direction_deg=90.0, dni_wm2=900.0, temperature_c=20.0)

    def status(self, index):
        self.log.append("status")
        return SimpleNamespace(cleanliness=0.95)


class _Sensor:
    """A spot sensor whose after frames are on their way for one wait (``frames``: a live run's
    worker, or None as in simulations); it says no spot."""

    def __init__(self, log, live):
        self.log, self.frames = log, (object() if live else None)

    def after(self, ctx, before):
        self.log.append("frames asked")
        yield FrameWait(FRAME_POLL_S)
        self.log.append("reading in")
        return Reading(False, "no_spot", "no spot on the board", 1000.0)


@pytest.mark.parametrize("live", [True, False])
def test_a_live_measurement_reads_the_plant_before_its_frames_a_simulated_one_after(cfg, live):
    """In a live run the weather and cleanliness are read while the beam holds, so the way from the
    reading to the next command holds no plant request of theirs; a simulation reads them after the
    reading, as it always did (the same results for the same seed)."""
    from helicalib.campaign.measure import measure

    log, recorded = [], []
    h = cfg.heliostat("H0001")
    host = SimpleNamespace(record=lambda ctx, obs, frames: recorded.append(obs) or 7)
    ctx = SimpleNamespace(sensor=_Sensor(log, live), plant=_Plant(log), host=host, index=0, approach=(1, 1),
                          sun=lambda t: ((0.0, 0.0, 1.0), 180.0, 30.0, True), campaign_id=1, heliostat_id="H0001",
                          target_id=h.target, target=cfg.target(h.target), visit_id=3, before_path="b.png")
    before = Before(capture_time_s=999.0, data=b"", state=None)
    values, _ = drive({"m": measure(ctx, before, (100.0, 200.0), (100.0, 200.0), None, 0)})
    obs, _before = values["m"]
    if live:
        assert log == ["weather", "status", "frames asked", "reading in"]
    else:
        assert log == ["frames asked", "reading in", "weather", "status"]
    assert len(recorded) == 1 and recorded[0].reason == "no_spot"
    assert not obs.valid and obs.dni_wm2 == 900.0 and obs.cleanliness == 0.95 and obs.id == 7


def test_a_live_tick_never_steps_a_visit_twice_past_its_new_wait(demo_field_path, tmp_path):
    """Two boards' visits wait for a frame that is in: stepped in one tick, each goes on once and
    keeps the plant second it then asks between its after frames (a second step would grab the
    next frame at once, milliseconds after the first)."""
    from campaign_helpers import inprocess_campaign

    from helicalib.campaign.state import RunningVisit
    from helicalib.config import load_field_config

    cfg = load_field_config(demo_field_path)
    runner = inprocess_campaign(cfg, tmp_path, 10, 2, [cfg.heliostats[0].id])[0]
    steps = []

    def visit(name):
        yield FrameWait(FRAME_POLL_S)
        steps.append((name, "frame in"))
        yield 1.0  # the plant second between two after frames
        steps.append((name, "next grab"))
        yield 3600.0

    now = runner.devices.clock.now_s()
    gens = {h: visit(h) for h in "AB"}
    for g in gens.values():
        next(g)
    runner.state.active = {"A": RunningVisit("A", "T1", gens["A"], None, now - 1, frame=True),
                           "B": RunningVisit("B", "T2", gens["B"], None, now - 1, frame=True)}
    runner.frame_passes = 3
    try:
        runner.tick(now)
    finally:
        runner.state.active = {}
    assert sorted(steps) == [("A", "frame in"), ("B", "frame in")], steps
