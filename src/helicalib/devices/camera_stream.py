"""A target camera that streams (RTSP or HTTP MJPEG), read through OpenCV's FFmpeg backend.

:class:`StreamCamera` implements :class:`helicalib.devices.protocols.Camera`. A reader thread
takes every frame off the stream as it comes (so no frame waits in a buffer to be handed out
later) and notes the real (monotonic) time it arrived. ``grab`` asks for the first frame that
arrives after the call began, the newest one then, so a frame is never older than the request,
and hands it out as an 8-bit grayscale PNG (only that frame is converted to an image).

Capture time. A stream carries no capture time the controller can trust, so a frame's capture
time is the plant time at which it arrived, less the camera's known latency: ``clock.now_s()`` at
the grab, less the frame's age since its arrival plus ``latency_s``, both in real seconds times
the clock's rate. The camera's own encoding and network delay (typically 50-300 ms for an IP
camera; measure it once against a clock shown to the camera) is ``latency_s``
(``cameras[].latency_ms``); without it capture times are late by that much.

Exposure. A stream cannot carry one; a camera with ``exposure_url`` sets it there
(``GET <exposure_url>?exposure_ms=4.5`` answers with ``X-Exposure-Ms: <applied>``, the contract of
PLANT_INTERFACE 1.1 on the control URL). After a change, ``grab`` hands out the first frame that
arrived ``latency_s`` plus :data:`SETTLE_PERIODS` frame periods after the control answered: a
frame exposed before the change arrives up to ``latency_s`` later, one in exposure at the change
a period after that, and neither is handed out as one after it. Without ``exposure_url`` the
request is ignored and ``Frame.exposure_ms`` is None.

Failures raise :class:`~helicalib.devices.camera_http.CameraError` with the HTTP camera's reason
codes: ``camera_unreachable`` (the stream cannot be opened within the deadline),
``camera_timeout`` (no new frame within it: a stalled or lost stream), ``camera_wrong_size``,
``camera_http_error`` / ``camera_no_exposure`` (the exposure control failed or answered without
``X-Exposure-Ms``). A lost stream is opened again by the next ``grab``.
"""

from __future__ import annotations

import http.client
import math
import os
import threading
import time
import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from helicalib.devices.camera_http import CameraError
from helicalib.devices.protocols import Frame

PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1]
"""Fast lossless PNG (level 1): a frame is encoded in milliseconds."""
FALLBACK_PERIOD_S = 0.2
"""Frame period assumed before two frames have arrived [real s]."""
SETTLE_PERIODS = 2
"""Frame periods waited after an exposure change beyond the camera's latency: the frame being
exposed at the change (old setting, or a mix) and one more for a camera that applies a new
setting at the frame after next."""
FFMPEG_OPTIONS_ENV = "OPENCV_FFMPEG_CAPTURE_OPTIONS"
FFMPEG_OPTIONS = "rtsp_transport;tcp|fflags;nobuffer|analyzeduration;0|probesize;32"
"""FFmpeg's options for opening a stream: RTSP over TCP (no frame lost to a dropped UDP datagram),
and no probing of the stream before the first frame (FFmpeg's default reads up to 5 s of it, which
OpenCV then hands out as a backlog of old frames: measured 2 s and 20 frames at 10 fps)."""
_OPTIONS_LOCK = threading.Lock()
REOPEN_WAIT_S = 0.2
"""Real seconds between attempts to open a stream that could not be opened, within a grab's deadline."""


class _Lost(Exception):
    """The stream ended while a grab waited (it is opened again within the grab's deadline)."""


@dataclass(frozen=True)
class Arrived:
    """A decoded frame and when it arrived (monotonic real seconds); ``number`` counts from 1."""

    image: np.ndarray
    arrived_s: float
    number: int


def open_stream(url: str, open_timeout_s: float, read_timeout_s: float):
    """``cv2.VideoCapture`` of ``url`` through FFmpeg with open and read timeouts and FFmpeg's
    options :data:`FFMPEG_OPTIONS` (``$OPENCV_FFMPEG_CAPTURE_OPTIONS`` instead, when it is set)."""
    params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, max(1, int(open_timeout_s * 1000)),
              cv2.CAP_PROP_READ_TIMEOUT_MSEC, max(1, int(read_timeout_s * 1000))]
    with _OPTIONS_LOCK:  # OpenCV reads FFmpeg's options from the environment when it opens
        own = FFMPEG_OPTIONS_ENV not in os.environ
        if own:
            os.environ[FFMPEG_OPTIONS_ENV] = FFMPEG_OPTIONS
        try:
            return cv2.VideoCapture(url, cv2.CAP_FFMPEG, params)
        finally:
            if own:
                os.environ.pop(FFMPEG_OPTIONS_ENV, None)


class _Reader:
    """One connection: a thread taking every frame of ``capture`` off the stream (``grab``: demuxed
    and decoded, so none waits in a buffer) until the stream ends or ``stop`` is set; a frame is
    converted to an image (``retrieve``) only when ``on_grabbed`` asks for it (a frame handed out):
    measured at 1280 × 1024 MJPEG, 10 fps, 5 % of a core for grab alone, 13 % for grab and retrieve."""

    def __init__(self, capture, on_grabbed: Callable[[], bool], on_image: Callable[[np.ndarray], None],
                 on_end: Callable[[str], None]):
        self.capture = capture
        self.stop = threading.Event()
        self._on_grabbed, self._on_image, self._on_end = on_grabbed, on_image, on_end
        self.thread = threading.Thread(target=self._run, daemon=True, name="helicalib-stream-reader")
        self.thread.start()

    def _run(self) -> None:
        why = "stream closed"
        try:
            while not self.stop.is_set():
                if not self.capture.grab():
                    why = "the stream ended or stalled (no frame within the read timeout)"
                    break
                if self._on_grabbed():
                    ok, image = self.capture.retrieve()
                    if not ok or image is None:
                        why = "a frame could not be decoded"
                        break
                    self._on_image(image)
        except cv2.error as exc:  # a decoder fault: the connection is given up and opened again
            why = f"decoder error: {exc}"
        finally:
            self.capture.release()
            self._on_end(why)


class StreamCamera:
    """One streaming target camera.

    Parameters
    ----------
    url : str
        ``rtsp://...`` or an HTTP MJPEG URL (``cameras[].url``).
    clock : Clock
        Plant time (:class:`helicalib.devices.protocols.Clock`) that stamps the frames.
    timeout_s : float
        Deadline of one grab [real s]: opening the stream when it is not open, and a new frame.
    expected_size_px : (int, int), optional
        (width, height) every frame must have.
    exposure_url : str, optional
        The HTTP control URL that sets the exposure (``cameras[].exposure_url``).
    latency_s : float
        Real seconds from exposure to a frame's arrival (``cameras[].latency_ms``): subtracted
        from capture times, and waited after an exposure change.
    open_capture : callable
        ``(url, open_timeout_s, read_timeout_s) -> VideoCapture``, injected (:func:`open_stream`).
    monotonic : callable
        Real time for deadlines and arrivals (``time.monotonic``), injected.
    """

    def __init__(self, url: str, *, clock, timeout_s: float = 5.0, expected_size_px: tuple[int, int] | None = None,
                 exposure_url: str | None = None, latency_s: float = 0.0,
                 open_capture: Callable[..., object] = open_stream, monotonic: Callable[[], float] = time.monotonic):
        self.url = url
        self.clock = clock
        self.timeout_s = float(timeout_s)
        self.expected_size_px = None if expected_size_px is None else (int(expected_size_px[0]), int(expected_size_px[1]))
        self.exposure_url = exposure_url
        self.latency_s = float(latency_s)
        self._open_capture = open_capture
        self._monotonic = monotonic
        self._cond = threading.Condition()
        self._newest: Arrived | None = None
        self._last_arrival_s: float | None = None
        self._wanted_after_s: float | None = None  # a grab waits for a frame that arrives after this
        self._count = 0
        self._intervals_s: list[float] = []
        self._reader: _Reader | None = None
        self._ended: str | None = None
        self.exposure_ms: float | None = None
        """The exposure the control URL last reported as applied [ms]; None before the first."""

    @classmethod
    def from_config(cls, cam, *, clock, timeout_s: float = 5.0,
                    expected_size_px: tuple[int, int] | None = None) -> StreamCamera:
        """The camera of ``cam`` (a :class:`helicalib.config.Camera` of kind ``stream``); ``clock``
        None: the computer's UTC (a plant whose clock is not read)."""
        if clock is None:
            from helicalib.devices.clock import SystemClock

            clock = SystemClock()
        return cls(cam.url, clock=clock, timeout_s=timeout_s, expected_size_px=expected_size_px,
                   exposure_url=cam.exposure_url, latency_s=float(cam.latency_ms) / 1000.0)

    # -- the reader's side -------------------------------------------------------------------

    def _grabbed(self) -> bool:
        """A frame came off the stream: note its arrival; True when a grab waits for it."""
        now = self._monotonic()
        with self._cond:
            if self._last_arrival_s is not None:
                self._intervals_s = (self._intervals_s + [now - self._last_arrival_s])[-8:]
            self._last_arrival_s = now
            self._count += 1
            return self._wanted_after_s is not None and now > self._wanted_after_s

    def _retrieved(self, image: np.ndarray) -> None:
        with self._cond:
            self._newest = Arrived(image, self._last_arrival_s, self._count)
            self._wanted_after_s = None
            self._cond.notify_all()

    def _ended_with(self, why: str) -> None:
        with self._cond:
            self._ended = why
            self._cond.notify_all()

    @property
    def frame_period_s(self) -> float:
        """The stream's frame period, the median of the last intervals between arrivals [real s]."""
        with self._cond:
            gaps = sorted(self._intervals_s)
        return gaps[len(gaps) // 2] if gaps else FALLBACK_PERIOD_S

    # -- the caller's side -------------------------------------------------------------------

    def _connect(self, end: float, why: str | None = None) -> None:
        """Open the stream and start its reader when none runs; retried until monotonic ``end``
        (``why``: how the last connection ended, for the error)."""
        reader = self._reader
        if reader is not None:
            if reader.thread.is_alive() and self._ended is None:
                return
            reader.stop.set()
            reader.thread.join(self.timeout_s + 1.0)
        last = why or "not opened"
        while True:
            left = end - self._monotonic()
            if left <= 0:
                raise CameraError("camera_unreachable", f"camera {self.url}: the stream could not be opened within "
                                                        f"{self.timeout_s:g} s ({last})", True)
            try:
                capture = self._open_capture(self.url, left, self.timeout_s)
            except cv2.error as exc:
                capture, last = None, f"OpenCV: {exc}".splitlines()[0]
            if capture is not None and capture.isOpened():
                break
            if capture is not None:
                capture.release()
            time.sleep(min(REOPEN_WAIT_S, max(0.0, end - self._monotonic())))
        with self._cond:
            self._ended = None
            self._intervals_s = []
            self._last_arrival_s = None
        self._reader = _Reader(capture, self._grabbed, self._retrieved, self._ended_with)

    def _wait_frame(self, after_s: float, end: float) -> Arrived:
        """The first frame that arrived after monotonic ``after_s`` (the newest then), waiting until ``end``."""
        with self._cond:
            self._wanted_after_s = after_s
            try:
                while True:
                    newest = self._newest
                    if newest is not None and newest.arrived_s > after_s:
                        return newest
                    if self._ended is not None:
                        raise _Lost(self._ended)
                    left = end - self._monotonic()
                    if left <= 0:
                        raise CameraError("camera_timeout", f"camera {self.url}: no new frame within "
                                                            f"{self.timeout_s:g} s", True)
                    self._cond.wait(min(left, 0.1))
            finally:
                self._wanted_after_s = None

    def grab(self, exposure_ms: float | None = None) -> Frame:
        """The newest frame that arrived after this call began (after the exposure took effect, when
        one was asked for and the camera can set it), as an 8-bit grayscale PNG."""
        start = self._monotonic()
        end = start + self.timeout_s
        self._connect(end)
        after = start
        if self.exposure_url is not None:
            if exposure_ms is not None and (self.exposure_ms is None or not math.isclose(exposure_ms, self.exposure_ms)):
                self.exposure_ms = self._control(exposure_ms, end)
                after = self._monotonic() + self.latency_s + SETTLE_PERIODS * self.frame_period_s
            elif self.exposure_ms is None:
                self.exposure_ms = self._control(None, end)
        while True:
            try:
                return self._frame(self._wait_frame(after, end))
            except _Lost as lost:  # opened again within the deadline
                self._connect(end, why=str(lost))

    def _frame(self, arrived: Arrived) -> Frame:
        image = arrived.image
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
        if image.dtype != np.uint8:
            image = (image >> (8 * image.itemsize - 8)).astype(np.uint8)
        size = (int(image.shape[1]), int(image.shape[0]))
        if self.expected_size_px is not None and size != self.expected_size_px:
            raise CameraError("camera_wrong_size", f"camera {self.url}: frame of {size[0]}×{size[1]} px, "
                                                   f"expected {self.expected_size_px[0]}×{self.expected_size_px[1]}")
        rate = float(getattr(self.clock, "rate", 1.0)) or 1.0
        age_s = self._monotonic() - arrived.arrived_s + self.latency_s
        capture = float(self.clock.now_s()) - rate * age_s
        ok, buf = cv2.imencode(".png", image, PNG_PARAMS)
        if not ok:
            raise CameraError("camera_not_image", f"camera {self.url}: frame could not be encoded as PNG")
        return Frame(data=buf.tobytes(), capture_time_s=capture, source=self.url, exposure_ms=self.exposure_ms)

    def _control(self, exposure_ms: float | None, end: float) -> float:
        """Ask the control URL for ``exposure_ms`` (None: the current setting); the applied value."""
        parts = urllib.parse.urlsplit(self.exposure_url)
        where = f"camera {self.url}: exposure control {self.exposure_url}"
        path = parts.path or "/"
        query = parts.query
        if exposure_ms is not None:
            query = (query + "&" if query else "") + urllib.parse.urlencode({"exposure_ms": f"{float(exposure_ms):g}"})
        if query:
            path += "?" + query
        left = end - self._monotonic()
        if left <= 0:
            raise CameraError("camera_timeout", f"{where}: no time left within {self.timeout_s:g} s", True)
        kind = http.client.HTTPSConnection if parts.scheme == "https" else http.client.HTTPConnection
        conn = kind(parts.hostname, parts.port, timeout=left)
        try:
            conn.request("GET", path)
            resp = conn.getresponse()
            resp.read()
        except (TimeoutError, OSError, http.client.HTTPException) as exc:
            raise CameraError("camera_unreachable", f"{where}: {type(exc).__name__}: {exc}", True) from None
        finally:
            conn.close()
        if resp.status != 200:
            raise CameraError("camera_http_error", f"{where}: HTTP {resp.status} {resp.reason}", resp.status >= 500)
        raw = resp.headers.get("X-Exposure-Ms")
        try:
            applied = float(raw)
        except (TypeError, ValueError):
            applied = math.nan
        if not (math.isfinite(applied) and applied > 0):
            raise CameraError("camera_no_exposure", f"{where}: X-Exposure-Ms header missing or unreadable ({raw!r})")
        return applied

    def close(self) -> None:
        """Stop reading (the reader releases the stream within its read timeout)."""
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.stop.set()
            reader.thread.join(self.timeout_s + 1.0)

    def __enter__(self) -> StreamCamera:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
