"""GenICamCamera at its seams. No GenTL producer and no GigE Vision / USB3 Vision camera can run
here, so the acquirer is a small stand-in shaped like harvesters' ``ImageAcquirer``
(``remote_device.node_map.<feature>.value``, ``fetch(timeout=)`` as a context manager yielding a
buffer with ``payload.components[0].data/width/height/data_format``, ``try_fetch``, ``queue()``,
``num_holding_filled_buffers``) whose device clamps its exposure like a camera does and, like a
continuously acquiring camera, keeps the next buffer filled before it is fetched (so a buffer
exposed before a change waits in it). Everything of helicalib's own is real: the unit conversion,
the pixel formats, PNG encoding, the errors, the config's producer and serial."""

from __future__ import annotations

import builtins
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


class Buffer:
    """A filled buffer: frames are ``ramp · exposure_us/1000`` counts."""

    def __init__(self, acquirer, exposure_us):
        self.acquirer, self.exposure_us = acquirer, exposure_us
        a = acquirer
        ramp = np.tile(np.arange(W, dtype=np.float64), (H, 1)) * (exposure_us / 1000.0)
        top = 2 ** a.bits - 1
        data = np.clip(ramp * 2 ** (a.bits - 8), 0, top).astype(np.uint8 if a.bits == 8 else np.uint16).ravel()
        component = types.SimpleNamespace(data=data, width=W, height=H, data_format=a.data_format)
        self.payload = types.SimpleNamespace(components=[component])

    def queue(self):
        self.acquirer.queued.append(self.exposure_us)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.queue()


class Acquirer:
    """Shaped like harvesters.core.ImageAcquirer. ``prefill``: like a camera acquiring without
    pause, the producer fills the next buffer (at the exposure then set) before it is fetched;
    ``threaded``: harvesters runs its own fetch thread (buffers wait in its queue);
    ``no_exposure``: a device without the exposure feature."""

    def __init__(self, data_format="Mono8", bits=8, timeout=False, prefill=False, threaded=False, no_exposure=False):
        features = {"Gain": Node(0.0, 0.0, 24.0)}
        if not no_exposure:
            features["ExposureTime"] = Node(1000.0, 20.0, 50_000.0)
        self.remote_device = types.SimpleNamespace(node_map=types.SimpleNamespace(**features))
        self.data_format, self.bits, self.timeout = data_format, bits, timeout
        self.prefill, self.threaded = prefill, threaded
        self.thread_image_acquisition = types.SimpleNamespace(is_running=lambda: threaded)
        self.ready: list[Buffer] = []
        self.fetched_at_us: list[float] = []
        self.queued: list[float] = []
        self.stopped = self.destroyed = False

    def _setting_us(self):
        node = getattr(self.remote_device.node_map, "ExposureTime", None)
        return 1000.0 if node is None else node.value

    @property
    def num_holding_filled_buffers(self):
        return len(self.ready) if self.threaded else 0  # harvesters' own queue: used by its thread only

    def try_fetch(self, timeout):
        assert not self.threaded, "try_fetch races harvesters' fetch thread"
        return self.ready.pop(0) if self.ready else None

    def fetch(self, timeout):
        if self.timeout:
            raise type("TimeoutException", (Exception,), {})("timed out")
        buffer = self.ready.pop(0) if self.ready else Buffer(self, self._setting_us())
        if self.prefill:
            self.ready.append(Buffer(self, self._setting_us()))
        self.fetched_at_us.append(buffer.exposure_us)
        return buffer

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


def test_a_device_without_the_exposure_feature_takes_frames_and_ignores_an_asked_exposure():
    acq = Acquirer(no_exposure=True)
    cam = GenICamCamera(acq, "genicam://A1", clock=Clock())
    assert cam.exposure_ms is None and not cam.has_exposure
    plain, asked = cam.grab(), cam.grab(exposure_ms=4.0)
    assert plain.exposure_ms is None and asked.exposure_ms is None
    assert _png(asked)[0, 50] == 50  # the device's own exposure
    named = GenICamCamera(Acquirer(), "genicam://A1", clock=Clock(), exposure_feature="ExposureTimeAbs")
    assert named.grab(exposure_ms=2.0).exposure_ms is None  # a feature name the device lacks: the same
    with pytest.raises(CameraError) as err:  # asked explicitly, it says so
        named.set_exposure(2.0)
    assert err.value.reason == "camera_no_exposure" and "ExposureTimeAbs" in str(err.value)


@pytest.mark.parametrize("threaded", [False, True], ids=["producer-queue", "harvesters-thread"])
def test_after_an_exposure_change_the_buffers_filled_before_it_are_discarded(threaded):
    acq = Acquirer(prefill=True, threaded=threaded)
    cam = GenICamCamera(acq, "genicam://A1", clock=Clock())
    assert cam.grab().exposure_ms == 1.0 and len(acq.ready) == 1  # the next buffer waits, at 1 ms
    long = cam.grab(exposure_ms=2.0)
    assert long.exposure_ms == 2.0 and _png(long)[0, 50] == 100  # exposed at 2 ms, not the waiting one
    assert 1000.0 in acq.queued  # the stale buffer went back to the producer unread
    same = cam.grab(exposure_ms=2.0)  # no change: nothing discarded
    assert _png(same)[0, 50] == 100 and acq.queued.count(2000.0) == 2  # the two frames handed out


def test_latency_shifts_capture_times_and_discards_the_buffers_in_flight():
    acq = Acquirer()
    now = [100.0]
    setting = [(0.0, 1000.0)]  # (monotonic s, exposure µs): the device's settings over time
    latency_s, period_s = 0.3, 0.1
    node = acq.remote_device.node_map.ExposureTime

    class Timed(Node):
        @Node.value.setter
        def value(self, v):
            Node.value.fset(self, v)
            setting.append((now[0], self._value))

    node.__class__ = Timed

    def fetch(timeout):  # a frame every period, exposed at the setting latency_s before it arrives
        now[0] += period_s
        exposed_at = now[0] - latency_s
        return Buffer(acq, [us for t, us in setting if t <= exposed_at][-1])

    acq.fetch = fetch
    clock = Clock()
    cam = GenICamCamera(acq, "genicam://A1", clock=clock, latency_s=latency_s, monotonic=lambda: now[0])
    frame = cam.grab()
    assert frame.capture_time_s == pytest.approx(clock.t - latency_s)
    long = cam.grab(exposure_ms=2.0)
    assert long.exposure_ms == 2.0 and _png(long)[0, 50] == 100  # the frames in flight were discarded
    assert acq.queued.count(1000.0) >= 3


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
    refusing = Acquirer()

    class Refusing(Node):  # a device that refuses out-of-range values (GenApi's OutOfRangeException)
        @Node.value.setter
        def value(self, v):
            raise type("OutOfRangeException", (Exception,), {})(f"{v} outside [20, 50000]")

    refusing.remote_device.node_map.ExposureTime.__class__ = Refusing
    with pytest.raises(CameraError) as err:  # the feature exists and fails: a camera error
        GenICamCamera(refusing, "genicam://A1", clock=Clock()).grab(exposure_ms=900.0)
    assert err.value.reason == "camera_no_exposure" and "ExposureTime refused 900 ms" in str(err.value)
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

    built = GenICamCamera.from_config(cam.model_copy(update={"latency_ms": 120.0}), cfg, clock=Clock(),
                                      open_acquirer=fake_open)
    assert opened == {"cti": str(tmp_path / "vendor.cti"), "serial": "21A0042"}
    assert built.grab().exposure_ms == 1.0 and built.latency_s == pytest.approx(0.12)

    real_import = builtins.__import__

    def no_harvesters(name, *args, **kw):
        if name.startswith("harvesters"):
            raise ImportError(name)
        return real_import(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", no_harvesters)
    with pytest.raises(ConfigError) as err:
        open_acquirer(str(tmp_path / "vendor.cti"), "21A0042", cam.id)
    assert "pip install 'helicalib[genicam]'" in str(err.value) and "\n" not in str(err.value)
