"""The plant over OPC UA (asyncua), through a node map: the only client-side asyncua user.

:class:`OpcUaPlant` implements :class:`helicalib.devices.protocols.Plant` (and ``Hurries``) with a
synchronous façade over an asyncua client living in its own event-loop thread
(:class:`OpcUaLink`). A status read is one Read request of the heliostat's six nodes; a command is
one Read of its ``sequence_done`` and one Call of the map's method with a new sequence number,
which the plant's ``sequence_done`` shows once it took (or refused) the command.

Every request has the endpoint's timeout. A lost connection or a timeout is retried once after
reconnecting; then :class:`~helicalib.devices.protocols.PlantUnreachableError`. A Bad status code
of a node or a method (the server answered) is a one-line :class:`~helicalib.errors.PlantError`
naming the node and the heliostat. Safety comes from :class:`~helicalib.devices.guard.CommandGuard`
as for Modbus: no call without ``armed``, strokes range-checked before sending, the stow gate.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone

from asyncua import Client, ua
from asyncua.crypto import security_policies, uacrypto

from helicalib.devices.guard import CommandGuard
from helicalib.devices.nodemap import Method, NodeMap, fill, is_node_id, load_node_map
from helicalib.devices.protocols import HeliostatStatus, PlantUnreachableError, Weather
from helicalib.devices.registers import FieldCommand, FieldState, HeliostatCommand
from helicalib.errors import ConfigError, PlantError

LINK_CODES = frozenset(getattr(ua.StatusCodes, n) for n in (
    "BadConnectionClosed", "BadSessionIdInvalid", "BadSessionClosed", "BadSecureChannelIdInvalid",
    "BadSecureChannelClosed", "BadTimeout", "BadCommunicationError", "BadServerNotConnected",
    "BadNotConnected", "BadSessionNotActivated", "BadRequestInterrupted", "BadShutdown",
    "BadServerHalted", "BadDisconnect"))
"""Status codes that say the link failed, not the plant: reconnect and retry."""


@dataclass(frozen=True)
class Security:
    """How the client secures its channel and who it logs in as."""

    policy: str = "None"
    mode: str = "SignAndEncrypt"
    certificate: str | None = None
    private_key: str | None = None
    server_certificate: str | None = None
    username: str | None = None
    password: str | None = None


class _LinkDown(Exception):
    """The link failed (not the plant's answer): reconnect and retry."""


def quiet_asyncua() -> None:
    """Silence asyncua's own log (its connection and session lines would reach stderr through
    Python's last-resort handler): a failure is one :class:`PlantError` line of ours."""
    logging.getLogger("asyncua").setLevel(logging.CRITICAL)


def _status_name(code) -> str:
    return ua.StatusCode(code).name if not isinstance(code, ua.StatusCode) else code.name


class OpcUaLink:
    """One OPC UA endpoint: an asyncua client on an event loop thread, connected on first use,
    reconnected once per failed call (thread-safe).

    ``down_s``: after a call failed every attempt, further calls fail at once for this many real
    seconds (a tick asking 500 heliostats must not wait 500 timeouts).
    """

    def __init__(self, endpoint: str, timeout_s: float = 4.0, security: Security | None = None,
                 down_s: float = 5.0, monotonic: Callable[[], float] = time.monotonic):
        self.endpoint = endpoint
        self.timeout_s = float(timeout_s)
        self.security = security or Security()
        self.down_s = down_s
        self.attempts = 2
        self._monotonic = monotonic
        self._down_until = -math.inf
        self._down_reason = ""
        self._lock = threading.Lock()
        self._client: Client | None = None
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="opcua-client", daemon=True)
        self._thread.start()
        self._paths: dict[str, ua.NodeId] = {}

    def _run(self, coro, timeout_s: float):
        fut = asyncio.run_coroutine_threadsafe(coro, self._loop)
        try:
            return fut.result(timeout_s)
        except TimeoutError:
            fut.cancel()
            raise

    async def _open(self) -> Client:
        s = self.security
        client = Client(self.endpoint, timeout=self.timeout_s, watchdog_intervall=max(1.0, self.timeout_s))
        client.application_uri = "urn:helicalib:client"
        if s.policy != "None":
            cert = await uacrypto.load_certificate(s.certificate)
            uri = _certificate_uri(cert)
            if uri:
                client.application_uri = uri
            await client.set_security(getattr(security_policies, f"SecurityPolicy{s.policy}"), s.certificate,
                                      s.private_key, server_certificate=s.server_certificate,
                                      mode=getattr(ua.MessageSecurityMode, s.mode))
        if s.username is not None:
            client.set_user(s.username)
            client.set_password(s.password or "")
        try:
            await asyncio.wait_for(client.connect(), self.timeout_s)
        except BaseException:
            await self._close(client)
            raise
        return client

    async def _close(self, client: Client) -> None:
        try:
            await asyncio.wait_for(client.disconnect(), 1.0)
        except Exception:  # noqa: BLE001 - the link is gone either way
            pass

    def _drop(self) -> None:
        client, self._client = self._client, None
        self._paths.clear()
        if client is not None:
            try:
                self._run(self._close(client), 2.0)
            except Exception:  # noqa: BLE001
                pass

    def call(self, what: str, job: Callable[[Client, "OpcUaLink"], object]):
        """Run ``job(client, link)`` (a coroutine function) on the loop; ``what`` names it in errors."""
        with self._lock:
            if self._monotonic() < self._down_until:
                raise PlantUnreachableError(f"plant {self.endpoint}: {what} not tried: the plant did not answer "
                                            f"moments ago ({self._down_reason})")
            last = "no answer"
            for _ in range(self.attempts):
                try:
                    if self._client is None:
                        self._client = self._run(self._open(), self.timeout_s + 2.0)
                    out = self._run(job(self._client, self), 2 * self.timeout_s + 1.0)
                    self._down_until = -math.inf
                    return out
                except ua.UaStatusCodeError as exc:
                    if exc.code not in LINK_CODES:
                        if self._client is None:     # connecting was refused: a reachable plant said no
                            raise PlantError(f"plant {self.endpoint}: connecting refused: {_status_name(exc.code)}") from None
                        raise PlantError(f"plant {self.endpoint}: {what}: {_status_name(exc.code)}") from None
                    last = _status_name(exc.code)
                except (OSError, TimeoutError, asyncio.TimeoutError, ConnectionError, ua.UaError, _LinkDown) as exc:
                    last = f"{type(exc).__name__}: {exc}".strip().rstrip(":")
                self._drop()
            self._down_until = self._monotonic() + self.down_s
            self._down_reason = last
            raise PlantUnreachableError(f"plant {self.endpoint}: {what} failed after {self.attempts} "
                                        f"attempt{'s' * (self.attempts > 1)} ({last})")

    async def node_ids(self, client: Client, refs: Sequence[str]) -> list[ua.NodeId]:
        """Node ids of map references (browse paths from Objects resolved once, then kept)."""
        out = []
        for ref in refs:
            if is_node_id(ref):
                out.append(ua.NodeId.from_string(ref))
                continue
            nid = self._paths.get(ref)
            if nid is None:
                try:
                    node = await client.nodes.objects.get_child([p for p in ref.strip("/").split("/")])
                except ua.UaStatusCodeError as exc:
                    if exc.code in LINK_CODES:
                        raise
                    raise PlantError(f"plant {self.endpoint}: browse path {ref} from Objects: "
                                     f"{_status_name(exc.code)}") from None
                nid = self._paths[ref] = node.nodeid
            out.append(nid)
        return out

    def hurry(self) -> None:
        """One attempt per call from now on and a 1 s down window (a stopping controller)."""
        self.attempts = 1
        self.down_s = min(self.down_s, 1.0)

    def close(self) -> None:
        with self._lock:
            self._drop()
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5)


def _certificate_uri(cert) -> str | None:
    """The application URI in a certificate's subject alternative names (what servers check)."""
    from cryptography import x509

    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None


def _number(value, what: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise PlantError(f"{what}: {value!r} is not a number") from None
    if not math.isfinite(out):
        raise PlantError(f"{what}: {out!r} is not finite")
    return out


def _seconds(value, what: str) -> float:
    """Plant time from a DateTime (UTC) or a number of UTC seconds."""
    if isinstance(value, datetime):
        return (value if value.tzinfo else value.replace(tzinfo=timezone.utc)).timestamp()
    return _number(value, what)


class OpcUaPlant:
    """The plant's SCS and weather station over OPC UA; implements ``devices.protocols.Plant``.

    Parameters
    ----------
    endpoint : str
        ``opc.tcp://host:port/path``.
    node_map : NodeMap
    heliostat_ids : sequence of str
        Ids by block index: they fill the map's ``{id}`` and name heliostats in messages.
    heliostat_count : int, optional
        Expected number of heliostats (the field config's); a plant reporting another is refused.
    armed : bool
        Allow commands. False (default): every command raises :class:`PlantError` before anything is sent.
    stroke_limits_mm : array_like, shape (N, 2, 2), optional
        A stroke command outside is refused before it is sent.
    timeout_s : float
        Per-request timeout [s].
    security : Security, optional
    """

    def __init__(self, endpoint: str, node_map: NodeMap, heliostat_ids: Sequence[str],
                 heliostat_count: int | None = None, *, armed: bool = False, stroke_limits_mm=None,
                 timeout_s: float = 4.0, security: Security | None = None, **link_kw):
        quiet_asyncua()
        self.map = node_map
        self.link = OpcUaLink(endpoint, timeout_s, security, **link_kw)
        self.guard = CommandGuard(armed, heliostat_ids, stroke_limits_mm)
        self.ids = list(heliostat_ids)
        self._expected_count = heliostat_count
        self._count: int | None = None
        self._last_sent: dict[int, int] = {}

    @classmethod
    def from_config(cls, cfg, *, armed: bool = False, **kw) -> "OpcUaPlant":
        """The client of ``cfg.plant.opcua``: its node map (a file next to the field config or a
        shipped name), security, user and password (from the environment variable ``password_env``)."""
        o = cfg.plant.opcua
        where = cfg.source or "field config"
        nm = load_node_map(o.node_map, cfg.resolve_path)
        password = None
        if o.password_env is not None:
            password = os.environ.get(o.password_env)
            if password is None:
                raise ConfigError(f"{where}: plant.opcua.password_env: the environment variable {o.password_env} "
                                  "is not set (it holds the OPC UA user's password)")
        if o.security_policy != "None" and (o.certificate is None or o.private_key is None):
            raise ConfigError(f"{where}: plant.opcua: security_policy {o.security_policy} needs certificate and "
                              "private_key (the client's own, PEM)")
        path = lambda p: None if p is None else str(cfg.resolve_path(p))  # noqa: E731
        sec = Security(o.security_policy, o.security_mode, path(o.certificate), path(o.private_key),
                       path(o.server_certificate), o.username, password)
        g = CommandGuard.from_config(cfg, armed)
        kw.setdefault("timeout_s", o.timeout_s)
        return cls(o.endpoint, nm, g.heliostat_ids, len(cfg.heliostats), armed=armed,
                   stroke_limits_mm=g.stroke_limits_mm, security=sec, **kw)

    @property
    def armed(self) -> bool:
        return self.guard.armed

    @property
    def stowed(self) -> bool:
        """Whether this client sent STOW ALL and no RESUME TRACKING since (moves and tracks are refused)."""
        return self.guard.stowed

    def hurry(self) -> None:
        """One attempt per request from now on (a stopping controller must not wait out retries)."""
        self.link.hurry()

    def close(self) -> None:
        self.link.close()

    def __enter__(self) -> "OpcUaPlant":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ reads
    def _read(self, refs: Sequence[str], names: Sequence[str], what: str) -> list:
        """Values of the nodes ``refs`` in one Read request; a Bad status names the node."""
        link = self.link

        async def job(client, link):
            nids = await link.node_ids(client, refs)
            dvs = await client.uaclient.read_attributes(nids, ua.AttributeIds.Value)
            out = []
            for ref, name, dv in zip(refs, names, dvs):
                if not dv.StatusCode.is_good():
                    raise PlantError(f"plant {link.endpoint}: {name} (node {ref}): {dv.StatusCode.name}")
                out.append(dv.Value.Value if dv.Value is not None else None)
            return out

        return link.call(f"read of {what}", job)

    def _label(self, index: int) -> str:
        return self.guard.label(index)

    def _check_index(self, index: int) -> None:
        n = self.heliostat_count()
        if not 0 <= int(index) < n:
            raise PlantError(f"heliostat index {index} outside the plant's 0..{n - 1}")

    def heliostat_count(self) -> int:
        """Heliostats the plant reports (checked once against the expected count)."""
        if self._count is None:
            (raw,) = self._read([self.map.field.heliostat_count], ["heliostat count"], "heliostat count")
            count = int(_number(raw, f"plant {self.link.endpoint}: heliostat count"))
            if self._expected_count is not None and count != self._expected_count:
                raise PlantError(f"plant {self.link.endpoint}: reports {count} heliostats, the field config has "
                                 f"{self._expected_count}; the heliostat order must match the config")
            self._count = count
        return self._count

    def plant_time(self) -> tuple[float, float]:
        """(plant time [UTC s], rate); a map without a rate node: rate 1."""
        f = self.map.field
        refs, names = [f.plant_time], ["plant time"]
        if f.plant_time_rate is not None:
            refs.append(f.plant_time_rate.node)
            names.append("plant time rate")
        vals = self._read(refs, names, "plant time and rate")
        t = _seconds(vals[0], f"plant {self.link.endpoint}: plant time (node {f.plant_time})")
        rate = f.plant_time_rate.value(_number(vals[1], "plant time rate")) if len(vals) > 1 else 1.0
        if not (math.isfinite(t) and rate > 0):
            raise PlantError(f"plant {self.link.endpoint}: plant time {t!r} / rate {rate!r} outside the contract")
        return t, rate

    def weather(self) -> Weather:
        """Wind, direction, DNI, temperature, pressure in one Read."""
        w = self.map.weather
        keys = ("wind_ms", "wind_direction_deg", "dni_wm2", "temperature_c", "pressure_hpa")
        nums = [getattr(w, k) for k in keys]
        vals = self._read([n.node for n in nums], list(keys), "weather")
        return Weather(**{k: n.value(_number(v, f"plant {self.link.endpoint}: weather {k} (node {n.node})"))
                          for k, n, v in zip(keys, nums, vals)})

    def field_state(self) -> FieldState:
        node = self.map.field.state.node
        (raw,) = self._read([node], ["field state"], "field state")
        state = self.map.field_state_of(int(_number(raw, "field state")))
        if state is None:
            raise PlantError(f"plant {self.link.endpoint}: field state {raw!r} (node {node}) not in the node map")
        return state

    def _refs(self, index: int) -> list[str]:
        return [fill(r, index, self.ids[index]) for r in self.map.heliostat.order()]

    def status(self, index: int) -> HeliostatStatus:
        """State, last sequence processed, fault code, actual strokes, cleanliness in one Read."""
        self._check_index(index)
        h, label = self.map.heliostat, self._label(index)
        refs = self._refs(index)
        names = [f"{label} {n}" for n in ("state", "sequence done", "fault", "stroke 1", "stroke 2", "cleanliness")]
        v = self._read(refs, names, f"{label} status")
        nums = [_number(x, f"plant {self.link.endpoint}: {n} (node {r})") for x, n, r in zip(v, names, refs)]
        state = self.map.state_of(int(nums[0]))
        if state is None:
            raise PlantError(f"plant {self.link.endpoint}: {label} state {v[0]!r} (node {refs[0]}) not in the node map")
        fault = self.map.fault_of(int(nums[2]))
        if fault is None:
            raise PlantError(f"plant {self.link.endpoint}: {label} fault code {v[2]!r} (node {refs[2]}) not in the "
                             "node map")
        return HeliostatStatus(index=int(index), state=state, sequence_done=int(nums[1]), fault=int(fault),
                               strokes_mm=(h.stroke_1_mm.value(nums[3]), h.stroke_2_mm.value(nums[4])),
                               cleanliness=h.cleanliness.value(nums[5]))

    # ------------------------------------------------------------------ commands
    def _invoke(self, spec: Method, args: dict, what: str, index: int | None = None) -> None:
        """Call the map's method with ``args`` in its argument order and types."""
        obj, method = (spec.object, spec.method) if index is None else \
            (fill(spec.object, index, self.ids[index]), fill(spec.method, index, self.ids[index]))
        variants = [ua.Variant(args[name] if kind in ("String",) else _typed(args[name], kind),
                               getattr(ua.VariantType, kind)) for name, kind in spec.typed_args()]

        async def job(client, link):
            oid, mid = await link.node_ids(client, [obj, method])
            (res,) = await client.uaclient.call([ua.CallMethodRequest(ObjectId=oid, MethodId=mid,
                                                                      InputArguments=variants)])
            if not res.StatusCode.is_good():
                raise PlantError(f"plant {link.endpoint}: {what}: method {method} on {obj}: {res.StatusCode.name}")

        self.link.call(what, job)

    def field_command(self, command: int) -> None:
        """Field command: 1 stow all (from then on every move and track command is refused), 2 resume
        tracking all (the gate opens again)."""
        cmd = FieldCommand(int(command))
        self.guard.refuse_unarmed(f"field command {cmd.name}")
        spec = self.map.commands.field
        if cmd.name not in spec.values:
            raise PlantError(f"field command {cmd.name}: the node map's commands.field.values has no value for it")
        with self.guard.lock:
            self._invoke(spec, {"command": spec.values[cmd.name]}, f"field command {cmd.name}")
            self.guard.field_sent(cmd)

    def _command(self, index: int, command: HeliostatCommand, spec: Method | None, args: dict) -> int:
        what = f"{command.name} command to {self._label(index)}"
        self.guard.refuse_unarmed(what)
        if spec is None:
            raise PlantError(f"{what} not sent: the node map has no commands.resume (tracking with the plant's "
                             "own corrections)")
        self._check_index(index)
        with self.guard.lock:
            self.guard.gate(command, what)
            ref = fill(self.map.heliostat.sequence_done, index, self.ids[index])
            (done,) = self._read([ref], [f"{self._label(index)} sequence done"], f"{self._label(index)} sequence done")
            mod = self.map.commands.sequence_modulus
            done = int(_number(done, "sequence done")) % mod
            seq = (max(done, self._last_sent.get(index, done)) + 1) % mod
            while seq == done:
                seq = (seq + 1) % mod
            self._invoke(spec, {**args, "sequence": seq, "index": index, "id": self.ids[index]}, what, index)
            self._last_sent[index] = seq
        return seq

    def move_to(self, index: int, strokes_mm) -> int:
        """Command strokes (actuator 1, 2) [mm] and hold; returns the sequence number sent. Strokes
        outside the drive's range are refused before anything is sent."""
        s = self.guard.strokes(index, strokes_mm)
        return self._command(index, HeliostatCommand.MOVE, self.map.commands.move,
                             {"stroke_1_mm": float(s[0]), "stroke_2_mm": float(s[1])})

    def track(self, index: int, corrections_mm) -> int:
        """Return to tracking with these stroke corrections [mm]; ``None``: with the plant's own (the
        map's ``resume`` method). Returns the sequence number."""
        if corrections_mm is None:
            return self._command(index, HeliostatCommand.TRACK, self.map.commands.resume, {})
        c = self.guard.corrections(index, corrections_mm)
        return self._command(index, HeliostatCommand.TRACK, self.map.commands.track,
                             {"correction_1_mm": float(c[0]), "correction_2_mm": float(c[1])})

    def stow(self, index: int) -> int:
        """Send one heliostat to stow; returns the sequence number."""
        return self._command(index, HeliostatCommand.STOW, self.map.commands.stow, {})


def _typed(value, kind: str):
    return float(value) if kind in ("Float", "Double") else (bool(value) if kind == "Boolean" else int(value))
