"""The plant over OPC UA (asyncua), through a node map: the only client-side asyncua user.

:class:`OpcUaPlant` implements :class:`helicalib.devices.protocols.Plant` (and ``Hurries``) over
:class:`~helicalib.devices.opcua_link.OpcUaLink` (an asyncua client on its own event-loop
thread). A status read is one Read request of the heliostat's six nodes; a command is one Read
of its ``sequence_done`` and one Call of the map's method with a new sequence number, which the
plant's ``sequence_done`` shows once it took (or refused) the command.

Every request has the endpoint's timeout. A lost connection or a timeout is retried once after
reconnecting; then :class:`~helicalib.devices.protocols.PlantUnreachableError`. A command's Call
is never sent twice: when its answer is lost, the heliostat's ``sequence_done`` says whether it
was taken. A Bad status code of a node or a method (the server answered) is a one-line
:class:`~helicalib.errors.PlantError` naming the node and the heliostat. Safety comes from
:class:`~helicalib.devices.guard.CommandGuard` as for Modbus: no call without ``armed``, strokes
range-checked before sending (and still inside the range as the argument's type carries them),
the stow gate.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from datetime import datetime, timezone

import numpy as np
from asyncua import ua

from helicalib.devices.guard import CommandGuard
from helicalib.devices.nodemap import (
    INT_RANGES,
    Method,
    NodeMap,
    check_fits,
    fill,
    load_node_map,
)
from helicalib.devices.opcua_link import CallInDoubt, OpcUaLink, Security, quiet_asyncua
from helicalib.devices.protocols import HeliostatStatus, PlantUnreachableError, Weather
from helicalib.devices.registers import FieldCommand, FieldState, HeliostatCommand
from helicalib.errors import ConfigError, PlantError

__all__ = ["OpcUaPlant", "Security", "quiet_asyncua"]


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
            dvs = await link.request(client.uaclient.read_attributes(nids, ua.AttributeIds.Value))
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
        self.guard.check_index(index, self.heliostat_count())

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
        """Call the map's method with ``args`` in its argument order and types; a value its type
        cannot carry is a :class:`PlantError` before anything is sent. :class:`CallInDoubt` when the
        Call may have reached the plant but its answer did not come back (it is not sent again)."""
        obj, method = (spec.object, spec.method) if index is None else \
            (fill(spec.object, index, self.ids[index]), fill(spec.method, index, self.ids[index]))
        variants = []
        for name, kind in spec.typed_args():
            value = args[name]
            if kind in INT_RANGES:
                try:
                    check_fits(kind, int(value), f"argument {name}")
                except ValueError as exc:
                    raise PlantError(f"plant {self.link.endpoint}: {what} not sent: {exc}") from None
            elif kind in ("Float", "Double"):
                value = float(value)
            variants.append(ua.Variant(value, getattr(ua.VariantType, kind)))

        async def job(client, link):
            oid, mid = await link.node_ids(client, [obj, method])
            request = ua.CallMethodRequest(ObjectId=oid, MethodId=mid, InputArguments=variants)
            (res,) = await link.request(client.uaclient.call([request]), acts=True)
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
        what = f"field command {cmd.name}"
        with self.guard.lock:
            try:
                self._invoke(spec, {"command": spec.values[cmd.name]}, what)
            except CallInDoubt as exc:
                if cmd == FieldCommand.STOW_ALL:      # it may have been taken: hold moves and tracks back
                    self.guard.field_sent(cmd)
                raise PlantError(f"plant {self.link.endpoint}: {what} may or may not have been taken; not resent "
                                 f"(its answer was lost: {exc})") from None
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
            done = self._sequence_done(index)
            mod = self.map.commands.sequence_modulus
            seq = (max(done, self._last_sent.get(index, done)) + 1) % mod
            while seq == done:
                seq = (seq + 1) % mod
            try:
                self._invoke(spec, {**args, "sequence": seq, "index": index, "id": self.ids[index]}, what, index)
            except CallInDoubt as exc:
                self._last_sent[index] = seq      # it may be in flight: never reuse its number
                return self._settle(index, seq, what, str(exc))
            self._last_sent[index] = seq
        return seq

    def _sequence_done(self, index: int) -> int:
        """The last sequence number the heliostat processed, as the plant shows it (one Read)."""
        ref = fill(self.map.heliostat.sequence_done, index, self.ids[index])
        name = f"{self._label(index)} sequence done"
        (done,) = self._read([ref], [name], name)
        done = int(_number(done, f"plant {self.link.endpoint}: {name} (node {ref})"))
        return done % self.map.commands.sequence_modulus

    def _settle(self, index: int, seq: int, what: str, lost: str) -> int:
        """A command whose answer was lost: ``seq`` if the plant's ``sequence_done`` shows it took it,
        else a one-line error (never a second Call: the plant may be acting on the first)."""
        head = f"plant {self.link.endpoint}: {what} (sequence {seq}) may or may not have been taken; not resent"
        try:
            done = self._sequence_done(index)
        except PlantError as exc:
            kind = PlantUnreachableError if isinstance(exc, PlantUnreachableError) else PlantError
            raise kind(f"{head} (its answer was lost: {lost}; then {exc})") from None
        if done == seq:
            return seq
        raise PlantError(f"{head} (its answer was lost: {lost}; sequence done reads {done})")

    def move_to(self, index: int, strokes_mm) -> int:
        """Command strokes (actuator 1, 2) [mm] and hold; returns the sequence number sent. Strokes
        outside the drive's range are refused before anything is sent."""
        s = [float(x) for x in self.guard.strokes(index, strokes_mm)]
        spec, limits = self.map.commands.move, self.guard.stroke_limits_mm
        for k, name in enumerate(("stroke_1_mm", "stroke_2_mm")):
            if limits is not None and spec.type_of(name) == "Float":
                s[k] = _float32_inside(s[k], limits[index, k])
        return self._command(index, HeliostatCommand.MOVE, spec, {"stroke_1_mm": s[0], "stroke_2_mm": s[1]})

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


def _float32_inside(value: float, limits) -> float:
    """The Float (32-bit) nearest ``value`` that stays inside ``limits`` (min, max): a range-checked
    stroke rounded to a Float must not reach the drive outside its range."""
    f = np.float32(value)
    if f < limits[0]:
        f = np.nextafter(f, np.float32(np.inf))
    elif f > limits[1]:
        f = np.nextafter(f, np.float32(-np.inf))
    return float(f)
