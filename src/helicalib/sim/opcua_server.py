"""The simulated plant served over OPC UA (asyncua), laid out by a node map.

:class:`OpcUaPlantService` serves a :class:`~helicalib.sim.plant.SimulatedPlant` on loopback: an
asyncua server in its own event loop thread whose variables are computed when read (value
callbacks) from the plant, advanced to ``clock.now_s()`` under the shared lock once per read
request, so a read is as fresh as a Modbus read of the same plant. Commands are methods acting at
once through ``plant.write_command`` / ``plant.field_command``, as the Modbus twin
(:mod:`helicalib.sim.modbus_map`) does on a sequence write.

The address space: ``Objects/Plant/Field`` (HeliostatCount, State, PlantTime, PlantTimeRate,
method Command), ``Objects/Plant/Weather`` (WindSpeed, WindDirection, DNI, Temperature, Pressure)
and ``Objects/Plant/Heliostats/<id>`` (State, SequenceDone, Fault, Stroke1, Stroke2, Cleanliness,
methods MoveTo, Track, Resume, Stow), all browse names in namespace 2; node ids are the map's (a
map that names a node by browse path gets a numeric id). Optionally a security policy with the
server's own certificate, and users with passwords. :meth:`OpcUaPlantService.lose_next_call`
breaks the link at a method call (the answer lost, the request lost, or the plant gone), the
faults a client must survive without executing a command twice.
"""

from __future__ import annotations

import asyncio
import errno
import socket
import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from asyncua import Server, ua
from asyncua.common.callback import CallbackType
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.user_managers import UserManager

from helicalib.devices.nodemap import NodeMap, fill, is_node_id, load_node_map
from helicalib.devices.opcua_link import quiet_asyncua
from helicalib.devices.registers import FieldCommand, HeliostatCommand
from helicalib.errors import ConfigError

LOOPBACK = "127.0.0.1"
NAMESPACE = "urn:helicalib:simulated-plant"
PATH = "helicalib"
OPCUA = "OPC UA"
LINK_FAULTS = ("answer", "request", "plant")
"""What :meth:`OpcUaPlantService.lose_next_call` loses: the answer (the plant acted), the request
(it did not), or the plant (it acted, then the server stopped)."""


@dataclass(frozen=True)
class ServerSecurity:
    """The secured path of the simulated plant: its certificate and key (PEM), the policy it
    demands (``Basic256Sha256`` with ``SignAndEncrypt``), and the users it accepts (no anonymous
    session when ``users`` is given)."""

    certificate: Path
    private_key: Path
    policy: str = "Basic256Sha256"
    mode: str = "SignAndEncrypt"
    users: dict[str, str] = field(default_factory=dict)


class _Users(UserManager):
    def __init__(self, users: dict[str, str]):
        self.users = dict(users)

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if username is not None and self.users.get(username) == password:
            return User(role=UserRole.User, name=username)
        return None


class OpcUaPlantService:
    """Serve a simulated plant over OPC UA on loopback until :meth:`stop`.

    Parameters
    ----------
    plant : SimulatedPlant
    clock : plant clock with ``now_s()`` and ``rate``
    lock : threading lock shared with the camera servers (one is made if None)
    port : int
        0: a free port (see :attr:`port`).
    node_map : NodeMap or str, optional
        The layout's node ids (default: the shipped ``opcua-default``).
    security : ServerSecurity, optional
    """

    def __init__(self, plant, clock, lock=None, port: int = 0, node_map: NodeMap | str | None = None,
                 security: ServerSecurity | None = None):
        self.plant = plant
        self.clock = clock
        self.lock = lock or threading.RLock()
        self.map = node_map if isinstance(node_map, NodeMap) else load_node_map(node_map)
        self.security = security
        self._want_port = int(port)
        self._port: int | None = None
        self.calls: list[tuple[str, tuple]] = []
        """Every method call the server took: (method name, arguments), for tests and logs."""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: Server | None = None
        self._faults: list[str] = []
        self._halted = False
        self.ids = [h.id for h in plant.cfg.heliostats]

    @property
    def port(self) -> int:
        if self._port is None:
            raise RuntimeError("the OPC UA server is not started")
        return self._port

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{LOOPBACK}:{self.port}/{PATH}"

    # -- lifecycle --------------------------------------------------------------------------
    def start(self) -> OpcUaPlantService:
        """Listen on loopback; a port that cannot be bound is a one-line :class:`ConfigError`."""
        quiet_asyncua()
        self._probe()
        ready = threading.Event()
        errors: list[BaseException] = []

        def run():
            loop = asyncio.new_event_loop()
            self._loop = loop
            asyncio.set_event_loop(loop)
            try:
                loop.run_until_complete(self._boot())
            except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
                errors.append(exc)
                ready.set()
                loop.close()
                return
            loop.call_soon(ready.set)
            loop.run_forever()
            loop.run_until_complete(self._server.stop())
            loop.close()

        self._thread = threading.Thread(target=run, name="sim-opcua", daemon=True)
        self._thread.start()
        if not ready.wait(30):
            raise RuntimeError("the OPC UA server did not start within 30 s")
        if errors:
            self._thread.join(5)
            exc = errors[0]
            if isinstance(exc, OSError):
                raise self._bind_error(exc) from None
            raise exc
        return self

    def _probe(self) -> None:
        """Bind the wanted port the way the server will (``SO_REUSEADDR``) before the server's slow
        set-up, so a port in use is said at once."""
        if self._want_port == 0:
            return
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind((LOOPBACK, self._want_port))
            except OSError as exc:
                raise self._bind_error(exc) from None

    def _bind_error(self, exc: OSError) -> ConfigError:
        if exc.errno == errno.EADDRINUSE:
            return ConfigError(f"{OPCUA} port {self._want_port} on {LOOPBACK} is in use")
        return ConfigError(f"{OPCUA} port {self._want_port} on {LOOPBACK}: cannot listen ({exc.strerror or exc})")

    def stop(self) -> None:
        """Close the listener and every session; returns when the server thread has ended."""
        if self._loop is not None and self._loop.is_running() and not self._halted:
            self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(10)
        self._loop = None

    def lose_next_call(self, what: str) -> None:
        """Break the link at the next method call: ``"answer"`` acts on it and closes every
        connection before the answer leaves; ``"request"`` closes them without acting;
        ``"plant"`` acts, closes them and stops the server."""
        if what not in LINK_FAULTS:
            raise ValueError(f"lose_next_call: {what!r} is not one of {', '.join(LINK_FAULTS)}")
        self._faults.append(what)

    def _cut(self, stop: bool) -> None:
        """Close every client connection (and with ``stop`` the server) from a method's worker thread;
        returns once they are closed, so the method's answer has nowhere to go."""
        loop, done = self._loop, threading.Event()

        def cut():
            for transport in list(self._server.iserver.asyncio_transports):
                transport.close()
            if stop:
                self._halted = True
                loop.stop()
            done.set()

        loop.call_soon_threadsafe(cut)
        done.wait(5)

    def __enter__(self) -> OpcUaPlantService:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- the address space ------------------------------------------------------------------
    async def _boot(self) -> None:
        sec = self.security
        server = Server(user_manager=_Users(sec.users) if sec is not None and sec.users else None)
        await server.init()
        server.set_endpoint(f"opc.tcp://{LOOPBACK}:{self._want_port}/{PATH}")
        server.set_server_name("helicalib simulated plant")
        if sec is not None:
            await server.load_certificate(str(sec.certificate))
            await server.load_private_key(str(sec.private_key))
            server.set_security_policy([getattr(ua.SecurityPolicyType, f"{sec.policy}_{sec.mode}")])
            if sec.users:
                server.set_identity_tokens([ua.UserNameIdentityToken])
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        ns = await server.register_namespace(NAMESPACE)
        self._ns = ns
        await self._build(server, ns)
        server.iserver.subscribe_server_callback(CallbackType.PreRead, self._pre_read)
        await server.start()
        self._server = server
        self._port = server.bserver.port

    def _nid(self, ref: str, ns: int) -> ua.NodeId:
        return ua.NodeId.from_string(ref) if is_node_id(ref) else ua.NodeId(0, ns)  # 0: the server picks

    async def _build(self, server: Server, ns: int) -> None:
        m = self.map
        plant = await server.nodes.objects.add_folder(ua.NodeId(0, ns), ua.QualifiedName("Plant", ns))
        fld = await plant.add_object(self._nid(m.commands.field.object, ns), ua.QualifiedName("Field", ns))
        p = self.plant
        var = self._variable
        await var(server, fld, m.field.heliostat_count, "HeliostatCount", ua.VariantType.UInt32, lambda: p.n)
        await var(server, fld, m.field.state.node, "State", ua.VariantType.UInt16,
                  lambda: m.raw_field_state(p.field_state()))
        await var(server, fld, m.field.plant_time, "PlantTime", ua.VariantType.DateTime,
                  lambda: datetime.fromtimestamp(p.plant_time()[0], timezone.utc))
        if m.field.plant_time_rate is not None:
            await var(server, fld, m.field.plant_time_rate.node, "PlantTimeRate", ua.VariantType.Double,
                      lambda: m.field.plant_time_rate.raw(getattr(self.clock, "rate", p.rate)))
        await self._method(fld, m.commands.field, "Command", lambda *a: self._field(a), ns)
        weather = await plant.add_object(ua.NodeId(0, ns), ua.QualifiedName("Weather", ns))
        w = m.weather
        for num, name, attr in ((w.wind_ms, "WindSpeed", "wind_ms"), (w.wind_direction_deg, "WindDirection",
                                "wind_direction_deg"), (w.dni_wm2, "DNI", "dni_wm2"),
                                (w.temperature_c, "Temperature", "temperature_c"),
                                (w.pressure_hpa, "Pressure", "pressure_hpa")):
            await var(server, weather, num.node, name, ua.VariantType.Double,
                      lambda num=num, attr=attr: num.raw(getattr(p.weather(), attr)))
        folder = await plant.add_folder(ua.NodeId(0, ns), ua.QualifiedName("Heliostats", ns))
        h = m.heliostat
        for i, hid in enumerate(self.ids):
            obj = await folder.add_object(self._nid(fill(m.commands.move.object, i, hid), ns), ua.QualifiedName(hid, ns))
            for ref, name, kind, fn in (
                    (h.state.node, "State", ua.VariantType.UInt16, lambda i=i: m.raw_state(p.state[i])),
                    (h.sequence_done, "SequenceDone", ua.VariantType.UInt32, lambda i=i: int(p.sequence_done[i])),
                    (h.fault.node, "Fault", ua.VariantType.UInt16, lambda i=i: m.raw_fault(p.fault[i])),
                    (h.stroke_1_mm.node, "Stroke1", ua.VariantType.Double,
                     lambda i=i: h.stroke_1_mm.raw(p.strokes_mm[i, 0])),
                    (h.stroke_2_mm.node, "Stroke2", ua.VariantType.Double,
                     lambda i=i: h.stroke_2_mm.raw(p.strokes_mm[i, 1])),
                    (h.cleanliness.node, "Cleanliness", ua.VariantType.Double,
                     lambda i=i: h.cleanliness.raw(p.cleanliness_of(i)))):
                await var(server, obj, fill(ref, i, hid), name, kind, fn)
            c = m.commands
            for spec, name, command in ((c.move, "MoveTo", HeliostatCommand.MOVE), (c.track, "Track", HeliostatCommand.TRACK),
                                        (c.resume, "Resume", None), (c.stow, "Stow", HeliostatCommand.STOW)):
                if spec is not None:
                    await self._method(obj, spec, name, lambda *a, i=i, spec=spec, command=command, name=name:
                                       self._heliostat(i, name, spec, command, a), ns, i, hid)

    async def _variable(self, server, parent, ref: str, name: str, kind, value_fn) -> None:
        node = await parent.add_variable(self._nid(ref, self._ns), ua.QualifiedName(name, self._ns),
                                         ua.Variant(value_fn(), kind))

        def read(_nodeid, _attr):
            with self.lock:
                return ua.DataValue(ua.Variant(value_fn(), kind))

        server.set_attribute_value_callback(node.nodeid, read)

    async def _method(self, parent, spec, name: str, act, ns: int, i: int = 0, hid: str = "") -> None:
        args = [ua.Argument(Name=a, DataType=ua.NodeId(getattr(ua.ObjectIds, t)), ValueRank=-1)
                for a, t in spec.typed_args()]
        method = spec.method if not hid else fill(spec.method, i, hid)

        def call(_parent, *variants):
            values = tuple(v.Value for v in variants)
            if len(values) != len(args):
                return ua.StatusCode(ua.StatusCodes.BadArgumentsMissing if len(values) < len(args)
                                     else ua.StatusCodes.BadTooManyArguments)
            fault = self._faults.pop(0) if self._faults else None
            if fault != "request":
                act(*values)
            if fault is not None:
                self._cut(stop=fault == "plant")
            return []

        await parent.add_method(self._nid(method, ns), ua.QualifiedName(name, ns), call, args, [])

    # -- acting on commands -------------------------------------------------------------------
    def _sync(self) -> None:
        now = float(self.clock.now_s())
        if now > self.plant.t_s:
            self.plant.advance_to(now)

    def _pre_read(self, event, _dispatcher) -> None:
        with self.lock:
            self._sync()

    def _field(self, values: tuple) -> None:
        spec = self.map.commands.field
        named = dict(zip((a for a, _ in spec.typed_args()), values))
        raw = int(named.get("command", 0))
        by_raw = {v: FieldCommand[k] for k, v in spec.values.items()}
        with self.lock:
            self.calls.append(("Command", values))
            self._sync()
            self.plant.field_command(int(by_raw.get(raw, FieldCommand.NONE)))

    def _heliostat(self, i: int, name: str, spec, command, values: tuple) -> None:
        named = dict(zip((a for a, _ in spec.typed_args()), values))
        seq = int(named["sequence"])
        strokes = corrections = None
        if "stroke_1_mm" in named:
            strokes = [float(named["stroke_1_mm"]), float(named["stroke_2_mm"])]
        if "correction_1_mm" in named:
            corrections = [float(named["correction_1_mm"]), float(named["correction_2_mm"])]
        with self.lock:
            self.calls.append((name, (self.ids[i], *values)))
            self._sync()
            self.plant.write_command(i, int(command if command is not None else HeliostatCommand.TRACK), seq,
                                     strokes_mm=strokes, corrections_mm=corrections)

