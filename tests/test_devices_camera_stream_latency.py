"""StreamCamera against a camera with latency: a small HTTP MJPEG camera on loopback whose frames
arrive ``LATENCY_S`` after they were exposed, as an IP camera's do (encoding, network: 50-300 ms).
Each frame is a uniform gray JPEG whose level is the exposure set ``LATENCY_S`` before it is sent
(``LEVEL_PER_MS`` counts per ms), so a frame exposed before a change shows the old level. Real
sockets, real JPEG, real FFmpeg decoding; the control URL speaks PLANT_INTERFACE 1.1."""

from __future__ import annotations

import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlparse

import cv2
import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.devices.camera_stream import StreamCamera
from helicalib.devices.connect import cameras_from_config

FPS = 10.0
LATENCY_S = 0.3
LEVEL_PER_MS = 20.0
SIZE = (64, 48)
BOUNDARY = "frame"


class LaggingCamera:
    """An MJPEG camera whose frames arrive ``latency_s`` after exposure, with an exposure control URL."""

    def __init__(self, latency_s: float = LATENCY_S, fps: float = FPS):
        self.latency_s, self.period_s = latency_s, 1.0 / fps
        self.settings = [(float("-inf"), 1.0)]  # (monotonic s, exposure ms)
        self.lock = threading.Lock()
        self.stopping = threading.Event()
        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), self._handler())
        self.httpd.daemon_threads = True
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/{path}"

    def exposure_at(self, t: float) -> float:
        with self.lock:
            return [ms for since, ms in self.settings if since <= t][-1]

    def stop(self) -> None:
        self.stopping.set()
        self.httpd.shutdown()
        self.httpd.server_close()

    def _handler(self):
        camera = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):
                pass

            def do_GET(self):  # noqa: N802
                parts = urlparse(self.path)
                if parts.path == "/exposure":
                    asked = parse_qs(parts.query).get("exposure_ms")
                    if asked:
                        with camera.lock:
                            camera.settings.append((time.monotonic(), float(asked[-1])))
                    self.send_response(200)
                    self.send_header("Content-Length", "0")
                    self.send_header("X-Exposure-Ms", repr(camera.exposure_at(time.monotonic())))
                    self.end_headers()
                    return
                self.close_connection = True
                self.send_response(200)
                self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
                self.send_header("Connection", "close")
                self.end_headers()
                due = time.monotonic()
                try:
                    while not camera.stopping.is_set():
                        level = min(255.0, LEVEL_PER_MS * camera.exposure_at(time.monotonic() - camera.latency_s))
                        _, jpeg = cv2.imencode(".jpg", np.full(SIZE[::-1], level, np.uint8))
                        body = jpeg.tobytes()
                        self.wfile.write(f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                                         f"Content-Length: {len(body)}\r\n\r\n".encode() + body + b"\r\n")
                        self.wfile.flush()
                        due += camera.period_s
                        time.sleep(max(0.0, due - time.monotonic()))
                except (BrokenPipeError, ConnectionResetError):
                    pass

        return Handler


class Clock:
    rate = 1.0
    uncertainty_s = 0.0

    def now_s(self):
        return 1_790_000_000.0 + time.monotonic()


def _level(frame) -> float:
    img = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_UNCHANGED)
    return float(np.median(img))


@pytest.fixture()
def lagging():
    camera = LaggingCamera()
    yield camera
    camera.stop()


def test_after_an_exposure_change_no_frame_exposed_before_it_is_handed_out(lagging):
    cam = StreamCamera(lagging.url("stream.mjpg"), clock=Clock(), timeout_s=5.0, expected_size_px=SIZE,
                       exposure_url=lagging.url("exposure"), latency_s=LATENCY_S)
    try:
        first = cam.grab()
        assert first.exposure_ms == 1.0 and abs(_level(first) - LEVEL_PER_MS) < 3
        for asked in (4.0, 8.0, 2.0):  # each frame shows the level of the exposure it is labelled with
            frame = cam.grab(exposure_ms=asked)
            assert frame.exposure_ms == asked
            assert abs(_level(frame) - LEVEL_PER_MS * asked) < 3, (asked, _level(frame))
    finally:
        cam.close()


def test_capture_time_is_arrival_less_the_latency(lagging):
    clock = Clock()
    cam = StreamCamera(lagging.url("stream.mjpg"), clock=clock, timeout_s=5.0, latency_s=LATENCY_S)
    try:
        before = clock.now_s()
        frame = cam.grab()
        after = clock.now_s()
        assert before - LATENCY_S - 0.05 <= frame.capture_time_s <= after - LATENCY_S
    finally:
        cam.close()


def test_from_config_takes_latency_ms(demo_field_path):
    cfg = load_field_config(demo_field_path)
    cam_cfg = cfg.cameras[0].model_copy(update={"kind": "stream", "url": "http://127.0.0.1:9/s.mjpg",
                                                 "exposure_url": "http://127.0.0.1:9/e", "latency_ms": 180.0})
    cam = cameras_from_config(cfg.model_copy(update={"cameras": [cam_cfg]}), timeout_s=2.0)[cam_cfg.target]
    assert isinstance(cam, StreamCamera) and cam.latency_s == pytest.approx(0.18)
