"""The HTTP camera client against real loopback HTTP servers: good frames and every kind of fault."""

from __future__ import annotations

import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.devices.camera_http import CameraError, HttpCamera, image_size
from helicalib.devices.connect import cameras_from_config
from helicalib.devices.protocols import Camera
from helicalib.errors import MeasurementError
from helicalib.geometry.sun import to_unix_seconds

IMG = (np.arange(64 * 48) % 200).astype(np.uint8).reshape(48, 64)
PNG = cv2.imencode(".png", IMG)[1].tobytes()
JPG = cv2.imencode(".jpg", IMG)[1].tobytes()


class Script:
    """What the server answers, one entry per request (the last one repeats)."""

    def __init__(self):
        self.answers: list[str] = ["ok"]
        self.requests = 0

    def next(self) -> str:
        self.requests += 1
        return self.answers.pop(0) if len(self.answers) > 1 else self.answers[0]


@pytest.fixture()
def server():
    script = Script()

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):
            pass

        def send(self, code, body, headers=None, claimed=None):
            self.send_response(code)
            self.send_header("Content-Length", str(claimed if claimed is not None else len(body)))
            for k, v in (headers or {}).items():
                self.send_header(k, v)
            self.send_header("Connection", "close")
            self.end_headers()
            try:
                self.wfile.write(body)
            except (BrokenPipeError, ConnectionResetError):  # the client gave up (timeout test)
                pass
            self.close_connection = True

        def do_GET(self):  # noqa: N802
            mode = script.next()
            t = {"X-Capture-Time": "1774000000.25", "Content-Type": "image/png"}
            if mode == "ok":
                self.send(200, PNG, t)
            elif mode == "jpeg":
                self.send(200, JPG, {**t, "Content-Type": "image/jpeg"})
            elif mode == "503":
                self.send(503, b"busy", {})
            elif mode == "404":
                self.send(404, b"no such camera", {})
            elif mode == "short":  # Content-Length promises more than is sent
                self.send(200, PNG[: len(PNG) // 2], t, claimed=len(PNG))
            elif mode == "cut_png":  # consistent length, but the PNG lacks its end
                self.send(200, PNG[: len(PNG) - 20], t)
            elif mode == "no_time":
                self.send(200, PNG, {"Content-Type": "image/png"})
            elif mode == "bad_time":
                self.send(200, PNG, {"X-Capture-Time": "noon"})
            elif mode == "html":
                self.send(200, b"<html>login</html>", {"X-Capture-Time": "1.0", "Content-Type": "text/html"})
            elif mode == "slow":
                time.sleep(1.0)
                self.send(200, PNG, t)

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    httpd.daemon_threads = True
    th = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    th.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/T1.png", script
    httpd.shutdown()
    httpd.server_close()


def camera(url, **kw):
    kw.setdefault("sleep", lambda s: None)
    return HttpCamera(url, timeout_s=kw.pop("timeout_s", 2.0), **kw)


def test_good_frame_with_capture_time(server):
    url, script = server
    cam = camera(url, expected_size_px=(64, 48))
    assert isinstance(cam, Camera)
    f = cam.grab()
    assert f.data == PNG and f.capture_time_s == 1774000000.25 and f.source == url
    script.answers = ["jpeg"]
    assert cam.grab().data == JPG
    assert image_size(PNG) == (64, 48) and image_size(JPG) == (64, 48)


@pytest.mark.parametrize("mode, reason", [("503", "camera_http_error"), ("short", "camera_truncated"),
                                          ("cut_png", "camera_truncated")])
def test_transient_faults_are_retried_then_succeed(server, mode, reason):
    url, script = server
    script.answers = [mode, "ok"]
    waits = []
    assert camera(url, retries=2, sleep=waits.append).grab().data == PNG
    assert script.requests == 2 and waits == [0.2]
    script.answers = [mode]
    script.requests = 0
    with pytest.raises(CameraError) as err:
        camera(url, retries=2).grab()
    assert err.value.reason == reason and "after 3 attempts" in str(err.value)
    assert isinstance(err.value, MeasurementError) and script.requests == 3


@pytest.mark.parametrize("mode, reason, text", [
    ("404", "camera_http_error", "HTTP 404"), ("no_time", "camera_no_capture_time", "X-Capture-Time"),
    ("bad_time", "camera_no_capture_time", "'noon'"), ("html", "camera_not_image", "neither PNG nor JPEG"),
])
def test_permanent_faults_are_not_retried(server, mode, reason, text):
    url, script = server
    script.answers = [mode]
    with pytest.raises(CameraError) as err:
        camera(url, retries=3).grab()
    assert err.value.reason == reason and text in str(err.value) and url in str(err.value)
    assert script.requests == 1


def test_wrong_frame_size(server):
    url, _ = server
    with pytest.raises(CameraError, match="64×48 px, expected 1280×1024") as err:
        camera(url, expected_size_px=(1280, 1024)).grab()
    assert err.value.reason == "camera_wrong_size"


def test_timeout(server):
    url, script = server
    script.answers = ["slow"]
    with pytest.raises(CameraError, match="no answer within 0.2 s") as err:
        camera(url, timeout_s=0.2, retries=0).grab()
    assert err.value.reason == "camera_timeout"


def test_unreachable():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(CameraError) as err:
        camera(f"http://127.0.0.1:{port}/x.png", retries=1).grab()
    assert err.value.reason == "camera_unreachable"


def test_simulated_plant_camera_over_loopback(demo_field_path):
    from helicalib.sim.clock import RateClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.server import PlantServer

    cfg = load_field_config(demo_field_path)
    start = float(to_unix_seconds("2026-03-20T05:00:00Z"))
    plant = SimulatedPlant(cfg, start_s=start, rate=600.0)
    server = PlantServer(plant, RateClock(start, 600.0, lambda: 0.0), modbus_port=0, camera_port=0).start()
    try:
        cams = cameras_from_config(cfg)
        assert set(cams) == {t.id for t in cfg.targets}
        cam = HttpCamera(server.camera_url(cfg.cameras[0].id), expected_size_px=cfg.cameras[0].resolution_px)
        frame = cam.grab()
        assert frame.capture_time_s == pytest.approx(start, abs=1.0)
        img = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert img.shape[:2] == tuple(reversed(cfg.cameras[0].resolution_px))
    finally:
        server.stop()
