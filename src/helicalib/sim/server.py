"""Serve a :class:`SimulatedPlant` over the real plant interface: Modbus TCP + HTTP cameras.

``PlantServer`` runs a pymodbus TCP server (its own asyncio loop in a thread) whose datastore is
:class:`~helicalib.sim.modbus_map.PlantRegisters`, and one stdlib ``ThreadingHTTPServer`` per
camera port answering ``GET <camera url path>`` with a PNG frame and ``X-Capture-Time``. Both bind
to loopback only (a port of 0 picks a free one; see ``modbus_port`` / ``camera_ports``). Plant
time comes from an injected clock. Faults (:class:`FaultInjector`) can be switched at run time.

Not part of the interface but served for honest judging: ``GET /truth.json`` on a camera port
returns the true state of every heliostat (strokes, state, true tracking error while holding).
"""

from __future__ import annotations

import asyncio
import errno
import random
import socket
import threading
import time
from dataclasses import dataclass, field
from http.server import ThreadingHTTPServer
from urllib.parse import urlparse

import numpy as np
from helicalib.errors import ConfigError
from helicalib.sim.camera import SimCamera
from helicalib.sim.camera_server import make_http_handler
from helicalib.sim.modbus_map import PlantRegisters
from helicalib.sim.modbus_server import FaultyTcpServer, PlantContext

LOOPBACK = "127.0.0.1"
MODBUS = "Modbus TCP"
CAMERA_HTTP = "camera HTTP"


class PortInUseError(ConfigError):
    """A port the plant server must listen on is taken; ``kind`` (:data:`MODBUS` or :data:`CAMERA_HTTP`)
    and ``port`` say which."""

    def __init__(self, kind: str, port: int):
        self.kind = kind
        self.port = int(port)
        super().__init__(f"{kind} port {port} on {LOOPBACK} is in use")


def bind_error(kind: str, port: int, exc: OSError) -> ConfigError:
    """The one-line error for a listener that could not bind ``port``."""
    if exc.errno == errno.EADDRINUSE:
        return PortInUseError(kind, port)
    if exc.errno == errno.EACCES:
        return ConfigError(f"{kind} port {port} on {LOOPBACK}: permission denied (ports below 1024 need privileges)")
    return ConfigError(f"{kind} port {port} on {LOOPBACK}: cannot listen ({exc.strerror or exc})")


def check_port_free(kind: str, port: int) -> None:
    """Raise :func:`bind_error`'s error if ``port`` cannot be bound on loopback as a server binds it
    (``SO_REUSEADDR``, as asyncio and ``http.server`` do). Port 0 always can. pymodbus swallows the
    reason of a failed listen, so its ports are probed first."""
    if int(port) == 0:
        return
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((LOOPBACK, int(port)))
        except OSError as exc:
            raise bind_error(kind, port, exc) from None


@dataclass
class FaultInjector:
    """Probabilities of injected faults (mutable at run time); ``rng`` decides each request."""

    modbus_drop_probability: float = 0.0
    modbus_slow_probability: float = 0.0
    modbus_slow_s: float = 3.0
    camera_503_probability: float = 0.0
    camera_truncate_probability: float = 0.0
    camera_slow_probability: float = 0.0
    camera_slow_s: float = 3.0
    rng: random.Random = field(default_factory=lambda: random.Random(0))

    @classmethod
    def from_scenario(cls, faults, seed: int = 0) -> FaultInjector:
        return cls(**{k: getattr(faults, k) for k in (
            "modbus_drop_probability", "modbus_slow_probability", "modbus_slow_s", "camera_503_probability",
            "camera_truncate_probability", "camera_slow_probability", "camera_slow_s")}, rng=random.Random(seed))

    def happens(self, probability: float) -> bool:
        return probability > 0 and self.rng.random() < probability


class PlantServer:
    """Serve a simulated plant on loopback (Modbus TCP + HTTP cameras) until :meth:`stop`.

    Parameters
    ----------
    plant : SimulatedPlant
    clock : plant clock with ``now_s()`` and ``rate`` (e.g. :class:`~helicalib.sim.clock.RateClock`)
    modbus_port : int
        SCS port (0 = a free port); the weather endpoint is served here too, and on its own
        port if the field config names another one (``weather_port``).
    camera_port : int or None
        Port for every camera (0 = a free one); None = the ports of the cameras' URLs.
    faults : FaultInjector, optional
    sleep : callable
        Real sleep for slow answers (``time.sleep``).
    register_map : RegisterMap, a shipped map's name or a YAML path, optional
        The Modbus layout served (default: ``PLANT_INTERFACE.md``).
    """

    def __init__(self, plant, clock, modbus_port: int = 0, camera_port: int | None = 0,
                 weather_port: int | None = None, faults: FaultInjector | None = None, sleep=time.sleep,
                 register_map=None):
        self.plant = plant
        self.clock = clock
        self.registers = PlantRegisters(plant, clock, register_map=register_map)
        self.faults = faults or FaultInjector()
        self.sleep = sleep
        cfg = plant.cfg
        self.units = {cfg.plant.scs.unit, cfg.plant.weather_endpoint.unit}
        self._want_modbus = [modbus_port]
        if weather_port is not None and weather_port != modbus_port:
            self._want_modbus.append(weather_port)
        # cameras grouped by port
        self._camera_groups: dict[int, dict[str, SimCamera]] = {}
        for c in cfg.cameras:
            url = urlparse(c.url)
            port = camera_port if camera_port is not None else (url.port or 80)
            self._camera_groups.setdefault(port, {})[url.path or "/"] = SimCamera(plant, c.id)
        self.modbus_ports: list[int] = []
        self.camera_ports: dict[int, int] = {}   # wanted → bound
        self._loop: asyncio.AbstractEventLoop | None = None
        self._modbus: list[FaultyTcpServer] = []
        self._http: list[ThreadingHTTPServer] = []
        self._threads: list[threading.Thread] = []

    @property
    def modbus_port(self) -> int:
        return self.modbus_ports[0]

    def camera_url(self, camera_id: str) -> str:
        """The URL at which a camera is served (bound port)."""
        for want, group in self._camera_groups.items():
            for path, cam in group.items():
                if cam.config.id == camera_id:
                    return f"http://{LOOPBACK}:{self.camera_ports[want]}{path}"
        raise KeyError(camera_id)

    # -- lifecycle --------------------------------------------------------------------------
    def start(self) -> PlantServer:
        """Listen on every port; raises :class:`PortInUseError` (or another one-line
        :class:`ConfigError`) naming the port that cannot be bound, with nothing left listening."""
        for port in self._want_modbus:
            check_port_free(MODBUS, port)
        try:
            return self._start()
        except BaseException:
            self.stop()
            raise

    def _start(self) -> PlantServer:
        ready = threading.Event()
        errors: list[BaseException] = []

        def run_loop():
            loop = asyncio.new_event_loop()
            self._loop = loop
            asyncio.set_event_loop(loop)

            async def boot():
                for port in self._want_modbus:
                    ctx = PlantContext(self.registers, self.units)
                    srv = FaultyTcpServer(ctx, address=(LOOPBACK, port))
                    srv.faults = self.faults
                    await srv.serve_forever(background=True)
                    self._modbus.append(srv)
                    self.modbus_ports.append(srv.transport.sockets[0].getsockname()[1])

            try:
                loop.run_until_complete(boot())
            except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
                errors.append(exc)
                ready.set()
                return
            loop.call_soon(ready.set)                # set once the loop runs: stop() can then reach it
            loop.run_forever()
            loop.close()

        t = threading.Thread(target=run_loop, name="sim-modbus", daemon=True)
        t.start()
        self._threads.append(t)
        ready.wait(10)
        if errors:
            for port in self._want_modbus:           # taken since the first probe: say which
                check_port_free(MODBUS, port)
            raise RuntimeError(f"Modbus server did not start: {errors[0]}")
        for want, group in self._camera_groups.items():
            try:
                httpd = ThreadingHTTPServer((LOOPBACK, want), make_http_handler(self, group))
            except OSError as exc:
                raise bind_error(CAMERA_HTTP, want, exc) from None
            httpd.daemon_threads = True
            self.camera_ports[want] = httpd.server_address[1]
            th = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.1}, name="sim-http", daemon=True)
            th.start()
            self._http.append(httpd)
            self._threads.append(th)
        return self

    def stop(self) -> None:
        """Close every listener and connection; returns when the threads have ended."""
        for httpd in self._http:
            httpd.shutdown()
            httpd.server_close()
        if self._loop is not None:
            async def down():
                for srv in self._modbus:
                    await srv.shutdown()
            if self._loop.is_running():
                fut = asyncio.run_coroutine_threadsafe(down(), self._loop)
                try:
                    fut.result(5)
                finally:
                    self._loop.call_soon_threadsafe(self._loop.stop)
            else:                                   # its thread gave up while starting: close here
                for th in self._threads[:1]:
                    th.join(5)
                if not self._loop.is_closed():
                    self._loop.run_until_complete(down())
                    self._loop.close()
        for th in self._threads:
            th.join(5)

    def __enter__(self) -> PlantServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- truth ------------------------------------------------------------------------------
    def truth(self) -> dict:
        """True state of the plant now (simulator only): per heliostat state, strokes, true error."""
        with self.registers.lock:
            self.registers.sync()
            p = self.plant
            err = p.true_tracking_error_mrad()
            return {
                "plant_time_s": p.t_s,
                "heliostats": [
                    {"id": h.id, "state": int(p.state[i]), "strokes_mm": [float(x) for x in p.strokes_mm[i]],
                     "true_tracking_error_mrad": None if not np.isfinite(err[i]) else float(err[i])}
                    for i, h in enumerate(p.cfg.heliostats)
                ],
            }
