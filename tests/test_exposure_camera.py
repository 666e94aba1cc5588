"""Exposure (PLANT_INTERFACE 1.1) in the cameras: the simulated camera's grey levels in proportion to
the exposure, and the HTTP camera against the simulated plant's real HTTP server (query and header,
and a camera without exposure control: no header, the parameter ignored)."""

from __future__ import annotations

import http.server
import threading

import cv2
import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.devices.camera_http import CameraError, HttpCamera
from helicalib.geometry.sun import to_unix_seconds
from helicalib.sim.camera import SimCamera, noise_scale
from helicalib.sim.clock import RateClock
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.sim.server import PlantServer

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))  # daylight at the demo field
QUIET = {"camera": {"noise_counts": 0.0}}


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def _image(frame) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_UNCHANGED)


def test_nominal_exposure_gives_the_fixed_cameras_frame_bit_for_bit(cfg):
    fixed = SimCamera(SimulatedPlant(cfg, parse_scenario({"camera": {"exposure": False}}), start_s=START),
                      cfg.cameras[0].id)
    free = SimCamera(SimulatedPlant(cfg, start_s=START), cfg.cameras[0].id)
    a, b = fixed.grab(exposure_ms=7.0), free.grab(exposure_ms=1.0)
    assert a.exposure_ms is None and fixed.exposure_ms == 1.0  # ignored: it cannot set its exposure
    assert b.exposure_ms == 1.0
    assert np.array_equal(_image(a), _image(b))


def test_grey_levels_scale_with_the_exposure_and_clip_at_255(cfg):
    cam = SimCamera(SimulatedPlant(cfg, parse_scenario(QUIET), start_s=START), cfg.cameras[0].id)
    base = _image(cam.grab()).astype(float)
    half = _image(cam.grab(exposure_ms=0.5)).astype(float)
    lit = (base > 20) & (base < 250)
    assert lit.sum() > 1000
    assert np.max(np.abs(half[lit] - 0.5 * base[lit])) <= 1.0  # rounding of either frame
    bright = _image(cam.grab(exposure_ms=40.0)).astype(float)
    assert cam.exposure_ms == 40.0
    assert bright.max() == 255 and np.all(bright[base >= 7] == 255)  # every level ≥ 6.4 × 40 clips


def test_exposure_is_clamped_to_the_range_and_refused_when_not_positive(cfg):
    cam = SimCamera(SimulatedPlant(cfg, parse_scenario(QUIET), start_s=START), cfg.cameras[0].id)
    assert cam.set_exposure(1e6) == 100.0 and cam.set_exposure(1e-6) == 0.01
    assert cam.grab(exposure_ms=3.0).exposure_ms == 3.0 and cam.grab().exposure_ms == 3.0  # the setting stays
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="exposure_ms"):
            cam.set_exposure(bad)


def test_noise_keeps_its_read_part_and_grows_with_shot_noise():
    assert noise_scale(1.0, 0.45) == 1.0
    assert noise_scale(0.0, 0.45) == pytest.approx(0.45 ** 0.5)
    assert noise_scale(4.0, 0.45) == pytest.approx((0.45 + 0.55 * 4) ** 0.5)
    assert noise_scale(4.0, 1.0) == 1.0  # read noise only


def test_scenario_refuses_a_nominal_exposure_outside_the_range():
    from helicalib.errors import ConfigError

    with pytest.raises(ConfigError, match="exposure_ms"):
        parse_scenario({"camera": {"exposure_ms": 200.0}})
    with pytest.raises(ConfigError, match="exposure_range_ms"):
        parse_scenario({"camera": {"exposure_range_ms": [0.0, 10.0]}})


def _served(cfg, scenario):
    plant = SimulatedPlant(cfg, parse_scenario(scenario), start_s=START, rate=600.0)
    return PlantServer(plant, RateClock(START, 600.0, lambda: 0.0), modbus_port=0, camera_port=0).start()


def test_http_camera_asks_for_an_exposure_and_reads_the_applied_one(cfg):
    server = _served(cfg, QUIET)
    try:
        url = server.camera_url(cfg.cameras[0].id)
        cam = HttpCamera(url + "?lens=wide", expected_size_px=cfg.cameras[0].resolution_px)  # a query of its own
        nominal = cam.grab()
        assert nominal.exposure_ms == 1.0  # every frame carries X-Exposure-Ms, asked or not
        short = cam.grab(exposure_ms=0.25)
        assert short.exposure_ms == 0.25
        a, b = _image(nominal).astype(float), _image(short).astype(float)
        lit = (a > 20) & (a < 250)
        assert lit.sum() > 1000
        assert np.max(np.abs(b[lit] - 0.25 * a[lit])) <= 1.0
        assert cam.grab(exposure_ms=5000.0).exposure_ms == 100.0  # clamped by the camera
        assert cam.grab().exposure_ms == 100.0  # and kept
    finally:
        server.stop()


def test_http_camera_without_exposure_control_sees_no_header(cfg):
    server = _served(cfg, {"camera": {"noise_counts": 0.0, "exposure": False}})
    try:
        cam = HttpCamera(server.camera_url(cfg.cameras[0].id), expected_size_px=cfg.cameras[0].resolution_px)
        plain, asked = cam.grab(), cam.grab(exposure_ms=0.25)
        assert plain.exposure_ms is None and asked.exposure_ms is None
        assert np.array_equal(_image(plain), _image(asked))  # the parameter is ignored
    finally:
        server.stop()


class _Header(http.server.BaseHTTPRequestHandler):
    """A camera answering a fixed PNG with a given X-Exposure-Ms, and recording the path asked."""

    exposure = "abc"
    paths: list = []

    def log_message(self, *args):
        pass

    def do_GET(self):  # noqa: N802
        type(self).paths.append(self.path)
        ok, buf = cv2.imencode(".png", np.zeros((4, 4), np.uint8))
        body = buf.tobytes()
        self.send_response(200)
        self.send_header("Content-Type", "image/png")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("X-Capture-Time", "1.0")
        self.send_header("X-Exposure-Ms", self.exposure)
        self.end_headers()
        self.wfile.write(body)


@pytest.mark.parametrize("header", ["abc", "-2", "nan", "0"])
def test_an_unreadable_exposure_header_is_a_camera_error(header):
    handler = type("H", (_Header,), {"exposure": header, "paths": []})
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    try:
        cam = HttpCamera(f"http://127.0.0.1:{httpd.server_address[1]}/c1.png?exposure_ms=9&a=1", retries=0)
        with pytest.raises(CameraError) as err:
            cam.grab(exposure_ms=2.5)
        assert err.value.reason == "camera_bad_exposure" and "X-Exposure-Ms" in str(err.value)
        assert handler.paths == ["/c1.png?a=1&exposure_ms=2.5"]  # the URL's own exposure replaced
        with pytest.raises(CameraError) as err:
            cam.grab(exposure_ms=-1.0)
        assert err.value.reason == "camera_bad_exposure" and len(handler.paths) == 1  # nothing sent
    finally:
        httpd.shutdown()
        httpd.server_close()
