"""A live run's frames off the tick's thread (campaign/frames.py) against real HTTP cameras on
loopback: each answers a real PNG frame after a delay (a camera under load), stamps it with the
time it took it, and logs when each request began and ended.

The frame keeps the camera's capture time (not its arrival); two boards' grabs overlap in the
camera servers' log; a camera that fails makes the reading invalid with its reason; without a worker
(the simulations' virtual clock) a reading waits exactly as it always did.
"""

from __future__ import annotations

import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from types import SimpleNamespace

import numpy as np
import pytest

from helicalib.campaign.frames import FRAME_POLL_S, FrameWait, FrameWorker, run_now
from helicalib.campaign.sensor import frames_off_thread
from helicalib.campaign.state import RunningVisit
from helicalib.campaign.sensor import CameraSensor
from helicalib.devices.camera_http import HttpCamera
from helicalib.vision.frames import encode_png

DELAY_S = 0.15
"""Real seconds a test camera takes to answer (after it took the frame)."""


class Camera:
    """A camera server on 127.0.0.1: ``mode`` "ok" (a PNG, X-Capture-Time the time it was taken),
    "error" (HTTP 500 every time) or "skewed" (a capture time an hour off)."""

    def __init__(self, mode: str = "ok", seed: int = 0):
        self.mode = mode
        self.image = np.random.default_rng(seed).integers(0, 255, (48, 64), dtype=np.uint8)
        self.body = encode_png(self.image)
        self.log: list[tuple[float, float, float]] = []   # (began, ended, capture time) per request
        cam = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):  # noqa: N802
                began = time.time()
                taken = began + (3600.0 if cam.mode == "skewed" else 0.0)
                time.sleep(DELAY_S)
                if cam.mode == "error":
                    self.send_response(500)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                else:
                    self.send_response(200)
                    self.send_header("Content-Type", "image/png")
                    self.send_header("X-Capture-Time", repr(taken))
                    self.send_header("Content-Length", str(len(cam.body)))
                    self.end_headers()
                    self.wfile.write(cam.body)
                cam.log.append((began, time.time(), taken))

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/frame.png"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture()
def cameras():
    made = []

    def make(mode="ok", seed=0):
        made.append(Camera(mode, seed))
        return made[-1]
    yield make
    for cam in made:
        cam.close()


def sensor_of(cam: Camera) -> CameraSensor:
    return CameraSensor(HttpCamera(cam.url, retries=0, backoff_s=0.0), camera_config=None)


def ctx_of(hid: str, after_frames: int = 3):
    """What a grab asks of a visit: plant time (here the real clock, as at rate 1), the skew allowed."""
    settings = SimpleNamespace(max_capture_skew_s=5.0, after_frames=after_frames)
    return SimpleNamespace(now=time.time, settings=settings, time_slack_s=None, heliostat_id=hid)


def drive(gens: dict):
    """Step generators of plant-second waits as the live tick does, one after another, each when its
    wait is over (plant time = real time here); returns each one's value and the waits it asked."""
    wake = {k: 0.0 for k in gens}
    waits = {k: [] for k in gens}
    values = {}
    while len(values) < len(gens):
        for k, gen in gens.items():
            if k in values or wake[k] > time.time():
                continue
            try:
                w = gen.send(None)
            except StopIteration as done:
                values[k] = done.value
                continue
            waits[k].append(w)
            wake[k] = time.time() + w
        time.sleep(0.005)
    return values, waits


def test_a_frame_on_the_camera_s_thread_keeps_its_capture_time_and_the_visit_waits_for_it(cameras):
    cam = cameras("ok")
    sensor = sensor_of(cam)
    sensor.frames = FrameWorker("a")
    try:
        values, waits = drive({"a": sensor._grab_waiting(ctx_of("H1"))})
    finally:
        sensor.frames.close()
    frame, image = values["a"]
    began, ended, taken = cam.log[0]
    assert frame.capture_time_s == taken == began          # the time the camera took it, not its arrival
    assert ended > taken
    assert np.array_equal(image, cam.image)                # decoded on the camera's thread
    assert waits["a"] and set(waits["a"]) == {FRAME_POLL_S}  # the visit yielded while the frame was on its way
    assert all(isinstance(w, FrameWait) for w in waits["a"])


def test_two_boards_grabs_overlap_in_the_cameras_logs(cameras):
    cams = {"A": cameras("ok", 1), "B": cameras("ok", 2)}
    sensors = {t: sensor_of(c) for t, c in cams.items()}
    stop = frames_off_thread(sensors)
    try:
        gens = {t: (run_now_frames(s, ctx_of(f"H{t}", 3))) for t, s in sensors.items()}
        values, _waits = drive(gens)
    finally:
        stop()
    assert all(s.frames is None for s in sensors.values())   # given back at the run's end
    a, b = cams["A"].log, cams["B"].log
    assert len(a) == len(b) == 3
    # every one of board B's grabs began while one of board A's was being answered, or the other way round
    overlaps = sum(1 for (b0, b1, _t) in b for (a0, a1, _s) in a if b0 < a1 and a0 < b1)
    assert overlaps >= 3
    for t, frames in values.items():
        assert [f.capture_time_s for f, _img in frames] == [taken for _b, _e, taken in cams[t].log]


def run_now_frames(sensor: CameraSensor, ctx):
    """A board's after frames as :meth:`CameraSensor.after` takes them (grab, a plant second, grab ...)."""
    out = []
    for k in range(ctx.settings.after_frames):
        out.append((yield from sensor._grab_waiting(ctx)))
        if k < ctx.settings.after_frames - 1:
            yield 1.0
    return out


@pytest.mark.parametrize("mode, reason", [("error", "camera_http_error"), ("skewed", "capture_time")])
def test_a_camera_that_fails_makes_the_reading_invalid_with_its_reason(cameras, mode, reason):
    cam = cameras(mode)
    sensor = sensor_of(cam)
    stop = frames_off_thread({"T": sensor})
    try:
        values, _waits = drive({"T": sensor.after(ctx_of("H7"), before=SimpleNamespace(state=None))})
    finally:
        stop()
    reading = values["T"]
    assert not reading.valid and reading.reason == reason
    assert "H7" in reading.message or cam.url.split("/")[2] in reading.message
    assert len(cam.log) == 1                              # the first failure ends the reading
    if mode == "skewed":                                  # the refused frame is kept with the reading
        assert reading.frames == (cam.body,)


def test_without_a_worker_a_reading_waits_as_it_always_did(cameras):
    """The simulations' path: grabs on the visit's thread, a plant second after every frame."""
    cam = cameras("error")
    sensor = sensor_of(cam)
    values, waits = drive({"T": sensor.after(ctx_of("H2"), before=SimpleNamespace(state=None))})
    assert waits["T"] == [] and values["T"].reason == "camera_http_error"
    ok = cameras("ok")
    sensor = sensor_of(ok)
    gen = sensor._grab_waiting(ctx_of("H3"))
    with pytest.raises(StopIteration):                    # no wait at all: the frame is there at once
        gen.send(None)
    frame, image = run_now(sensor._grab_waiting(ctx_of("H3")))
    assert frame.capture_time_s == ok.log[-1][2] and np.array_equal(image, ok.image)


def test_a_live_tick_steps_again_the_visits_whose_frame_is_on_its_way(demo_field_path, tmp_path):
    """A frame that came in while the tick stepped the other boards is used in that tick."""
    from campaign_helpers import inprocess_campaign
    from helicalib.config import load_field_config

    cfg = load_field_config(demo_field_path)
    runner = inprocess_campaign(cfg, tmp_path, 10, 2, [cfg.heliostats[0].id])[0]
    steps = []

    def visit(name, frame_waits):
        for _ in range(frame_waits):
            steps.append(name)
            yield FrameWait(FRAME_POLL_S)   # its frame still on its way
        steps.append(name)
        yield 1.0                           # its frame in: on to its next move

    now = runner.devices.clock.now_s()
    runner.state.active = {"A": RunningVisit("A", "T1", visit("A", 1), None, now, frame=True),
                           "B": RunningVisit("B", "T2", visit("B", 5), None, now, frame=True),
                           "C": RunningVisit("C", "T3", visit("C", 0), None, now, frame=False)}
    runner._frames_in(now)                  # simulations: frame_passes 0, nothing stepped again
    assert steps == []
    runner.frame_passes = 3
    runner._frames_in(now)
    assert steps == ["A", "B", "A", "B", "B"]   # A's frame came in at its second look; C waits on its move
    assert not runner.state.active["A"].frame and runner.state.active["B"].frame
    runner.state.active = {}


def test_the_frame_workers_are_closed_when_the_live_jobs_cannot_start(demo_field_path, tmp_path, monkeypatch):
    """``run_live`` gives its cameras' frame workers back (and the signal handlers) when anything
    between their start and the run's loop fails (here the scheduler's start)."""
    import signal

    from apscheduler.schedulers.background import BackgroundScheduler

    from campaign_helpers import inprocess_campaign
    from helicalib.app import live
    from helicalib.config import load_field_config

    cfg = load_field_config(demo_field_path)
    runner = inprocess_campaign(cfg, tmp_path, 10, 2, [cfg.heliostats[0].id])[0]
    given = []

    def refuse(_scheduler, *args, **kwargs):
        given.extend(s.frames for s in runner.devices.sensors.values() if isinstance(s, CameraSensor))
        raise RuntimeError("no thread for the scheduler")

    monkeypatch.setattr(BackgroundScheduler, "start", refuse)
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(RuntimeError, match="no thread for the scheduler"):
        live.run_live(runner, runner.devices.clock.now_s() + 60.0)
    assert given and all(isinstance(w, FrameWorker) for w in given)     # they were started ...
    assert all(s.frames is None for s in runner.devices.sensors.values())  # ... and given back
    assert all(w._pool._shutdown for w in given)
    assert signal.getsignal(signal.SIGINT) is handler
