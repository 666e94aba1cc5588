"""StreamCamera against a real RTSP stream: Debian's ffmpeg encodes frames that carry their own
number (ten black/white blocks, bit i in columns 32·i..32·i+31) as MJPEG over RTP and publishes
them (ffmpeg's RTSP muxer, ANNOUNCE/RECORD over TCP) to a small RTSP relay on loopback; the
camera plays them from the relay (DESCRIBE/SETUP/PLAY over TCP) exactly as it plays an IP
camera's stream. The relay (:class:`RtspRelay` below) forwards the publisher's interleaved RTP
and RTCP packets byte for byte and knows nothing of their content: everything the camera decodes
was packetised by ffmpeg. Killing ffmpeg ends the stream (the relay closes its players, as a
camera that reboots does).

Skipped only when /usr/bin/ffmpeg is missing (``make`` installs it).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time

import cv2
import numpy as np
import pytest

from helicalib.devices.camera_http import CameraError
from helicalib.devices.camera_stream import StreamCamera

FFMPEG = "/usr/bin/ffmpeg"


@pytest.fixture(autouse=True)
def _ffmpeg():
    """Debian's ffmpeg publishes the stream; `make test` installs it (never skipped: a missing one fails)."""
    if shutil.which(FFMPEG) is None:
        pytest.fail(f"{FFMPEG} is not installed: `make test` installs Debian's ffmpeg (apt-get)")

FPS = 10
SIZE = (320, 240)
PLANT_T0_S = 1_790_000_000.0


class OffsetClock:
    """Plant time = a fixed start + monotonic real time (rate 1)."""

    rate = 1.0
    uncertainty_s = 0.0

    def __init__(self):
        self._m0 = time.monotonic()

    def now_s(self) -> float:
        return PLANT_T0_S + time.monotonic() - self._m0

    estimate_s = now_s

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


# ---------------------------------------------------------------------------------------------
# the relay: one publisher (ANNOUNCE/SETUP/RECORD), any number of players (DESCRIBE/SETUP/PLAY),
# interleaved TCP transport only
# ---------------------------------------------------------------------------------------------


def _read_message(sock: socket.socket, buf: bytearray):
    """('rtsp', start line, headers, body) or ('data', channel, payload) or None at the end."""
    while True:
        if buf[:1] == b"$" and len(buf) >= 4:
            size = int.from_bytes(buf[2:4], "big")
            if len(buf) >= 4 + size:
                channel, payload = buf[1], bytes(buf[4:4 + size])
                del buf[:4 + size]
                return "data", channel, payload
        elif buf[:1] not in (b"", b"$"):
            head_end = buf.find(b"\r\n\r\n")
            if head_end >= 0:
                lines = bytes(buf[:head_end]).decode("latin-1").split("\r\n")
                headers = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:] if ":" in ln)}
                size = int(headers.get("content-length", "0"))
                if len(buf) >= head_end + 4 + size:
                    body = bytes(buf[head_end + 4:head_end + 4 + size])
                    del buf[:head_end + 4 + size]
                    return "rtsp", lines[0], headers, body
        chunk = sock.recv(65536)
        if not chunk:
            return None
        buf.extend(chunk)


class RtspRelay:
    def __init__(self):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.sdp: bytes | None = None
        self.players: list[socket.socket] = []
        self.lock = threading.Lock()
        self.closed = False
        threading.Thread(target=self._accept, daemon=True).start()

    def url(self, path: str = "live") -> str:
        return f"rtsp://127.0.0.1:{self.port}/{path}"

    def close(self) -> None:
        self.closed = True
        self.listener.close()
        self._drop_players()

    def _drop_players(self) -> None:
        with self.lock:
            players, self.players = self.players, []
        for p in players:
            try:
                p.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            p.close()

    def _accept(self) -> None:
        while not self.closed:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        buf = bytearray()
        publishing = False
        try:
            while True:
                msg = _read_message(conn, buf)
                if msg is None:
                    break
                if msg[0] == "data":
                    if publishing:
                        self._forward(msg[1], msg[2])
                    continue  # a player's RTCP receiver report
                _, start, headers, body = msg
                method, uri = start.split(" ")[:2]
                reply = {"CSeq": headers.get("cseq", "0")}
                code, answer = "200 OK", b""
                if method == "OPTIONS":
                    reply["Public"] = "DESCRIBE, ANNOUNCE, SETUP, PLAY, RECORD, TEARDOWN, GET_PARAMETER"
                elif method == "ANNOUNCE":
                    self.sdp = body
                elif method == "DESCRIBE":
                    if self.sdp is None:
                        code = "404 Not Found"
                    else:
                        answer = self.sdp
                        reply.update({"Content-Type": "application/sdp", "Content-Base": uri.rstrip("/") + "/"})
                elif method == "SETUP":
                    if "tcp" not in headers.get("transport", "").lower():
                        code = "461 Unsupported Transport"
                    else:
                        reply.update({"Transport": headers["transport"], "Session": "12345678;timeout=60"})
                elif method == "RECORD":
                    publishing = True
                    reply["Session"] = "12345678"
                elif method == "PLAY":
                    if self.sdp is None:
                        code = "404 Not Found"
                    else:
                        reply["Session"] = "12345678"
                elif method == "TEARDOWN":
                    code = "200 OK"
                head = f"RTSP/1.0 {code}\r\n" + "".join(f"{k}: {v}\r\n" for k, v in reply.items())
                head += f"Content-Length: {len(answer)}\r\n\r\n"
                conn.sendall(head.encode() + answer)
                if method == "PLAY" and code.startswith("200"):
                    with self.lock:
                        self.players.append(conn)
        except OSError:
            pass
        finally:
            if publishing:  # the camera is gone: so is its stream
                self.sdp = None
                self._drop_players()
            conn.close()

    def _forward(self, channel: int, payload: bytes) -> None:
        packet = b"$" + bytes([channel]) + len(payload).to_bytes(2, "big") + payload
        with self.lock:
            players = list(self.players)
        for p in players:
            try:
                p.sendall(packet)
            except OSError:
                with self.lock:
                    if p in self.players:
                        self.players.remove(p)


def publish(url: str) -> subprocess.Popen:
    """ffmpeg publishing numbered frames at FPS in real time (RTSP muxer over TCP, MJPEG over RTP)."""
    source = (f"color=c=black:s={SIZE[0]}x{SIZE[1]}:r={FPS},format=gray,"
              "geq=lum='if(bitand(N\\,pow(2\\,floor(X/32)))\\,255\\,0)',format=yuvj420p")
    return subprocess.Popen([FFMPEG, "-hide_banner", "-loglevel", "error", "-re", "-f", "lavfi", "-i", source,
                             "-c:v", "mjpeg", "-huffman", "default", "-force_duplicated_matrix", "1", "-q:v", "3", "-f", "rtsp", "-rtsp_transport", "tcp", url],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def number(frame) -> int:
    img = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.ndim == 2 and img.dtype == np.uint8  # 8-bit grayscale PNG
    bits = [int(img[SIZE[1] // 2, 32 * i + 16] > 128) for i in range(10)]
    return sum(b << i for i, b in enumerate(bits))


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(5)


@pytest.fixture
def relay():
    r = RtspRelay()
    yield r
    r.close()


def test_newest_frame_with_its_capture_time_and_reconnect_after_ffmpeg_restarts(relay):
    proc = publish(relay.url())
    clock = OffsetClock()
    cam = StreamCamera(relay.url(), clock=clock, timeout_s=5.0, expected_size_px=SIZE)
    try:
        first = cam.grab()
        assert first.source == relay.url() and first.exposure_ms is None
        time.sleep(1.0)  # a camera that buffered would now hand out the frame after `first`
        t_before = clock.now_s()
        second = cam.grab()
        t_after = clock.now_s()
        gap = number(second) - number(first)
        assert FPS * 1.0 - 5 <= gap <= FPS * 1.6, gap  # a camera that buffered: 1 (ffmpeg may run slow on a loaded machine)
        # capture time: after the request began (a frame is never older than the request), not in the future
        assert t_before - 0.001 <= second.capture_time_s <= t_after
        assert 0.9 <= second.capture_time_s - first.capture_time_s <= 1.6

        stop(proc)  # the camera reboots
        with pytest.raises(CameraError) as err:
            cam.timeout_s = 1.0
            cam.grab()
        assert err.value.reason == "camera_unreachable" and relay.url() in str(err.value)

        proc = publish(relay.url())
        cam.timeout_s = 5.0
        again = cam.grab()  # opened again: frames of the new stream, counted from 0
        assert number(again) < number(second)
    finally:
        cam.close()
        stop(proc)


def test_a_stream_that_never_comes_times_out_within_the_deadline(relay):
    cam = StreamCamera(relay.url(), clock=OffsetClock(), timeout_s=0.8)
    t = time.monotonic()
    with pytest.raises(CameraError) as err:
        cam.grab()
    assert err.value.reason == "camera_unreachable" and "0.8 s" in str(err.value)
    assert time.monotonic() - t < 3.0
    cam.close()


def test_a_frame_of_the_wrong_size_is_refused(relay):
    proc = publish(relay.url())
    cam = StreamCamera(relay.url(), clock=OffsetClock(), timeout_s=5.0, expected_size_px=(640, 480))
    try:
        with pytest.raises(CameraError) as err:
            cam.grab()
        assert err.value.reason == "camera_wrong_size" and "320×240" in str(err.value)
    finally:
        cam.close()
        stop(proc)
