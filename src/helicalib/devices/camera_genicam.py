"""A GigE Vision / USB3 Vision target camera through a GenTL producer and ``harvesters``
(the optional extra ``helicalib[genicam]``).

:class:`GenICamCamera` implements :class:`helicalib.devices.protocols.Camera`. The device is found
by its serial number (``url: genicam://<serial>``) through the GenTL producer (``genicam.cti``,
or ``$GENICAM_GENTL64_PATH``). Exposure and gain are GenICam features (SFNC ``ExposureTime`` in
microseconds, ``Gain`` in dB, or the names ``genicam.exposure_feature`` / ``gain_feature`` give);
the applied value is read back from the device. A frame is fetched from the acquisition with the
grab's deadline, turned into 8-bit mono (Mono10/12/14/16 shifted down to their top 8 bits; a
colour format is refused) and PNG-encoded. Its capture time is the plant time at which the
buffer was fetched (the device's own timestamp counts in its own clock, which the plant does
not share).

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
    """

    def __init__(self, acquirer, source: str, *, clock, timeout_s: float = 5.0,
                 expected_size_px: tuple[int, int] | None = None, exposure_feature: str = "ExposureTime",
                 gain_feature: str = "Gain"):
        self.acquirer = acquirer
        self.source = source
        self.clock = clock
        self.timeout_s = float(timeout_s)
        self.expected_size_px = None if expected_size_px is None else (int(expected_size_px[0]), int(expected_size_px[1]))
        self.exposure_feature = exposure_feature
        self.gain_feature = gain_feature

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
                   gain_feature=features.gain_feature if features else "Gain")

    def _node(self, name: str):
        node = getattr(self.acquirer.remote_device.node_map, name, None)
        if node is None:
            raise CameraError("camera_no_exposure", f"camera {self.source}: the device has no feature {name}")
        return node

    @property
    def exposure_ms(self) -> float:
        """The exposure the device applies [ms] (read back)."""
        return float(self._node(self.exposure_feature).value) / US_PER_MS

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
        """A frame fetched after the exposure (when given) was applied, as an 8-bit grayscale PNG."""
        if exposure_ms is not None and not math.isclose(exposure_ms, self.exposure_ms):
            self.set_exposure(exposure_ms)
        applied = self.exposure_ms
        where = f"camera {self.source}"
        start = time.monotonic()
        try:
            with self.acquirer.fetch(timeout=self.timeout_s) as buffer:
                component = buffer.payload.components[0]
                image = to_mono8(component.data, int(component.width), int(component.height),
                                 str(component.data_format), where)
                image = image.copy()  # the buffer goes back to the producer on leaving the block
        except CameraError:
            raise
        except Exception as exc:  # harvesters' TimeoutException, a lost device
            if "timeout" in type(exc).__name__.lower() or time.monotonic() - start >= self.timeout_s:
                raise CameraError("camera_timeout", f"{where}: no frame within {self.timeout_s:g} s", True) from None
            raise CameraError("camera_unreachable", f"{where}: {type(exc).__name__}: {exc}", True) from None
        capture = float(self.clock.now_s())
        size = (int(image.shape[1]), int(image.shape[0]))
        if self.expected_size_px is not None and size != self.expected_size_px:
            raise CameraError("camera_wrong_size", f"{where}: frame of {size[0]}×{size[1]} px, "
                                                   f"expected {self.expected_size_px[0]}×{self.expected_size_px[1]}")
        ok, buf = cv2.imencode(".png", image, PNG_PARAMS)
        if not ok:
            raise CameraError("camera_not_image", f"{where}: frame could not be encoded as PNG")
        return Frame(data=buf.tobytes(), capture_time_s=capture, source=self.source, exposure_ms=applied)

    def close(self) -> None:
        """Stop the acquisition and give the device back."""
        for step in ("stop", "destroy"):
            fn = getattr(self.acquirer, step, None)
            if fn is not None:
                fn()
