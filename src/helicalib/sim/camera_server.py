"""The simulated plant's HTTP cameras: one handler per camera port answering ``GET <camera url path>``
with a PNG frame and ``X-Capture-Time`` (PLANT_INTERFACE.md, "Camera"), and ``GET /truth.json``.

Exposure (interface 1.1): a camera with exposure control (the scenario's ``camera.exposure``, the
default) takes ``?exposure_ms=<positive float>`` (clamped to its range; anything else is answered
400) and sends ``X-Exposure-Ms`` with every frame; one without sends no such header and ignores
the parameter."""

from __future__ import annotations

import json
from http.server import BaseHTTPRequestHandler
import math
from urllib.parse import parse_qs, urlparse

from helicalib.sim.camera import SimCamera, encode_png


def make_http_handler(server, cameras: dict[str, SimCamera]):
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):  # quiet
            pass

        def _send(self, code: int, body: bytes, ctype: str, headers: dict | None = None, cut: bool = False):
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            for k, v in (headers or {}).items():
                self.send_header(k, v)
            if cut:
                self.send_header("Connection", "close")
            self.end_headers()
            self.wfile.write(body[: len(body) // 2] if cut else body)
            if cut:
                self.wfile.flush()
                self.close_connection = True

        def do_GET(self):  # noqa: N802
            parts = urlparse(self.path)
            path = parts.path
            f = server.faults
            if path == "/truth.json":
                body = json.dumps(server.truth()).encode()
                return self._send(200, body, "application/json")
            cam = cameras.get(path)
            if cam is None:
                return self._send(404, f"no camera at {path}; cameras: {sorted(cameras)}\n".encode(), "text/plain")
            if f.happens(f.camera_slow_probability):
                server.sleep(f.camera_slow_s)
            asked = parse_qs(parts.query).get("exposure_ms") if cam.exposure_control else None
            exposure_ms = None
            if asked:
                try:
                    exposure_ms = float(asked[-1])
                except ValueError:
                    exposure_ms = math.nan
                if not (math.isfinite(exposure_ms) and exposure_ms > 0):
                    return self._send(400, f"exposure_ms must be a positive number, got {asked[-1]!r}\n".encode(),
                                      "text/plain")
            if f.happens(f.camera_503_probability):
                return self._send(503, b"camera busy (injected fault)\n", "text/plain")
            with server.registers.lock:
                server.registers.sync()
                if exposure_ms is not None:
                    cam.set_exposure(exposure_ms)
                image, t = cam.render()
                applied = cam.exposure_ms
            body = encode_png(image)
            headers = {"X-Capture-Time": repr(float(t))}
            if cam.exposure_control:
                headers["X-Exposure-Ms"] = repr(float(applied))
            self._send(200, body, "image/png", headers, cut=f.happens(f.camera_truncate_probability))

    return Handler
