"""GenICamCamera at its seams. No GenTL producer and no GigE Vision / USB3 Vision camera can run
here, so the acquirer is a small stand-in shaped like harvesters' ``ImageAcquirer``
(``remote_device.node_map.<feature>.value``, ``fetch(timeout=)`` as a context manager yielding a
buffer with ``payload.components[0].data/width/height/data_format``) whose device clamps its
exposure like a camera does. Everything of helicalib's own is real: the unit conversion, the
pixel formats, PNG encoding, the errors, the config's producer and serial."""

from __future__ import annotations

import builtins
import contextlib
import types

import cv2
import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.devices.camera_genicam import GenICamCamera, open_acquirer, producer_path, serial_of, to_mono8
from helicalib.devices.camera_http import CameraError
from helicalib.errors import ConfigError

W, H = 96, 64


class Clock:
    rate = 1.0
    uncertainty_s = 0.0

    def __init__(self):
        self.t = 1_790_000_000.0

    def now_s(self):
        self.t += 0.5
        return self.t

    estimate_s = now_s


class Node:
    def __init__(self, value, lo=None, hi=None):
        self._value, self.lo, self.hi = value, lo, hi

    @property
    def value(self):
        return self._value

    @value.setter
    def value(self, v):
        if self.lo is not None:
            v = min(max(v, self.lo), self.hi)  # the device clamps
        self._value = v


class Acquirer:
    """Shaped like harvesters.core.ImageAcquirer; frames are ``ramp · ExposureTime/1000`` counts."""

    def __init__(self, data_format="Mono8", bits=8, timeout=False):
        self.remote_device = types.SimpleNamespace(node_map=types.SimpleNamespace(
            ExposureTime=Node(1000.0, 20.0, 50_000.0), Gain=Node(0.0, 0.0, 24.0)))
        self.data_format, self.bits, self.timeout = data_format, bits, timeout
        self.fetched_at_us: list[float] = []
        self.stopped = self.destroyed = False

    @contextlib.contextmanager
    def fetch(self, timeout):
        if self.timeout:
            raise type("TimeoutException", (Exception,), {})("timed out")
        exposure_us = self.remote_device.node_map.ExposureTime.value
        self.fetched_at_us.append(exposure_us)
        ramp = np.tile(np.arange(W, dtype=np.float64), (H, 1)) * (exposure_us / 1000.0)
        top = 2 ** self.bits - 1
        data = np.clip(ramp * 2 ** (self.bits - 8), 0, top).astype(np.uint8 if self.bits == 8 else np.uint16).ravel()
        component = types.SimpleNamespace(data=data, width=W, height=H, data_format=self.data_format)
        yield types.SimpleNamespace(payload=types.SimpleNamespace(components=[component]))

    def stop(self):
        self.stopped = True

    def destroy(self):
        self.destroyed = True


def _png(frame) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.ndim == 2 and img.dtype == np.uint8
    return img


def test_exposure_in_ms_is_written_in_microseconds_and_read_back_clamped():
    acq = Acquirer()
    cam = GenICamCamera(acq, "genicam://A1", clock=Clock(), expected_size_px=(W, H))
    frame = cam.grab()
    assert frame.exposure_ms == 1.0 and frame.source == "genicam://A1"
    assert _png(frame)[0, 50] == 50
    long = cam.grab(exposure_ms=2.0)
    assert acq.remote_device.node_map.ExposureTime.value == 2000.0 and long.exposure_ms == 2.0
    assert _png(long)[0, 50] == 100 and acq.fetched_at_us[-1] == 2000.0  # fetched after the setting
    assert cam.grab(exposure_ms=500.0).exposure_ms == 50.0  # the device's range
    assert cam.set_gain(30.0) == 24.0
    assert long.capture_time_s > frame.capture_time_s  # plant time at each fetch
    cam.close()
    assert acq.stopped and acq.destroyed


@pytest.mark.parametrize("fmt, bits", [("Mono10", 10), ("Mono12", 12), ("Mono16", 16)])
def test_deeper_mono_formats_keep_their_top_8_bits(fmt, bits):
    cam = GenICamCamera(Acquirer(fmt, bits), "genicam://A1", clock=Clock())
    img = _png(cam.grab())
    assert img[0, 50] == 50 and img[0, 95] == 95


def test_faults_are_camera_errors_with_reasons():
    with pytest.raises(CameraError) as err:
        GenICamCamera(Acquirer("BayerRG8"), "genicam://A1", clock=Clock()).grab()
    assert err.value.reason == "camera_not_image" and "BayerRG8" in str(err.value)
    with pytest.raises(CameraError) as err:
        GenICamCamera(Acquirer(), "genicam://A1", clock=Clock(), expected_size_px=(640, 480)).grab()
    assert err.value.reason == "camera_wrong_size" and "96×64" in str(err.value)
    with pytest.raises(CameraError) as err:
        GenICamCamera(Acquirer(timeout=True), "genicam://A1", clock=Clock(), timeout_s=0.5).grab()
    assert err.value.reason == "camera_timeout" and "0.5 s" in str(err.value)
    with pytest.raises(CameraError) as err:
        GenICamCamera(Acquirer(), "genicam://A1", clock=Clock(), exposure_feature="ExposureTimeAbs").grab()
    assert err.value.reason == "camera_no_exposure" and "ExposureTimeAbs" in str(err.value)
    with pytest.raises(CameraError) as err:
        to_mono8(np.zeros(10, np.uint8), W, H, "Mono8", "camera X")
    assert err.value.reason == "camera_truncated"


def test_config_serial_producer_and_the_missing_extra(demo_field_path, tmp_path, monkeypatch):
    cfg = load_field_config(demo_field_path)
    assert serial_of("genicam://21A0042") == "21A0042"
    with pytest.raises(ConfigError, match="genicam://<serial number>"):
        serial_of("http://cam/1")
    cam = cfg.cameras[0].model_copy(update={"kind": "genicam", "url": "genicam://21A0042", "genicam": None})
    monkeypatch.delenv("GENICAM_GENTL64_PATH", raising=False)
    with pytest.raises(ConfigError, match="no GenTL producer"):
        producer_path(cam, cfg)
    (tmp_path / "vendor.cti").write_bytes(b"")
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path))
    assert producer_path(cam, cfg) == str(tmp_path / "vendor.cti")

    opened = {}

    def fake_open(cti, serial, camera_id):
        opened.update(cti=cti, serial=serial)
        return Acquirer()

    built = GenICamCamera.from_config(cam, cfg, clock=Clock(), open_acquirer=fake_open)
    assert opened == {"cti": str(tmp_path / "vendor.cti"), "serial": "21A0042"}
    assert built.grab().exposure_ms == 1.0

    real_import = builtins.__import__

    def no_harvesters(name, *args, **kw):
        if name.startswith("harvesters"):
            raise ImportError(name)
        return real_import(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", no_harvesters)
    with pytest.raises(ConfigError) as err:
        open_acquirer(str(tmp_path / "vendor.cti"), "21A0042", cam.id)
    assert "pip install 'helicalib[genicam]'" in str(err.value) and "\n" not in str(err.value)
