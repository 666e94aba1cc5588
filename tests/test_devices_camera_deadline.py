"""A camera never stalls the controller: real slow and endless HTTP servers on loopback.

A camera that trickles its answer (2 kB every 0.5 s, each read well within the timeout), one that
trickles its headers, and one that sends an endless body without ``Content-Length``: each fetch
ends within its whole-request deadline, with a reason code, and memory stays bounded.
"""

from __future__ import annotations

import signal
import socket
import threading
import time
import tracemalloc

import cv2
import numpy as np
import pytest

from helicalib.devices.camera_http import CameraError, HttpCamera, frame_cap_bytes

PNG = cv2.imencode(".png", (np.arange(64 * 48) % 200).astype(np.uint8).reshape(48, 64))[1].tobytes()


class Raw:
    """A loopback TCP server that answers every connection with ``behaviour(conn, sent)``; counts bytes sent."""

    def __init__(self, behaviour):
        self.behaviour = behaviour
        self.sent = 0
        self.open = 0  # requests being answered now
        self.connections = 0  # requests answered or being answered
        self.first = threading.Event()  # set by the first request
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.stop = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.sock.getsockname()[1]}/T1.png"

    def _serve(self):
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            threading.Thread(target=self._one, args=(conn,), daemon=True).start()

    def _one(self, conn):
        self.open += 1
        self.connections += 1
        self.first.set()
        try:
            conn.recv(65536)  # the request
            self.behaviour(self, conn)
        except OSError:  # the client gave up: what it should do
            pass
        finally:
            self.open -= 1
            conn.close()

    def send(self, conn, data: bytes) -> None:
        conn.sendall(data)
        self.sent += len(data)

    def close(self):
        self.stop.set()
        self.sock.close()


def trickle_body(server, conn):
    server.send(conn, b"HTTP/1.1 200 OK\r\nContent-Type: image/png\r\nX-Capture-Time: 1.0\r\n"
                      b"Content-Length: 10000000\r\n\r\n")
    while not server.stop.is_set():
        server.send(conn, b"\0" * 2048)
        time.sleep(0.5)


def trickle_headers(server, conn):
    server.send(conn, b"HTTP/1.1 200 OK\r\n")
    while not server.stop.is_set():
        server.send(conn, b"X-Pad: a\r\n")
        time.sleep(0.5)


def endless_body(server, conn):
    server.send(conn, b"HTTP/1.1 200 OK\r\nContent-Type: image/png\r\nX-Capture-Time: 1.0\r\nConnection: close\r\n\r\n")
    block = PNG[:8] + b"\0" * 65528
    while not server.stop.is_set():
        server.send(conn, block)


def stall(server, conn):
    """Read the request, then answer nothing (until the client gives up or the server stops)."""
    server.stop.wait(60.0)


def huge_length(server, conn):
    server.send(conn, b"HTTP/1.1 200 OK\r\nContent-Type: image/png\r\nX-Capture-Time: 1.0\r\n"
                      b"Content-Length: 4000000000\r\n\r\n" + PNG)


HANG_S = 30.0
"""A test here that is not over after this many real seconds fails: a broken deadline must not
leave a test feeding on a trickling server for its ~40 minutes."""


@pytest.fixture(autouse=True)
def no_hang():
    """Fail the test (SIGALRM in the main thread) if it runs longer than :data:`HANG_S`."""

    def hung(*_):
        pytest.fail(f"still running after {HANG_S:g} s: the fetch deadline did not end it")

    previous = signal.signal(signal.SIGALRM, hung)
    signal.setitimer(signal.ITIMER_REAL, HANG_S)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture()
def raw():
    made = []

    def make(behaviour):
        made.append(Raw(behaviour))
        return made[-1]

    yield make
    for s in made:
        s.close()


def _timed(cam):
    t0 = time.monotonic()
    with pytest.raises(CameraError) as err:
        cam.grab()
    return err.value, time.monotonic() - t0


@pytest.mark.parametrize("behaviour", [trickle_body, trickle_headers], ids=["body", "headers"])
def test_a_trickling_camera_ends_within_the_fetch_deadline(raw, behaviour):
    server = raw(behaviour)
    # each read is answered well within the 2 s timeout: only the whole-request deadline ends it
    err, took = _timed(HttpCamera(server.url, timeout_s=2.0, retries=2, deadline_s=1.5))
    assert err.reason == "camera_deadline" and "1.5 s" in str(err) and server.url in str(err)
    assert took < 1.5 + 2.0, took  # the deadline, and room for a busy machine
    assert len(str(err).splitlines()) == 1


def test_an_endless_body_is_cut_at_the_frame_cap_and_memory_stays_bounded(raw):
    server = raw(endless_body)
    cam = HttpCamera(server.url, timeout_s=2.0, retries=2, expected_size_px=(64, 48), deadline_s=5.0)
    cap = frame_cap_bytes((64, 48))
    assert cam.max_bytes == cap and 64 * 48 * 8 < cap < 200_000
    tracemalloc.start()
    try:
        err, took = _timed(cam)
        _now, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert err.reason == "camera_too_large" and str(cap) in str(err)
    assert took < 5.0
    assert peak < 4 * cap, peak  # the body held at most the cap (plus a read's worth), not gigabytes


def test_an_announced_length_above_the_cap_is_refused_before_reading(raw):
    server = raw(huge_length)
    err, _took = _timed(HttpCamera(server.url, timeout_s=2.0, expected_size_px=(64, 48)))
    assert err.reason == "camera_too_large" and "4000000000 bytes announced" in str(err)


def test_an_unknown_frame_size_gets_a_sane_cap():
    cam = HttpCamera("http://127.0.0.1:9/x.png")
    assert 50_000_000 <= cam.max_bytes <= 256 * 1024 * 1024
    assert frame_cap_bytes((1280, 1024)) > 1280 * 1024 * 8  # a 16-bit RGBA PNG without compression fits


def test_the_deadline_covers_the_retries(raw):
    server = raw(stall)
    # a camera that never answers: each attempt times out after 0.4 s and is retried; three
    # attempts would take 1.2 s: the deadline of 1 s ends the fetch during the third
    err, took = _timed(HttpCamera(server.url, timeout_s=0.4, retries=2, deadline_s=1.0))
    assert server.connections > 1  # it did retry
    assert err.reason == "camera_deadline" and took < 1.0 + 2.0, took


def _answer_png(server, conn):
    server.send(conn, b"HTTP/1.1 200 OK\r\nContent-Type: image/png\r\nX-Capture-Time: 1.0\r\n"
                      b"Content-Length: %d\r\nConnection: close\r\n\r\n" % len(PNG) + PNG)


def _redirect_to(url):
    def behaviour(server, conn):
        server.send(conn, b"HTTP/1.1 302 Found\r\nLocation: " + url.encode() + b"\r\nContent-Length: 0\r\n"
                          b"Connection: close\r\n\r\n")

    return behaviour


def test_one_redirect_is_followed(raw):
    camera = raw(_answer_png)
    proxy = raw(_redirect_to(camera.url))
    frame = HttpCamera(proxy.url, timeout_s=2.0, retries=0, expected_size_px=(64, 48), deadline_s=3.0).grab()
    assert frame.data == PNG and frame.capture_time_s == 1.0
    assert proxy.connections == 1 and camera.connections == 1


def test_a_second_redirect_is_refused_in_one_line(raw):
    camera = raw(_answer_png)
    second = raw(_redirect_to(camera.url))
    first = raw(_redirect_to(second.url))
    err, _took = _timed(HttpCamera(first.url, timeout_s=2.0, retries=0, deadline_s=3.0))
    assert err.reason == "camera_http_error" and "302" in str(err) and "second redirect" in str(err)
    assert second.url in str(err) and len(str(err).splitlines()) == 1
    assert camera.connections == 0


def test_a_resolver_that_does_not_answer_ends_within_the_deadline():
    """The name is resolved within the fetch's deadline (a hung resolver: no socket yet for the
    watchdog to shut)."""
    hung = threading.Event()

    def resolver(*_a, **_k):
        hung.wait(20.0)
        raise OSError("resolver gave up")

    cam = HttpCamera("http://camera-t1.plant.invalid:8080/T1.png", timeout_s=0.5, retries=2, deadline_s=1.0,
                     resolve=resolver)
    try:
        err, took = _timed(cam)
    finally:
        hung.set()
    assert err.reason == "camera_deadline" and "camera-t1.plant.invalid" in str(err), err
    assert took < 1.0 + 2.0, took
