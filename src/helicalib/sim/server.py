"""Serve a :class:`SimulatedPlant` over a plant's own interface: its SCS over Modbus TCP (a register
map) or OPC UA (a node map), and its cameras by kind.

``PlantServer`` runs a pymodbus TCP server (its own asyncio loop in a thread) whose datastore is
:class:`~helicalib.sim.modbus_map.PlantRegisters` speaking the register map, or an OPC UA server
(:mod:`helicalib.sim.opcua_server`); one stdlib ``ThreadingHTTPServer`` per snapshot-camera port
answering ``GET <camera url path>`` with a PNG frame and ``X-Capture-Time`` (and ``X-Exposure-Ms``),
and stream cameras as MJPEG (:mod:`helicalib.sim.stream_server`). All bind to loopback only (a
port of 0 picks a free one; see ``modbus_port`` / ``camera_ports``). Plant time comes from an
injected clock. Faults (:class:`FaultInjector`) can be switched at run time.

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
from helicalib.config import Endpoint, OpcUa, is_map_name
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
    """Serve a simulated plant on loopback (Modbus TCP or OPC UA, and its cameras) until :meth:`stop`.

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
    protocol : ``"modbus"`` or ``"opcua"``
        How the SCS and the weather station are served: Modbus TCP (``register_map``), or OPC UA
        (``node_map``, on ``opcua_port``; None: the port of ``plant.opcua.endpoint``).
    The cameras are served by their ``kind``: ``http`` snapshot cameras on ``camera_port``,
    ``stream`` cameras as HTTP MJPEG with an exposure URL on ``stream_port`` (None: the port of the
    first stream camera's URL).
    """

    def __init__(self, plant, clock, modbus_port: int = 0, camera_port: int | None = 0,
                 weather_port: int | None = None, faults: FaultInjector | None = None, sleep=time.sleep,
                 register_map=None, protocol: str = "modbus", opcua_port: int | None = None, node_map=None,
                 opcua_security=None, stream_port: int | None = None):
        self.plant = plant
        self.clock = clock
        self.registers = PlantRegisters(plant, clock, register_map=register_map, served=protocol == "modbus")
        self.faults = faults or FaultInjector()
        self.sleep = sleep
        self.protocol = protocol
        cfg = plant.cfg
        self.units = ({e.unit for e in (cfg.plant.scs, cfg.plant.weather_endpoint) if e is not None} or {1}) | \
            set(self.registers.block_units if protocol == "modbus" else ())
        self._want_modbus = [modbus_port] if protocol == "modbus" else []
        if protocol == "modbus" and weather_port is not None and weather_port != modbus_port:
            self._want_modbus.append(weather_port)
        self.opcua = None
        if protocol == "opcua":
            from helicalib.sim.opcua_server import OpcUaPlantService

            if opcua_port is None:
                opcua_port = urlparse(cfg.plant.opcua.endpoint).port if cfg.plant.opcua is not None else 0
            if node_map is None and cfg.plant.opcua is not None and cfg.plant.opcua.node_map is not None:
                node_map = str(cfg.resolve_path(cfg.plant.opcua.node_map)) \
                    if not is_map_name(cfg.plant.opcua.node_map) else cfg.plant.opcua.node_map
            self.opcua = OpcUaPlantService(plant, clock, lock=self.registers.lock, port=opcua_port or 0,
                                           node_map=node_map, security=opcua_security)
        elif protocol != "modbus":
            raise ConfigError(f"protocol {protocol!r}: expected modbus or opcua")
        # snapshot cameras grouped by port; stream cameras on one stream service
        self._camera_groups: dict[int, dict[str, SimCamera]] = {}
        streams: dict[str, SimCamera] = {}
        for c in cfg.cameras:
            url = urlparse(c.url)
            if c.kind == "stream":
                streams[c.id] = SimCamera(plant, c.id)
                if stream_port is None:
                    stream_port = url.port or 80
                continue
            port = camera_port if camera_port is not None else (url.port or 80)
            self._camera_groups.setdefault(port, {})[url.path or "/"] = SimCamera(plant, c.id)
        self.streams = None
        if streams:
            from helicalib.sim.stream_server import StreamService

            self.streams = StreamService(streams, self.registers.lock, self.registers.sync,
                                         port=stream_port if camera_port is None else camera_port)
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
        if self.streams is not None and camera_id in self.streams.cameras:
            return self.streams.url(camera_id)
        for want, group in self._camera_groups.items():
            for path, cam in group.items():
                if cam.config.id == camera_id:
                    return f"http://{LOOPBACK}:{self.camera_ports[want]}{path}"
        raise KeyError(camera_id)

    def served_config(self, cfg):
        """``cfg`` as a client reaches this server: the SCS (and weather) endpoint, or the OPC UA
        endpoint, and every camera's URL at the ports bound (the register map is the caller's:
        ``self.registers.map``)."""
        plant = cfg.plant
        if self.protocol == "modbus":
            scs = (plant.scs or Endpoint(host=LOOPBACK, port=1)).model_copy(
                update={"host": LOOPBACK, "port": self.modbus_port})
            weather = None
            if plant.weather is not None and len(self.modbus_ports) > 1:
                weather = plant.weather.model_copy(update={"host": LOOPBACK, "port": self.modbus_ports[1]})
            plant = plant.model_copy(update={"protocol": "modbus", "scs": scs, "weather": weather})
        else:  # the served node map, without the security this server was not given
            node_map = None if plant.opcua is None else plant.opcua.node_map
            opcua = OpcUa(endpoint=self.opcua.endpoint, node_map=node_map) if self.opcua.security is None else \
                plant.opcua.model_copy(update={"endpoint": self.opcua.endpoint})
            plant = plant.model_copy(update={"protocol": "opcua", "opcua": opcua})
        cameras = []
        for c in cfg.cameras:
            update = {"url": self.camera_url(c.id)}
            if c.kind == "stream":
                update["exposure_url"] = self.streams.exposure_url(c.id)
            cameras.append(c.model_copy(update=update))
        return cfg.model_copy(update={"plant": plant, "cameras": tuple(cameras)})

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
        if self.opcua is not None:
            self.opcua.start()
        if self._want_modbus:
            self._start_modbus()
        if self.streams is not None:
            try:
                self.streams.start()
            except OSError as exc:
                raise bind_error(CAMERA_HTTP, self.streams._want_port, exc) from None
        self._start_cameras()
        return self

    def _start_modbus(self) -> None:
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

    def _start_cameras(self) -> None:
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

    def stop(self) -> None:
        """Close every listener and connection; returns when the threads have ended."""
        for httpd in self._http:
            httpd.shutdown()
            httpd.server_close()
        for service in (self.streams, self.opcua):
            if service is not None:
                service.stop()
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
