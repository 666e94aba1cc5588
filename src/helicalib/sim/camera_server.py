"""The simulated plant's HTTP cameras: one handler per camera port answering ``GET <camera url path>``
with a PNG frame and ``X-Capture-Time`` (PLANT_INTERFACE.md, "Camera"), and ``GET /truth.json``."""

from __future__ import annotations

import json
from http.server import BaseHTTPRequestHandler
from urllib.parse import urlparse

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
            path = urlparse(self.path).path
            f = server.faults
            if path == "/truth.json":
                body = json.dumps(server.truth()).encode()
                return self._send(200, body, "application/json")
            cam = cameras.get(path)
            if cam is None:
                return self._send(404, f"no camera at {path}; cameras: {sorted(cameras)}\n".encode(), "text/plain")
            if f.happens(f.camera_slow_probability):
                server.sleep(f.camera_slow_s)
            if f.happens(f.camera_503_probability):
                return self._send(503, b"camera busy (injected fault)\n", "text/plain")
            with server.registers.lock:
                server.registers.sync()
                image, t = cam.render()
            body = encode_png(image)
            self._send(200, body, "image/png", {"X-Capture-Time": repr(float(t))},
                       cut=f.happens(f.camera_truncate_probability))

    return Handler
