"""The simulated plant's cameras as live streams: HTTP MJPEG (``multipart/x-mixed-replace``) plus an
exposure control URL, the two things a stream camera (``cameras[].kind: stream``) reads.

``GET /<camera id>/stream.mjpg`` sends frames without end, ``fps`` a second (real time), each a
JPEG of the board rendered at the plant's time under the plant's lock (the same ``render()`` as
the HTTP snapshot camera), with ``X-Capture-Time`` in each part's headers (a stream reader through
FFmpeg does not see it). ``GET /<camera id>/exposure?exposure_ms=4.5`` sets the exposure of a
camera with exposure control (clamped to its range) and answers 200 with ``X-Exposure-Ms`` (the
contract of PLANT_INTERFACE 1.1 applied to the control URL); without ``exposure_ms`` it reports
the present setting. A camera without exposure control answers without the header and ignores
the parameter. Loopback only.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlparse

import cv2

from helicalib.sim.camera import SimCamera

LOOPBACK = "127.0.0.1"
BOUNDARY = "helicalibframe"
JPEG_QUALITY = 90
STREAM_PATH = "stream.mjpg"
EXPOSURE_PATH = "exposure"


def encode_jpeg(image) -> bytes:
    """8-bit grayscale JPEG of ``image`` (quality :data:`JPEG_QUALITY`)."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


class StreamService:
    """Serve ``cameras`` (camera id → :class:`SimCamera`) as MJPEG streams on one loopback port.

    ``lock`` and ``sync`` are the plant's (``PlantServer.registers.lock`` / ``.sync``): a frame is
    rendered holding the lock after ``sync()`` brought the plant to the clock's time.
    """

    def __init__(self, cameras: dict[str, SimCamera], lock, sync: Callable[[], object], port: int = 0,
                 fps: float = 5.0):
        self.cameras = dict(cameras)
        self.lock = lock
        self.sync = sync
        self.fps = float(fps)
        self._want_port = int(port)
        self._httpd: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()

    @property
    def port(self) -> int:
        if self._httpd is None:
            raise RuntimeError("stream service not started")
        return int(self._httpd.server_address[1])

    def url(self, camera_id: str) -> str:
        """The stream's URL (``cameras[].url`` of a ``kind: stream`` camera)."""
        self._camera(camera_id)
        return f"http://{LOOPBACK}:{self.port}/{camera_id}/{STREAM_PATH}"

    def exposure_url(self, camera_id: str) -> str:
        """The exposure control URL (``cameras[].exposure_url``)."""
        self._camera(camera_id)
        return f"http://{LOOPBACK}:{self.port}/{camera_id}/{EXPOSURE_PATH}"

    def _camera(self, camera_id: str) -> SimCamera:
        if camera_id not in self.cameras:
            raise KeyError(f"no streamed camera {camera_id!r} (streamed: {', '.join(sorted(self.cameras))})")
        return self.cameras[camera_id]

    def frame(self, cam: SimCamera) -> tuple[bytes, float]:
        """One JPEG of ``cam`` at the plant's present time, and that time [UTC s]."""
        with self.lock:
            self.sync()
            image, t = cam.render()
        return encode_jpeg(image), float(t)

    def set_exposure(self, cam: SimCamera, asked: str | None) -> float | None:
        """Apply ``asked`` [ms, text] (None: keep the setting); the exposure applied, or None for a
        camera without exposure control. Raises ValueError for an exposure that is not positive."""
        if not cam.exposure_control:
            return None
        if asked is not None:
            try:
                value = float(asked)
            except ValueError:
                value = math.nan
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"exposure_ms must be a positive number, got {asked!r}")
            with self.lock:
                cam.set_exposure(value)
        return float(cam.exposure_ms)

    def start(self) -> StreamService:
        self._stopping.clear()
        self._httpd = ThreadingHTTPServer((LOOPBACK, self._want_port), _handler(self))
        self._httpd.daemon_threads = True
        self._thread = threading.Thread(target=self._httpd.serve_forever, daemon=True, name="helicalib-sim-stream")
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop listening and end every stream (each ends within a frame period)."""
        self._stopping.set()
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None

    def __enter__(self) -> StreamService:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _handler(service: StreamService):
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):  # quiet
            pass

        def _send(self, code: int, body: bytes, headers: dict | None = None) -> None:
            self.send_response(code)
            self.send_header("Content-Type", "text/plain")
            self.send_header("Content-Length", str(len(body)))
            for k, v in (headers or {}).items():
                self.send_header(k, v)
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self):  # noqa: N802
            parts = urlparse(self.path)
            pieces = parts.path.strip("/").split("/")
            if len(pieces) != 2 or pieces[0] not in service.cameras or pieces[1] not in (STREAM_PATH, EXPOSURE_PATH):
                return self._send(404, f"no stream at {parts.path}; cameras: {sorted(service.cameras)}\n".encode())
            cam = service.cameras[pieces[0]]
            if pieces[1] == EXPOSURE_PATH:
                asked = parse_qs(parts.query).get("exposure_ms")
                try:
                    applied = service.set_exposure(cam, asked[-1] if asked else None)
                except ValueError as exc:
                    return self._send(400, f"{exc}\n".encode())
                headers = {} if applied is None else {"X-Exposure-Ms": repr(applied)}
                return self._send(200, b"", headers)
            self._stream(cam)

        def _stream(self, cam: SimCamera) -> None:
            self.close_connection = True
            self.send_response(200)
            self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
            self.send_header("Cache-Control", "no-cache")
            self.send_header("Connection", "close")
            self.end_headers()
            period_s = 1.0 / service.fps
            due = time.monotonic()
            try:
                while not service._stopping.is_set():
                    body, t = service.frame(cam)
                    head = (f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(body)}\r\n"
                            f"X-Capture-Time: {t!r}\r\n\r\n").encode()
                    self.wfile.write(head + body + b"\r\n")
                    self.wfile.flush()
                    due += period_s
                    time.sleep(max(0.0, due - time.monotonic()))
            except (BrokenPipeError, ConnectionResetError):
                pass  # the reader went away

    return Handler
