"""StreamCamera over HTTP MJPEG: against the simulated plant's stream service (rendered target
frames, the exposure control URL) and against ffmpeg's own MJPEG HTTP server
(``-f mpjpeg -listen 1``). Real sockets on loopback, real JPEG streams, real FFmpeg decoding.
The ffmpeg test is skipped only when /usr/bin/ffmpeg is missing."""

from __future__ import annotations

import shutil
import subprocess
import time
import urllib.request

import cv2
import numpy as np
import pytest
from conftest import free_port

from helicalib.config import load_field_config
from helicalib.devices.camera_http import CameraError
from helicalib.devices.camera_stream import StreamCamera
from helicalib.devices.connect import cameras_from_config
from helicalib.geometry.sun import to_unix_seconds
from helicalib.sim.camera import SimCamera
from helicalib.sim.clock import RateClock
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.sim.server import PlantServer
from helicalib.sim.stream_server import StreamService

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))  # daylight at the demo field
QUIET = {"camera": {"noise_counts": 0.0}}
FFMPEG = "/usr/bin/ffmpeg"


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def _image(frame) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.ndim == 2 and img.dtype == np.uint8  # 8-bit grayscale PNG
    return img


def _service(cfg, scenario=QUIET, fps=8.0):
    plant = SimulatedPlant(cfg, parse_scenario(scenario), start_s=START)
    clock = RateClock(START, 1.0, time.monotonic)
    server = PlantServer(plant, clock)  # not started: its plant lock and sync only
    cams = {c.id: SimCamera(plant, c.id) for c in cfg.cameras[:1]}
    return StreamService(cams, server.registers.lock, server.registers.sync, fps=fps).start(), clock


def test_the_simulated_stream_sets_its_exposure_and_hands_out_frames_taken_after_it(cfg):
    service, clock = _service(cfg)
    cam_cfg = cfg.cameras[0]
    cam = StreamCamera(service.url(cam_cfg.id), clock=clock, timeout_s=5.0, expected_size_px=cam_cfg.resolution_px,
                       exposure_url=service.exposure_url(cam_cfg.id))
    try:
        nominal = cam.grab()
        assert nominal.exposure_ms == 1.0  # read from the control URL: the camera's present setting
        assert abs(nominal.capture_time_s - clock.now_s()) < 1.0
        long = cam.grab(exposure_ms=8.0)
        short = cam.grab(exposure_ms=4.0)  # the first frame after the change is at the new exposure
        assert (long.exposure_ms, short.exposure_ms) == (8.0, 4.0)
        a, b = _image(long).astype(float), _image(short).astype(float)
        lit = (a > 60) & (a < 250)
        assert lit.sum() > 1000
        assert abs(np.median(b[lit] / a[lit]) - 0.5) < 0.03
        assert cam.grab(exposure_ms=5000.0).exposure_ms == 100.0  # clamped by the camera
        assert cam.grab().exposure_ms == 100.0  # and kept
    finally:
        cam.close()
        service.stop()


def test_a_stream_camera_without_exposure_control_ignores_the_request(cfg):
    service, clock = _service(cfg, {"camera": {"noise_counts": 0.0, "exposure": False}})
    cam = StreamCamera(service.url(cfg.cameras[0].id), clock=clock, timeout_s=5.0)
    try:
        assert cam.grab(exposure_ms=0.5).exposure_ms is None
        with urllib.request.urlopen(service.exposure_url(cfg.cameras[0].id) + "?exposure_ms=2") as answer:
            assert answer.status == 200 and answer.headers.get("X-Exposure-Ms") is None
        asked = StreamCamera(service.url(cfg.cameras[0].id), clock=clock, timeout_s=5.0,
                             exposure_url=service.exposure_url(cfg.cameras[0].id))
        with pytest.raises(CameraError) as err:
            asked.grab(exposure_ms=2.0)
        assert err.value.reason == "camera_no_exposure" and "X-Exposure-Ms" in str(err.value)
        asked.close()
    finally:
        cam.close()
        service.stop()


def test_wrong_size_and_a_stopped_service(cfg):
    service, clock = _service(cfg)
    url = service.url(cfg.cameras[0].id)
    cam = StreamCamera(url, clock=clock, timeout_s=1.5, expected_size_px=(64, 64))
    try:
        with pytest.raises(CameraError) as err:
            cam.grab()
        assert err.value.reason == "camera_wrong_size"
        service.stop()  # the stream ends; no new frame comes, and none is opened within the deadline
        t = time.monotonic()
        with pytest.raises(CameraError) as err:
            cam.grab()
        assert err.value.reason in ("camera_unreachable", "camera_timeout") and url in str(err.value)
        assert time.monotonic() - t < 4.0
    finally:
        cam.close()
        service.stop()


def test_cameras_from_config_builds_a_stream_camera(cfg, tmp_path):
    stream_cfg = cfg.model_copy(update={"cameras": [cfg.cameras[0].model_copy(update={
        "kind": "stream", "url": "http://127.0.0.1:9/cam/stream.mjpg", "exposure_url": "http://127.0.0.1:9/cam/exposure"})]})
    cams = cameras_from_config(stream_cfg, timeout_s=2.0)
    cam = cams[cfg.cameras[0].target]
    assert isinstance(cam, StreamCamera)
    assert cam.exposure_url == "http://127.0.0.1:9/cam/exposure" and cam.timeout_s == 2.0


def test_ffmpeg_mjpeg_over_http_hands_out_the_newest_frame():
    assert shutil.which(FFMPEG), f"{FFMPEG} is not installed: `make test` installs Debian's ffmpeg (apt-get)"
    url = f"http://127.0.0.1:{free_port()}/cam"
    source = "color=c=black:s=320x240:r=10,format=gray,geq=lum='if(bitand(N\\,pow(2\\,floor(X/32)))\\,255\\,0)'"
    proc = subprocess.Popen([FFMPEG, "-hide_banner", "-loglevel", "error", "-re", "-f", "lavfi", "-i", source,
                             "-c:v", "mjpeg", "-q:v", "3", "-f", "mpjpeg", "-listen", "1", url],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    cam = StreamCamera(url, clock=RateClock(START, 1.0, time.monotonic), timeout_s=5.0, expected_size_px=(320, 240))

    def number(frame) -> int:
        img = _image(frame)
        return sum(int(img[120, 32 * i + 16] > 128) << i for i in range(10))

    try:
        first = number(cam.grab())
        time.sleep(0.8)
        second = number(cam.grab())
        assert 4 <= second - first <= 13, (first, second)  # a camera that buffered: 1
    finally:
        cam.close()
        proc.kill()
        proc.wait(5)
