"""A target camera over HTTP (``PLANT_INTERFACE.md``, Camera): ``GET url`` → PNG/JPEG + ``X-Capture-Time``.

:class:`HttpCamera` implements :class:`helicalib.devices.protocols.Camera` with the standard
library only. A timeout, a refused connection, a 5xx answer or a truncated body is retried
(``retries`` times, with back-off); a 4xx answer, a body that is not an image, a missing or
unreadable capture time, or a frame of the wrong size is not. Every failure raises
:class:`CameraError` (a :class:`~helicalib.errors.MeasurementError`) whose ``reason`` is a short
code the visit records and whose message is one readable sentence.
"""

from __future__ import annotations

import http.client
import math
import socket
import struct
import time
import urllib.error
import urllib.request
from collections.abc import Callable

from helicalib.devices.protocols import Frame
from helicalib.errors import MeasurementError

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"
JPEG_MAGIC = b"\xff\xd8\xff"
JPEG_END = b"\xff\xd9"

REASONS = ("camera_timeout", "camera_unreachable", "camera_http_error", "camera_truncated", "camera_not_image",
           "camera_no_capture_time", "camera_wrong_size")
"""Reason codes of :class:`CameraError`."""


class CameraError(MeasurementError):
    """A frame could not be had; ``reason`` is one of :data:`REASONS`."""

    def __init__(self, reason: str, message: str, transient: bool = False):
        super().__init__(message)
        self.reason = reason
        self.transient = transient


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of a PNG (from its header) or a JPEG (decoded); None if not readable."""
    if data.startswith(PNG_MAGIC) and len(data) >= 24 and data[12:16] == b"IHDR":
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data.startswith(JPEG_MAGIC):
        import cv2
        import numpy as np

        img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        return None if img is None else (int(img.shape[1]), int(img.shape[0]))
    return None


class HttpCamera:
    """One target camera.

    Parameters
    ----------
    url : str
        ``camera.url`` of the field config.
    timeout_s : float
        Connect and read timeout of one request [s].
    retries : int
        Extra attempts after a transient failure.
    expected_size_px : (int, int), optional
        (width, height) every frame must have.
    backoff_s : float
        Wait before the first retry [s], doubled each time.
    sleep : callable
        Real sleep (``time.sleep``), injected.

    A camera is a device: it gives frames. Its flux calibration (FLUX.yaml) is the sensor's
    business (:func:`helicalib.campaign.sensor.camera_sensors`).
    """

    def __init__(self, url: str, timeout_s: float = 5.0, retries: int = 2, expected_size_px: tuple[int, int] | None = None,
                 backoff_s: float = 0.2, sleep: Callable[[float], None] = time.sleep):
        self.url = url
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.expected_size_px = None if expected_size_px is None else (int(expected_size_px[0]), int(expected_size_px[1]))
        self.backoff_s = float(backoff_s)
        self._sleep = sleep

    def grab(self) -> Frame:
        """The current frame; raises :class:`CameraError` after the retries."""
        delay = self.backoff_s
        for attempt in range(self.retries + 1):
            if attempt:
                self._sleep(delay)
                delay *= 2
            try:
                return self._once()
            except CameraError as err:
                if not err.transient or attempt == self.retries:
                    if err.transient and self.retries:
                        raise CameraError(err.reason, f"{err} (after {attempt + 1} attempts)") from None
                    raise
        raise AssertionError("unreachable")

    def _once(self) -> Frame:
        where = f"camera {self.url}"
        try:
            with urllib.request.urlopen(self.url, timeout=self.timeout_s) as resp:
                headers = resp.headers
                body = resp.read()
                length = headers.get("Content-Length")
        except urllib.error.HTTPError as exc:
            transient = exc.code >= 500
            raise CameraError("camera_http_error", f"{where}: HTTP {exc.code} {exc.reason}", transient) from None
        except (TimeoutError, socket.timeout) as exc:
            raise CameraError("camera_timeout", f"{where}: no answer within {self.timeout_s:g} s", True) from exc
        except http.client.IncompleteRead as exc:
            raise CameraError("camera_truncated", f"{where}: body cut short ({len(exc.partial)} bytes received)",
                              True) from None
        except urllib.error.URLError as exc:
            if isinstance(exc.reason, (TimeoutError, socket.timeout)):
                raise CameraError("camera_timeout", f"{where}: no answer within {self.timeout_s:g} s", True) from None
            raise CameraError("camera_unreachable", f"{where}: {exc.reason}", True) from None
        except (http.client.HTTPException, ConnectionError, OSError) as exc:
            raise CameraError("camera_unreachable", f"{where}: {type(exc).__name__}: {exc}", True) from None
        if length is not None and length.isdigit() and int(length) != len(body):
            raise CameraError("camera_truncated", f"{where}: body of {len(body)} bytes, Content-Length {length}", True)
        if body.startswith(PNG_MAGIC):
            if not body.rstrip(b"\x00").endswith(PNG_END):
                raise CameraError("camera_truncated", f"{where}: PNG without its end chunk ({len(body)} bytes)", True)
        elif body.startswith(JPEG_MAGIC):
            if not body.rstrip(b"\x00").endswith(JPEG_END):
                raise CameraError("camera_truncated", f"{where}: JPEG without its end marker ({len(body)} bytes)", True)
        else:
            raise CameraError("camera_not_image", f"{where}: answer is neither PNG nor JPEG "
                                                  f"({headers.get('Content-Type', 'no content type')}, {len(body)} bytes)")
        raw_time = headers.get("X-Capture-Time")
        try:
            capture = float(raw_time)
        except (TypeError, ValueError):
            capture = math.nan
        if not math.isfinite(capture):
            raise CameraError("camera_no_capture_time", f"{where}: X-Capture-Time header missing or unreadable ({raw_time!r})")
        if self.expected_size_px is not None:
            size = image_size(body)
            if size is None:
                raise CameraError("camera_not_image", f"{where}: image header unreadable")
            if size != self.expected_size_px:
                raise CameraError("camera_wrong_size", f"{where}: frame of {size[0]}×{size[1]} px, "
                                                       f"expected {self.expected_size_px[0]}×{self.expected_size_px[1]}")
        return Frame(data=body, capture_time_s=capture, source=self.url)


def cameras_from_config(cfg, timeout_s: float = 5.0, retries: int = 2) -> dict[str, HttpCamera]:
    """One :class:`HttpCamera` per target (the first camera configured for it), by target id.

    The frame size is checked against ``resolution_px`` when the camera gives it in the config.
    """
    out: dict[str, HttpCamera] = {}
    for cam in cfg.cameras:
        if cam.target not in out:
            size = cam.resolution_px if "resolution_px" in cam.model_fields_set else None
            out[cam.target] = HttpCamera(cam.url, timeout_s=timeout_s, retries=retries, expected_size_px=size)
    return out
