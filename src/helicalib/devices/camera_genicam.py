"""A GigE Vision / USB3 Vision target camera through a GenTL producer and ``harvesters``
(the optional extra ``helicalib[genicam]``).

:class:`GenICamCamera` implements :class:`helicalib.devices.protocols.Camera`. The device is found
by its serial number (``url: genicam://<serial>``) through the GenTL producer (``genicam.cti``,
or ``$GENICAM_GENTL64_PATH``). Exposure and gain are GenICam features (SFNC ``ExposureTime`` in
microseconds, ``Gain`` in dB, or the names ``genicam.exposure_feature`` / ``gain_feature`` give);
the applied value is read back from the device. A device without the exposure feature sets its
own: its frames carry ``exposure_ms=None`` and an asked exposure is ignored. A frame is fetched
from the acquisition with the grab's deadline, turned into 8-bit mono (Mono10/12/14/16 shifted
down to their top 8 bits; a colour format is refused) and PNG-encoded. Its capture time is the
plant time at which the buffer was fetched less the camera's latency ``latency_s`` (the device's
own timestamp counts in its own clock, which the plant does not share).

After an exposure change the buffers already filled (exposed at the old setting) are handed back
unread: those harvesters holds (``num_holding_filled_buffers``) and those the producer has ready
(``try_fetch``), and every buffer fetched less than ``latency_s`` after the change.

The acquirer is harvesters' ``ImageAcquirer``; tests hand in an object of the same shape (see
``docs/cameras.md``: no GenTL producer and no camera are available to the test suite).
"""

from __future__ import annotations

import math
import os
import time
import urllib.parse

import cv2
import numpy as np

from helicalib.devices.camera_http import CameraError
from helicalib.devices.protocols import Frame
from helicalib.errors import ConfigError

PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1]
GENTL_ENV = "GENICAM_GENTL64_PATH"
MONO_BITS = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono14": 14, "Mono16": 16}
"""Pixel formats (PFNC names) taken, and their significant bits."""
US_PER_MS = 1000.0
DRAIN_WAIT_S = 0.001
"""How long a drain waits for a buffer the producer already has ready [real s]."""
MAX_DRAINED = 64
"""At most this many filled buffers are handed back after an exposure change (more than a
producer announces)."""


def serial_of(url: str) -> str:
    """The serial number of ``genicam://<serial>``; ConfigError otherwise."""
    parts = urllib.parse.urlsplit(url)
    serial = parts.netloc or parts.path.lstrip("/")
    if parts.scheme != "genicam" or not serial:
        raise ConfigError(f"camera url {url!r}: a GenICam camera's url is genicam://<serial number>")
    return serial


def producer_path(cam, cfg) -> str:
    """The GenTL producer (.cti) of ``cam``: ``genicam.cti`` next to the field config, else the first
    file of ``$GENICAM_GENTL64_PATH`` (a directory or a list of them) that ends in ``.cti``."""
    cti = cam.genicam.cti if cam.genicam is not None else None
    if cti:
        return str(cfg.resolve_path(cti))
    for folder in os.environ.get(GENTL_ENV, "").split(os.pathsep):
        if folder.endswith(".cti") and os.path.isfile(folder):
            return folder
        if os.path.isdir(folder):
            for name in sorted(os.listdir(folder)):
                if name.endswith(".cti"):
                    return os.path.join(folder, name)
    raise ConfigError(f"camera {cam.id}: no GenTL producer: set cameras[].genicam.cti or ${GENTL_ENV}")


def open_acquirer(cti: str, serial: str, camera_id: str):
    """harvesters' ``ImageAcquirer`` of the device ``serial`` through the producer ``cti``, started."""
    try:
        from harvesters.core import Harvester
    except ImportError:
        raise ConfigError(f"camera {camera_id}: a GenICam camera needs harvesters: "
                          "pip install 'helicalib[genicam]'") from None
    harvester = Harvester()
    harvester.add_file(cti)
    harvester.update()
    serials = [str(getattr(info, "serial_number", "")) for info in harvester.device_info_list]
    if serial not in serials:
        harvester.reset()
        raise CameraError("camera_unreachable", f"camera {camera_id}: no GenICam device with serial {serial} "
                                                f"through {cti} (found: {', '.join(serials) or 'none'})", True)
    acquirer = harvester.create({"serial_number": serial})
    acquirer.start()
    return acquirer


def to_mono8(data: np.ndarray, width: int, height: int, data_format: str, where: str) -> np.ndarray:
    """(height, width) uint8 of a mono buffer; higher bit depths keep their top 8 bits."""
    bits = MONO_BITS.get(str(data_format))
    if bits is None:
        raise CameraError("camera_not_image", f"{where}: pixel format {data_format} is not taken (Mono8/10/12/14/16)")
    flat = np.asarray(data)
    if flat.size != width * height:
        raise CameraError("camera_truncated", f"{where}: buffer of {flat.size} pixels for {width}×{height}", True)
    image = flat.reshape(height, width)
    if bits > 8:
        image = (image.astype(np.uint16) >> (bits - 8)).astype(np.uint8)
    return image.astype(np.uint8, copy=False)


class GenICamCamera:
    """One GenICam target camera.

    Parameters
    ----------
    acquirer : object
        harvesters' ``ImageAcquirer`` (started), or an object of its shape.
    source : str
        Where the frames come from (``cameras[].url``), for ``Frame.source`` and messages.
    clock : Clock
        Plant time that stamps the frames.
    timeout_s : float
        Deadline of one fetch [real s].
    expected_size_px : (int, int), optional
    exposure_feature, gain_feature : str
        The node names of exposure [µs] and gain.
    latency_s : float
        Real seconds from exposure to a buffer's fetch (``cameras[].latency_ms``): subtracted from
        capture times, and buffers fetched sooner after an exposure change are discarded.
    monotonic : callable
        Real time for deadlines (``time.monotonic``), injected.
    """

    def __init__(self, acquirer, source: str, *, clock, timeout_s: float = 5.0,
                 expected_size_px: tuple[int, int] | None = None, exposure_feature: str = "ExposureTime",
                 gain_feature: str = "Gain", latency_s: float = 0.0, monotonic=time.monotonic):
        self.acquirer = acquirer
        self.source = source
        self.clock = clock
        self.timeout_s = float(timeout_s)
        self.expected_size_px = None if expected_size_px is None else (int(expected_size_px[0]), int(expected_size_px[1]))
        self.exposure_feature = exposure_feature
        self.gain_feature = gain_feature
        self.latency_s = float(latency_s)
        self._monotonic = monotonic

    @classmethod
    def from_config(cls, cam, cfg, *, clock, timeout_s: float = 5.0,
                    expected_size_px: tuple[int, int] | None = None, open_acquirer=open_acquirer) -> GenICamCamera:
        """The camera of ``cam`` (``kind: genicam``) of field config ``cfg``; ``clock`` None: UTC."""
        if clock is None:
            from helicalib.devices.clock import SystemClock

            clock = SystemClock()
        serial = serial_of(cam.url)
        acquirer = open_acquirer(producer_path(cam, cfg), serial, cam.id)
        features = cam.genicam
        return cls(acquirer, cam.url, clock=clock, timeout_s=timeout_s, expected_size_px=expected_size_px,
                   exposure_feature=features.exposure_feature if features else "ExposureTime",
                   gain_feature=features.gain_feature if features else "Gain",
                   latency_s=float(cam.latency_ms) / 1000.0)

    def _node(self, name: str):
        node = getattr(self.acquirer.remote_device.node_map, name, None)
        if node is None:
            raise CameraError("camera_no_exposure", f"camera {self.source}: the device has no feature {name}")
        return node

    @property
    def has_exposure(self) -> bool:
        """Whether the device has the exposure feature (one without it sets its own exposure)."""
        return getattr(self.acquirer.remote_device.node_map, self.exposure_feature, None) is not None

    @property
    def exposure_ms(self) -> float | None:
        """The exposure the device applies [ms] (read back); None for a device without the feature."""
        if not self.has_exposure:
            return None
        try:
            return float(self._node(self.exposure_feature).value) / US_PER_MS
        except CameraError:
            raise
        except Exception as exc:  # GenApi's AccessException and kin
            raise CameraError("camera_no_exposure", f"camera {self.source}: {self.exposure_feature} unreadable "
                                                    f"({type(exc).__name__}: {exc})") from None

    def set_exposure(self, exposure_ms: float) -> float:
        """Write the exposure [ms] (the device clamps or refuses out of its range); the applied value."""
        if not (math.isfinite(exposure_ms) and exposure_ms > 0):
            raise ValueError(f"exposure_ms must be a positive number, got {exposure_ms!r}")
        node = self._node(self.exposure_feature)
        try:
            node.value = float(exposure_ms) * US_PER_MS
        except Exception as exc:  # GenApi's OutOfRangeException and kin: report, do not crash a visit
            raise CameraError("camera_no_exposure", f"camera {self.source}: {self.exposure_feature} refused "
                                                    f"{exposure_ms:g} ms ({type(exc).__name__}: {exc})") from None
        return self.exposure_ms

    @property
    def gain(self) -> float:
        return float(self._node(self.gain_feature).value)

    def set_gain(self, gain: float) -> float:
        """Write the gain (the device's unit, dB by SFNC); the applied value."""
        node = self._node(self.gain_feature)
        try:
            node.value = float(gain)
        except Exception as exc:
            raise CameraError("camera_no_exposure", f"camera {self.source}: {self.gain_feature} refused {gain:g} "
                                                    f"({type(exc).__name__}: {exc})") from None
        return self.gain

    def grab(self, exposure_ms: float | None = None) -> Frame:
        """A frame exposed after the exposure (when given and the device has the feature) was
        applied, as an 8-bit grayscale PNG."""
        where = f"camera {self.source}"
        end = self._monotonic() + self.timeout_s
        applied = self.exposure_ms
        if exposure_ms is not None and applied is not None and not math.isclose(exposure_ms, applied):
            applied = self.set_exposure(exposure_ms)
            self._discard_filled(self._monotonic() + self.latency_s, end)
        image = self._fetch(end, keep=True)
        rate = float(getattr(self.clock, "rate", 1.0)) or 1.0
        capture = float(self.clock.now_s()) - rate * self.latency_s
        size = (int(image.shape[1]), int(image.shape[0]))
        if self.expected_size_px is not None and size != self.expected_size_px:
            raise CameraError("camera_wrong_size", f"{where}: frame of {size[0]}×{size[1]} px, "
                                                   f"expected {self.expected_size_px[0]}×{self.expected_size_px[1]}")
        ok, buf = cv2.imencode(".png", image, PNG_PARAMS)
        if not ok:
            raise CameraError("camera_not_image", f"{where}: frame could not be encoded as PNG")
        return Frame(data=buf.tobytes(), capture_time_s=capture, source=self.source, exposure_ms=applied)

    def _fetch(self, end: float, keep: bool) -> np.ndarray | None:
        """The next buffer within monotonic ``end``, as 8-bit mono when ``keep`` (else handed back unread)."""
        where = f"camera {self.source}"
        left = end - self._monotonic()
        if left <= 0:  # harvesters waits without end for a timeout of 0
            raise CameraError("camera_timeout", f"{where}: no frame within {self.timeout_s:g} s", True)
        try:
            with self.acquirer.fetch(timeout=left) as buffer:  # the buffer goes back to the producer after
                if not keep:
                    return None
                component = buffer.payload.components[0]
                image = to_mono8(component.data, int(component.width), int(component.height),
                                 str(component.data_format), where)
                return image.copy()
        except CameraError:
            raise
        except Exception as exc:  # harvesters' TimeoutException, a lost device
            if "timeout" in type(exc).__name__.lower() or self._monotonic() >= end:
                raise CameraError("camera_timeout", f"{where}: no frame within {self.timeout_s:g} s", True) from None
            raise CameraError("camera_unreachable", f"{where}: {type(exc).__name__}: {exc}", True) from None

    def _discard_filled(self, until: float, end: float) -> None:
        """Hand back the buffers filled before an exposure change: those harvesters holds, those
        the producer has ready, and those fetched before monotonic ``until`` (the latency)."""
        acquirer = self.acquirer
        for _ in range(min(MAX_DRAINED, int(getattr(acquirer, "num_holding_filled_buffers", 0) or 0))):
            self._fetch(end, keep=False)
        try_fetch = getattr(acquirer, "try_fetch", None)
        if try_fetch is not None and not _runs_thread(acquirer):
            for _ in range(MAX_DRAINED):
                buffer = try_fetch(timeout=DRAIN_WAIT_S)
                if buffer is None:
                    break
                buffer.queue()
        while self._monotonic() < until:
            self._fetch(end, keep=False)

    def close(self) -> None:
        """Stop the acquisition and give the device back."""
        for step in ("stop", "destroy"):
            fn = getattr(self.acquirer, step, None)
            if fn is not None:
                fn()


def _runs_thread(acquirer) -> bool:
    """Whether harvesters fetches in its own thread (its buffers then wait in its queue, counted by
    ``num_holding_filled_buffers``, and ``try_fetch`` would race that thread)."""
    thread = getattr(acquirer, "thread_image_acquisition", None)
    running = getattr(thread, "is_running", None)
    return bool(running()) if callable(running) else False
