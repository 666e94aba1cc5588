"""A target camera over HTTP (``PLANT_INTERFACE.md``, Camera): ``GET url`` → PNG/JPEG + ``X-Capture-Time``.

:class:`HttpCamera` implements :class:`helicalib.devices.protocols.Camera` with the standard
library only. A timeout, a refused connection, a 5xx answer or a truncated body is retried
(``retries`` times, with back-off); a 4xx answer, a body that is not an image, a missing or
unreadable capture time, or a frame of the wrong size is not. Every fetch has a whole-request
deadline (monotonic; the name is resolved and the connection made within it, and a watchdog shuts
the socket when it passes, so a camera trickling its answer cannot hold the controller; one
redirect is followed within the same deadline) and a size cap from the frame's expected size (an endless body cannot
fill the memory). Every failure raises
:class:`CameraError` (a :class:`~helicalib.errors.MeasurementError`) whose ``reason`` is a short
code the visit records and whose message is one readable sentence.

Exposure (interface 1.1): ``grab(exposure_ms=x)`` asks for ``x`` ms through the query parameter
``exposure_ms`` (added to any query the URL has); the frame's ``X-Exposure-Ms`` header, the
exposure the camera applied, goes into ``Frame.exposure_ms`` (None without the header: a camera
that cannot set its exposure and ignores the parameter).
"""

from __future__ import annotations

import http.client
import ipaddress
import math
import socket
import struct
import threading
import time
import urllib.parse
from collections.abc import Callable

from helicalib.devices.protocols import Frame
from helicalib.errors import MeasurementError

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"
JPEG_MAGIC = b"\xff\xd8\xff"
JPEG_END = b"\xff\xd9"
REDIRECTS = (301, 302, 303, 307, 308)
"""Answers whose ``Location`` is followed, once per fetch (a camera behind a proxy or moved)."""

REASONS = ("camera_timeout", "camera_unreachable", "camera_http_error", "camera_truncated", "camera_not_image",
           "camera_no_capture_time", "camera_wrong_size", "camera_deadline", "camera_too_large",
           "camera_bad_exposure")
"""Reason codes of :class:`CameraError`."""

DEADLINE_S = 10.0
"""Real seconds a whole frame fetch (connection, answer, retries) may take by default. A frame of a
few megabytes crosses a plant's LAN in well under a second; a camera that needs longer is faulty,
and the controller must go on (its weather reads, status and stow)."""
CHUNK_BYTES = 64 * 1024
"""Bytes asked of the socket per read (a read returns what has arrived, up to this)."""
FRAME_CAP_UNKNOWN_BYTES = 128 * 1024 * 1024
"""The most an answer may hold when the camera's frame size is not configured (a 4096 × 4096 frame
of 16-bit RGB stored without compression is 100 MB)."""


def frame_cap_bytes(size_px: tuple[int, int] | None) -> int:
    """The most a frame of ``size_px`` (width, height) can take as PNG or JPEG: every pixel at 4
    channels of 16 bits (8 bytes) uncompressed, PNG's filter byte per row, zlib's 5 bytes per
    stored block of 64 KiB and chunk headers (under 1 %), plus 64 KiB for the file's other chunks;
    :data:`FRAME_CAP_UNKNOWN_BYTES` when the size is not known."""
    if size_px is None:
        return FRAME_CAP_UNKNOWN_BYTES
    w, h = int(size_px[0]), int(size_px[1])
    raw = h * (w * 8 + 1)
    return int(raw * 1.01) + 64 * 1024


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
    deadline_s : float, optional
        The whole frame fetch, every attempt and wait included, ends within this many real seconds
        (:data:`DEADLINE_S` by default; a read waits at most what is left of it): a camera that trickles its
        answer (a few bytes every half second, each read within ``timeout_s``) raises
        ``camera_deadline`` instead of holding the controller for hours.
    max_bytes : int, optional
        The most an answer may hold (:func:`frame_cap_bytes` of ``expected_size_px`` by default):
        a longer body, or one without end and without ``Content-Length``, raises
        ``camera_too_large`` once that much has arrived (memory stays bounded).
    monotonic : callable
        Real time for the deadline (``time.monotonic``), injected.
    resolve : callable
        ``socket.getaddrinfo``, injected: the camera's host name is resolved within the deadline (a
        resolver that does not answer ends the fetch as ``camera_deadline``).

    A camera is a device: it gives frames. Its flux calibration (FLUX.yaml) is the sensor's
    business (:func:`helicalib.campaign.sensor.camera_sensors`).
    """

    def __init__(self, url: str, timeout_s: float = 5.0, retries: int = 2, expected_size_px: tuple[int, int] | None = None,
                 backoff_s: float = 0.2, sleep: Callable[[float], None] = time.sleep, deadline_s: float | None = None,
                 max_bytes: int | None = None, monotonic: Callable[[], float] = time.monotonic,
                 resolve: Callable[..., list] = socket.getaddrinfo):
        self.url = url
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.expected_size_px = None if expected_size_px is None else (int(expected_size_px[0]), int(expected_size_px[1]))
        self.backoff_s = float(backoff_s)
        self._sleep = sleep
        self.deadline_s = float(DEADLINE_S if deadline_s is None else deadline_s)
        self.max_bytes = int(max_bytes) if max_bytes is not None else frame_cap_bytes(self.expected_size_px)
        self._monotonic = monotonic
        self._resolve = resolve
        self._parts = urllib.parse.urlsplit(url)

    def grab(self, exposure_ms: float | None = None) -> Frame:
        """The current frame, taken at ``exposure_ms`` [ms] if given (interface 1.1; a camera without
        exposure control ignores it); raises :class:`CameraError` after the retries, or when the
        fetch's deadline passes (``camera_deadline``: no further attempt)."""
        parts = None if exposure_ms is None else self._with_exposure(exposure_ms)
        delay = self.backoff_s
        end = self._monotonic() + self.deadline_s
        for attempt in range(self.retries + 1):
            if attempt:
                wait = min(delay, max(0.0, end - self._monotonic()))
                self._sleep(wait)
                delay *= 2
            try:
                return self._once(end, parts, asked=parts is not None)
            except CameraError as err:
                out_of_time = self._monotonic() >= end
                if err.transient and out_of_time and attempt < self.retries:
                    # attempts were left but the time was not (an attempt's timeout ends at the
                    # deadline, the watchdog's or the socket's firing first): the deadline ended it
                    raise CameraError("camera_deadline", f"{err}; no further attempt within the fetch's "
                                                         f"deadline of {self.deadline_s:g} s") from None
                if not err.transient or attempt == self.retries or out_of_time:
                    if err.transient and attempt:
                        raise CameraError(err.reason, f"{err} (after {attempt + 1} attempts)") from None
                    raise
        raise AssertionError("unreachable")

    def _with_exposure(self, exposure_ms: float):
        """The camera's address with ``exposure_ms=<value>`` in its query (any other parameter kept,
        an ``exposure_ms`` of the URL replaced)."""
        value = float(exposure_ms)
        if not (math.isfinite(value) and value > 0):
            raise CameraError("camera_bad_exposure", f"camera {self.url}: exposure {exposure_ms!r} ms asked; "
                                                     "it must be a positive number")
        query = [(k, v) for k, v in urllib.parse.parse_qsl(self._parts.query, keep_blank_values=True)
                 if k != "exposure_ms"]
        query.append(("exposure_ms", f"{value:.6g}"))
        return self._parts._replace(query=urllib.parse.urlencode(query))

    def _connection(self, parts, timeout_s: float, end: float, where: str) -> http.client.HTTPConnection:
        kind = http.client.HTTPSConnection if parts.scheme == "https" else http.client.HTTPConnection
        conn = kind(parts.hostname, parts.port, timeout=timeout_s)
        # the name is resolved within the deadline (the watchdog cannot shut a socket that does not exist yet)
        conn._create_connection = lambda address, timeout, source=None: socket.create_connection(
            self._address(address, end, where), timeout, source)
        return conn

    def _address(self, address: tuple[str, int], end: float, where: str) -> tuple[str, int]:
        """``(host, port)`` resolved to an address, waiting at most until monotonic time ``end``."""
        try:
            ipaddress.ip_address(address[0])
            return address  # an address already: nothing to resolve
        except ValueError:
            pass
        found: dict[str, object] = {}

        def resolve() -> None:
            try:
                found["info"] = self._resolve(address[0], address[1], type=socket.SOCK_STREAM)
            except OSError as exc:
                found["error"] = exc

        worker = threading.Thread(target=resolve, daemon=True, name="helicalib-camera-resolve")
        worker.start()
        worker.join(max(0.0, end - self._monotonic()))
        if worker.is_alive():
            raise CameraError("camera_deadline", f"{where}: the name {address[0]} was not resolved within the "
                                                 f"fetch's deadline of {self.deadline_s:g} s")
        if "error" in found or not found.get("info"):
            raise CameraError("camera_unreachable", f"{where}: the name {address[0]} cannot be resolved "
                                                    f"({found.get('error', 'no address')})", True)
        return found["info"][0][4][:2]

    def _once(self, end: float, parts=None, asked: bool = False) -> Frame:
        """One request, ended (its socket shut) at monotonic time ``end`` whatever the server does;
        ``parts``: the address to ask (the camera's with an exposure when ``asked``, or the one a
        redirect gave: one is followed)."""
        redirected = parts is not None and not asked
        parts = parts or self._parts
        where = f"camera {self.url}" + (f" (redirected to {urllib.parse.urlunsplit(parts)})" if redirected else "")
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise CameraError("camera_unreachable", f"{where}: not an http:// or https:// address")
        left = end - self._monotonic()
        if left <= 0:
            raise CameraError("camera_deadline", f"{where}: no frame within the fetch's deadline of "
                                                 f"{self.deadline_s:g} s")
        conn = self._connection(parts, min(self.timeout_s, left), end, where)
        cut = threading.Event()

        def shut() -> None:  # the watchdog: a blocked read returns at once once the socket is shut
            cut.set()
            sock = conn.sock
            if sock is not None:
                try:
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

        watchdog = threading.Timer(left, shut)
        watchdog.daemon = True
        path = parts.path or "/"
        if parts.query:
            path += "?" + parts.query
        try:
            watchdog.start()
            try:
                conn.request("GET", path, headers={"Accept": "image/png, image/jpeg"})
                resp = conn.getresponse()
                headers = resp.headers
                length = headers.get("Content-Length")
                follow = self._redirect(resp, parts, redirected)
                if follow is None:
                    self._check_answer(resp, length, where)
                    body = self._body(resp, end, where)
            except CameraError:
                raise
            except (TimeoutError, socket.timeout) as exc:
                if cut.is_set():
                    raise self._late(where) from None
                raise CameraError("camera_timeout", f"{where}: no answer within {self.timeout_s:g} s", True) from exc
            except http.client.IncompleteRead as exc:
                if cut.is_set():
                    raise self._late(where) from None
                raise CameraError("camera_truncated", f"{where}: body cut short ({len(exc.partial)} bytes received)",
                                  True) from None
            except (http.client.HTTPException, ConnectionError, OSError) as exc:
                if cut.is_set():
                    raise self._late(where) from None
                raise CameraError("camera_unreachable", f"{where}: {type(exc).__name__}: {exc}", True) from None
        finally:
            watchdog.cancel()
            conn.close()
        if follow is not None:  # within the same deadline
            return self._once(end, follow)
        return self._frame(body, headers, length, where)

    @staticmethod
    def _redirect(resp, parts, redirected: bool):
        """The address a redirect answer points to (the first of a fetch only), else None."""
        location = resp.headers.get("Location")
        if resp.status not in REDIRECTS or not location or redirected:
            return None
        return urllib.parse.urlsplit(urllib.parse.urljoin(urllib.parse.urlunsplit(parts), location))

    def _check_answer(self, resp, length: str | None, where: str) -> None:
        """Refuse an error answer (a second redirect included) or one announcing more than a frame."""
        if resp.status >= 300:
            more = " (a second redirect: one is followed)" if resp.status in REDIRECTS else ""
            raise CameraError("camera_http_error", f"{where}: HTTP {resp.status} {resp.reason}{more}", resp.status >= 500)
        if length is not None and length.isdigit() and int(length) > self.max_bytes:
            raise CameraError("camera_too_large", f"{where}: answer of {int(length)} bytes announced, more than "
                                                  f"the {self.max_bytes} bytes a frame of this camera can hold")

    def _late(self, where: str) -> CameraError:
        return CameraError("camera_deadline", f"{where}: the answer did not end within the fetch's deadline of "
                                              f"{self.deadline_s:g} s (a camera sending slowly)")

    def _body(self, resp, end: float, where: str) -> bytes:
        """The answer's body, read as it comes (never more than :attr:`max_bytes`, never past ``end``)."""
        chunks, size = [], 0
        while True:
            if self._monotonic() >= end:
                raise self._late(where)
            chunk = resp.read1(CHUNK_BYTES)
            if not chunk:
                break
            size += len(chunk)
            if size > self.max_bytes:
                raise CameraError("camera_too_large", f"{where}: answer longer than {self.max_bytes} bytes, more "
                                                      "than a frame of this camera can hold; not read further")
            chunks.append(chunk)
        if self._monotonic() >= end:  # the watchdog shut the socket: the body ended early, not by itself
            raise self._late(where)
        return b"".join(chunks)

    def _frame(self, body: bytes, headers, length: str | None, where: str) -> Frame:
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
        return Frame(data=body, capture_time_s=capture, source=self.url, exposure_ms=self._exposure(headers, where))

    @staticmethod
    def _exposure(headers, where: str) -> float | None:
        """``X-Exposure-Ms`` [ms]; None without it (a camera that cannot set its exposure)."""
        raw = headers.get("X-Exposure-Ms")
        if raw is None:
            return None
        try:
            value = float(raw)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0):
            raise CameraError("camera_bad_exposure", f"{where}: X-Exposure-Ms header unreadable ({raw!r}); "
                                                     "expected the applied exposure in ms, a positive number")
        return value
