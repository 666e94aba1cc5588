"""The plant over Modbus TCP, in the layout of its register map (default ``PLANT_INTERFACE.md``
version 1; docs/register-maps.md).

:class:`ModbusPlant` implements :class:`helicalib.devices.protocols.Plant` through a
:class:`~helicalib.devices.modbus_link.ModbusLink` per endpoint (timeouts, retries with back-off,
reconnection; a Modbus exception answer is not retried). Failures raise :class:`~helicalib.errors.PlantError` naming the endpoint,
the register (address and meaning) and the heliostat; a plant that did not answer at all raises
its subclass :class:`~helicalib.devices.protocols.PlantUnreachableError`. Writes are refused unless ``armed=True``:
an unarmed client reads and plans but never writes to the plant.

A heliostat command is written as the map's handshake asks: the command fields, the mode (unless
the mode register, read with the handshake's registers just before, already holds it), then
either a sequence number different from the one in the register (``sequence``: the plant acts on
the change) or 1 to the execute register (``execute``: the plant acts, sets it back to 0 and counts
the command); a still-set execute register refuses the command (the plant has not taken the last one).
The execute write is sent once, never retried: if its answer is lost, the counter is read once and
the command counts as taken only if the counter shows it; otherwise a :class:`PlantError` says it may
or may not have been taken (a second execute would be a second command).

The client is the field's stow gate: once it has sent STOW ALL, it refuses every move and track
command (:class:`~helicalib.devices.protocols.FieldStowedError`) until it sends RESUME TRACKING.
Field commands and heliostat commands take one lock, so a stow sent from another thread (the
weather job) never lands between a command's fields and its sequence number, and no command
already waiting is sent after it.
"""

from __future__ import annotations

import math
import threading
import time
from contextlib import nullcontext
from collections.abc import Callable, Sequence

import numpy as np

from helicalib.devices.guard import CommandGuard
from helicalib.devices.modbus_batch import Sent, TrackBatch
from helicalib.devices.modbus_link import ModbusLink, quiet_pymodbus
from helicalib.devices.protocols import HeliostatStatus, PlantUnreachableError, Weather
from helicalib.devices.regcodec import decode, decode_raw, encode, encode_raw, plan_reads, raw_within, state_name
from helicalib.devices.registers import FaultCode, FieldCommand, FieldState, HeliostatCommand, HeliostatState
from helicalib.devices.regmap import load_register_map, register_map_of
from helicalib.devices.regschema import Q
from helicalib.errors import PlantError

__all__ = ["ModbusLink", "ModbusPlant", "quiet_pymodbus"]
"""``ModbusLink`` and ``quiet_pymodbus`` live in :mod:`helicalib.devices.modbus_link`; named here too
for the callers that know the plant client's module."""

_NOTHING = nullcontext()
HANDSHAKE = "heliostats.command.handshake."
STATUS_PATHS = ("heliostats.status.state", "heliostats.status.fault", "heliostats.status.strokes_mm[0]",
                "heliostats.status.strokes_mm[1]", "heliostats.status.cleanliness")
WEATHER_KEYS = ("wind_ms", "wind_direction_deg", "dni_wm2", "temperature_c", "pressure_hpa")
FIELD_COMMAND_NAME = {FieldCommand.NONE: "none", FieldCommand.STOW_ALL: "stow", FieldCommand.RESUME_TRACKING: "resume"}


class ModbusPlant:
    """The plant's SCS and weather station over Modbus TCP; implements ``devices.protocols.Plant``.

    Parameters
    ----------
    endpoint : helicalib.config.Endpoint
        SCS ``host``, ``port``, ``unit``, ``timeout_s``.
    weather_endpoint : helicalib.config.Endpoint, optional
        Weather station (default: the SCS endpoint, same connection).
    heliostat_count : int, optional
        Expected number of heliostats (the field config's); a plant reporting another is refused.
    armed : bool
        Allow writes. False (default): every write raises :class:`PlantError` before anything is sent.
    heliostat_ids : sequence of str, optional
        Ids by block index, for messages.
    stroke_limits_mm : array_like, shape (N, 2, 2), optional
        ``[i, actuator, (min, max)]``: a stroke command outside is refused before it is sent (a
        second guard behind the controller's own check).
    register_map : RegisterMap, str or Path, optional
        The plant's register map (default: ``PLANT_INTERFACE.md``); see :func:`load_register_map`.
    retries, backoff_s, backoff_max_s, sleep :
        See :class:`ModbusLink`.
    """

    def __init__(self, endpoint, weather_endpoint=None, heliostat_count: int | None = None, *, armed: bool = False,
                 heliostat_ids: Sequence[str] | None = None, stroke_limits_mm=None, register_map=None,
                 retries: int = 3, backoff_s: float = 0.2, backoff_max_s: float = 5.0,
                 sleep: Callable[[float], None] = time.sleep):
        kw = dict(retries=retries, backoff_s=backoff_s, backoff_max_s=backoff_max_s, sleep=sleep)
        self.scs = ModbusLink(endpoint.host, endpoint.port, endpoint.unit, endpoint.timeout_s, **kw)
        w = weather_endpoint
        if w is None or (w.host, w.port, w.unit) == (endpoint.host, endpoint.port, endpoint.unit):
            self.weather_link = self.scs
        else:
            self.weather_link = ModbusLink(w.host, w.port, w.unit, getattr(w, "timeout_s", endpoint.timeout_s), **kw)
        self.map = load_register_map(register_map)
        if heliostat_count is not None:
            self.map.check_count(heliostat_count, endpoint.unit)
        self.guard = CommandGuard(armed, heliostat_ids, stroke_limits_mm)
        self._expected_count = heliostat_count
        self._count: int | None = None
        self._last_sent: dict[int, int] = {}
        self._batch: TrackBatch | None = None
        self._one_at_a_time = threading.Lock()  # the SCS connection's heliostat commands, one after another
        self._link_kw = dict(kw, timeout_s=endpoint.timeout_s)
        q = self.map.q
        self._hs = self.map.doc.heliostats.command.handshake
        self._status_q = [q[k] for k in STATUS_PATHS] + [q[HANDSHAKE + "done"]]
        self._command_q = self._status_q + ([q[HANDSHAKE + "sequence"]] if self._hs.kind == "sequence"
                                            else [q[HANDSHAKE + "execute"]]) + [q["heliostats.command.mode"]]

    @classmethod
    def from_config(cls, cfg, *, armed: bool = False, register_map=None, **kw) -> "ModbusPlant":
        """The client of the plant a field config names, with its heliostat ids and stroke ranges;
        ``register_map`` (a file or a shipped name) overrides the config's ``plant.register_map``."""
        g = CommandGuard.from_config(cfg, armed)
        rmap = register_map_of(cfg, register_map)
        return cls(cfg.plant.scs, cfg.plant.weather_endpoint, len(cfg.heliostats), armed=armed,
                   heliostat_ids=g.heliostat_ids, stroke_limits_mm=g.stroke_limits_mm, register_map=rmap, **kw)

    @property
    def armed(self) -> bool:
        return self.guard.armed

    def hurry(self) -> None:
        """Two attempts per request from now on, no back-off (a stopping controller must not wait out retries)."""
        self.scs.hurry()
        self.weather_link.hurry()
        if self._batch is not None:
            self._batch.hurry()

    def close(self) -> None:
        if self._batch is not None:
            self._batch.close()
        self.scs.close()
        if self.weather_link is not self.scs:
            self.weather_link.close()

    def __enter__(self) -> "ModbusPlant":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ helpers
    def _label(self, index: int) -> str:
        return self.guard.label(index)

    def _check_index(self, index: int) -> None:
        self.guard.check_index(index, self.heliostat_count())

    def _where(self, q: Q, index: int | None = None) -> str:
        """``input 10002 (heliostats.status.strokes_mm[0])``: a quantity's register in messages (with
        its unit id when the heliostat's block lies on another unit than the endpoint's)."""
        step = self.map.unit_step(index) if q.block and index is not None else 0
        unit = f"unit {self.scs.unit + step} " if step else ""
        return f"{unit}{q.table} {self.map.address(q, index)} ({q.path})"

    def _read(self, qs: list[Q], what: str, index: int | None = None, link: ModbusLink | None = None) -> dict[str, list[int]]:
        """The registers of ``qs`` (plant-wide, or of heliostat ``index``'s block), in few requests."""
        m = self.map
        base = 0 if index is None else m.block_address(index)
        if index is None:
            readable = m.plant_readable
        else:
            readable = lambda table, a: 0 <= a - base < m.block_extent(table)
        wanted = [(q.table, base + r if q.block else r) for q in qs for r in q.registers]
        image: dict[tuple[str, int], int] = {}
        unit = {} if index is None or not m.unit_step(index) else {"unit": self.scs.unit + m.unit_step(index)}
        for table, start, count in plan_reads(wanted, readable):
            link = link or self.scs
            got = link.read(start, count, what, **unit, **({} if table == "holding" else {"table": table}))
            for k, v in enumerate(got):
                image[(table, start + k)] = v
        return {q.path: [image.get((q.table, m.address(q, index) + k), 0) for k in range(q.width)] for q in qs}

    def _write(self, table: str, address: int, values: list[int], what: str, retry: bool = True,
               index: int | None = None, link: ModbusLink | None = None) -> None:
        kw = {} if retry else {"retry": False}
        if index is not None and self.map.unit_step(index):
            kw["unit"] = self.scs.unit + self.map.unit_step(index)
        if table == "holding":
            (link or self.scs).write(address, values, what, **kw)
        else:
            (link or self.scs).write(address, values, what, table=table, **kw)

    def _value(self, q: Q, regs: list[int], who: str, index: int | None = None) -> float:
        """The value of ``q`` (of heliostat ``index``, named ``who``); not finite: a PlantError naming its register."""
        v = decode(q, regs)
        if not math.isfinite(v):
            raise PlantError(f"plant {self.scs.name}: {who}: {v!r} at {self._where(q, index)}: not a finite number")
        return v

    # ------------------------------------------------------------------ reads
    def interface_version(self) -> int | None:
        """The first identity register's value (PLANT_INTERFACE's interface version); None: the map has none."""
        q = self.map.q.get("identity[0]")
        return None if q is None else int(decode(q, self._read([q], "interface version")[q.path]))

    def heliostat_count(self) -> int:
        """Heliostats the plant reports (checked once against the map's identity and the expected count)."""
        if self._count is None:
            ids = [q for p, q in self.map.q.items() if p.startswith("identity[")]
            cq = self.map.q["plant.heliostat_count"]
            regs = self._read(ids + [cq], "interface version and heliostat count" if ids else "heliostat count")
            for q in ids:
                value = decode(q, regs[q.path])
                if value != q.equals:
                    raise PlantError(f"plant {self.scs.name}: {q.meaning or q.path} {value:g} at {q.table} {q.start}, "
                                     f"the register map {self.map.name} expects {q.equals}")
            count = int(decode(cq, regs[cq.path]))
            if self._expected_count is not None and count != self._expected_count:
                raise PlantError(f"plant {self.scs.name}: reports {count} heliostats, the field config has "
                                 f"{self._expected_count}; the block order must match the config")
            self._count = count
        return self._count

    def plant_time(self) -> tuple[float, float]:
        """(plant time [UTC s], rate); a map without a rate register: rate 1."""
        tq, rq = self.map.q["plant.clock.time"], self.map.q.get("plant.clock.rate")
        regs = self._read([tq] + ([rq] if rq else []), "plant time and rate")
        t = decode(tq, regs[tq.path])
        rate = decode(rq, regs[rq.path]) if rq else 1.0
        if not (math.isfinite(t) and math.isfinite(rate) and rate > 0):
            raise PlantError(f"plant {self.scs.name}: plant time {t!r} / rate {rate!r} outside the contract")
        return t, rate

    def weather(self) -> Weather:
        """Wind, direction, DNI, temperature, pressure (the map's weather quantities)."""
        qs = [self.map.q[f"weather.{k}"] for k in WEATHER_KEYS]
        regs = self._read(qs, "weather block", link=self.weather_link)
        return Weather(**{k: self._value(q, regs[q.path], "weather") for k, q in zip(WEATHER_KEYS, qs)})

    def field_state(self) -> FieldState:
        q = self.map.q["plant.field_state"]
        raw = int(decode_raw(q, self._read([q], "field state")[q.path]))
        name = state_name(q, raw)
        if name is None:
            raise PlantError(f"plant {self.scs.name}: field state {raw} at {self._where(q)} is not in the register "
                             f"map {self.map.name} ({sorted(q.values)})")
        return FieldState[name.upper()]

    def _block(self, index: int, qs: list[Q], link: ModbusLink | None = None) -> dict[str, list[int]]:
        self._check_index(index)
        return self._read(qs, f"{self._label(index)} block", index, link)

    def _status(self, index: int, regs: dict[str, list[int]]) -> HeliostatStatus:
        q = self.map.q
        sq, fq = q["heliostats.status.state"], q["heliostats.status.fault"]
        raw = int(decode_raw(sq, regs[sq.path]))
        name = state_name(sq, raw)
        if name is None:
            raise PlantError(f"plant {self.scs.name}: {self._label(index)} state {raw} at {self._where(sq, index)} "
                             f"is not in the register map {self.map.name}")
        fraw = int(decode_raw(fq, regs[fq.path]))
        fname = state_name(fq, fraw)
        if fname is None:  # passed on raw, a plant's own code could read as one of helicalib's
            raise PlantError(f"plant {self.scs.name}: {self._label(index)} fault code {fraw} at "
                             f"{self._where(fq, index)} is not in the register map {self.map.name} ({sorted(fq.values)})")
        fault = FaultCode[fname.upper()].value
        who = self._label(index)
        s = tuple(self._value(q[f"heliostats.status.strokes_mm[{k}]"], regs[f"heliostats.status.strokes_mm[{k}]"], who,
                              index) for k in (0, 1))
        clean = self._value(q["heliostats.status.cleanliness"], regs["heliostats.status.cleanliness"], who, index)
        done = int(decode_raw(q[HANDSHAKE + "done"], regs[HANDSHAKE + "done"]))
        return HeliostatStatus(index=int(index), state=HeliostatState[name.upper()], sequence_done=done,
                               fault=fault, strokes_mm=s, cleanliness=clean)

    def status(self, index: int) -> HeliostatStatus:
        """State, last command taken (the handshake's token), fault code, actual strokes, cleanliness."""
        return self._status(index, self._block(index, self._status_q))

    def cleanliness_many(self, indices) -> np.ndarray:
        """The cleanliness registers (k,) of heliostats ``indices`` (k,), read through neighbouring
        blocks (up to 125 registers a request: about 4 heliostats of PLANT_INTERFACE.md's 32-register
        blocks) instead of one request each; NaN where a read fails or the value is not finite (what
        a failed :meth:`status` leaves: the planner reads a board's candidates at once)."""
        q = self.map.q["heliostats.status.cleanliness"]
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        out = np.full(idx.size, np.nan)
        try:  # a count that cannot be read, or a heliostat the plant does not have: NaN, as status() gives
            count = self.heliostat_count()
        except PlantError:
            return out
        by_unit: dict[int, list[int]] = {}
        for k, i in enumerate(idx.tolist()):
            try:
                self.guard.check_index(i, count)
            except PlantError:
                continue
            by_unit.setdefault(self.map.unit_step(i), []).append(k)
        for step, ks in by_unit.items():
            at = {self.map.address(q, int(idx[k])): k for k in ks}
            wanted = [(q.table, a + j) for a in at for j in range(q.width)]
            unit = {"unit": self.scs.unit + step} if step else {}
            for table, start, n in plan_reads(wanted, self._in_a_block):
                try:
                    got = self.scs.read(start, n, f"cleanliness of {len(ks)} heliostats", table=table, **unit)
                except PlantError:
                    continue
                for a, k in at.items():
                    if start <= a and a + q.width <= start + n:
                        v = decode(q, got[a - start:a - start + q.width])
                        out[k] = v if math.isfinite(v) else np.nan
        return out

    def _in_a_block(self, table: str, address: int) -> bool:
        """Whether ``address`` answers reads as part of some heliostat's block (base and stride maps)."""
        h = self.map.doc.heliostats
        if h.addresses is not None or address < h.base:
            return False
        i, off = divmod(address - h.base, h.stride)
        return off < self.map.block_extent(table) and i < (h.per_unit or self.heliostat_count())

    # ------------------------------------------------------------------ writes
    @property
    def stowed(self) -> bool:
        """Whether this client sent STOW ALL and no RESUME TRACKING since (moves and tracks are refused)."""
        return self.guard.stowed

    def field_command(self, command: int) -> None:
        """Field command: 1 stow all (from then on every move and track command is refused), 2 resume
        tracking all (the gate opens again)."""
        cmd = FieldCommand(int(command))
        self.guard.refuse_unarmed(f"field command {cmd.name}")
        q = self.map.q["plant.field_command"]
        value = q.values.get(FIELD_COMMAND_NAME[cmd])
        if value is None:
            raise PlantError(f"plant {self.scs.name}: the register map {self.map.name} has no value for field "
                             f"command {cmd.name} ({q.path}.values)")
        with self.guard.lock:  # after the heliostat command in flight, before any waiting one
            self._write(q.table, q.start, encode_raw(q, value), f"field command {cmd.name}")
            self.guard.field_sent(cmd)

    def _next_sequence(self, index: int, written: int, done: int) -> int:
        """A sequence number the plant sees as new: one past the register's value (and past ours)."""
        taken = {written, done, self._last_sent.get(index, -1)}
        seq = (written + 1) & 0xFFFF
        while seq in taken:
            seq = (seq + 1) & 0xFFFF
        return seq

    def _encode(self, index: int, q: Q, value: float, limits=None) -> list[int]:
        """``value`` in ``q``'s registers; a stroke rounded to the register's resolution stays inside ``limits``."""
        try:
            if limits is None:
                return encode(q, value)
            return encode_raw(q, raw_within(q, value, *(float(x) for x in limits)))
        except ValueError as exc:
            raise PlantError(f"plant {self.scs.name}: {self._label(index)}: {q.path} at {self._where(q, index)}: "
                             f"{exc}") from None

    def _command(self, index: int, command: HeliostatCommand, fields: list[tuple[Q, list[int]]],
                 link: ModbusLink | None = None) -> int:
        """One heliostat command by the map's handshake, on ``link`` (default the SCS connection, one
        command at a time there; another: a batch's). Commands hold the stow gate's lock together (never
        two to one heliostat at once: the campaign waits for a batch before commanding one of its
        heliostats); a field command holds it alone."""
        what = f"{command.name} command to {self._label(index)}"
        self.guard.refuse_unarmed(what)
        mq = self.map.q["heliostats.command.mode"]
        mode = mq.values.get(command.name.lower())
        if mode is None:
            raise PlantError(f"plant {self.scs.name}: the register map {self.map.name} has no mode value for "
                             f"{command.name.lower()} ({mq.path}.values)")
        label = self._label(index)
        # one command at a time on the SCS connection, its turn taken before the gate's shared lock (a
        # command waiting for its turn must not hold a stow up); beside a batch's (other heliostats:
        # Tracking.land). A field command never takes the turn: no deadlock.
        with (self._one_at_a_time if link is None else _NOTHING), self.guard.lock.shared():
            self.guard.gate(command, what)
            regs = self._block(index, self._command_q, link)
            done = int(decode_raw(self.map.q[HANDSHAKE + "done"], regs[HANDSHAKE + "done"]))
            if self._hs.kind == "sequence":
                sq = self.map.q[HANDSHAKE + "sequence"]
                token = self._next_sequence(index, int(decode_raw(sq, regs[sq.path])), done)
                go = (sq, token, "sequence number")
            else:
                eq = self.map.q[HANDSHAKE + "execute"]
                if int(decode_raw(eq, regs[eq.path])) != 0:
                    raise PlantError(f"plant {self.scs.name}: {what} not sent: the execute register "
                                     f"{self._where(eq, index)} of {label} is still set: the plant has not "
                                     "taken the last command")
                token = (done + 1) & 0xFFFF
                go = (eq, 1, "execute")
            for q, values in fields:
                self._write(q.table, self.map.address(q, index), values, f"{label} {q.meaning or q.path}", index=index,
                            link=link)
            if int(decode_raw(mq, regs[mq.path])) != mode:  # (a refresh's track after a track: already there)
                self._write(mq.table, self.map.address(mq, index), encode_raw(mq, mode),
                            f"{label} command {command.name}", index=index, link=link)
            if self._hs.kind == "sequence":   # a retried write rewrites the same number: no second command
                self._write(go[0].table, self.map.address(go[0], index), [go[1]], f"{label} {go[2]}", index=index,
                            link=link)
            else:                             # the plant acts on every execute write: sent once
                try:
                    self._write(go[0].table, self.map.address(go[0], index), [go[1]], f"{label} {go[2]}", retry=False,
                                index=index, link=link)
                except PlantUnreachableError:
                    self._check_taken(index, token, what, link)
            self._last_sent[index] = token
        return token

    def _check_taken(self, index: int, token: int, what: str, link: ModbusLink | None = None) -> None:
        """After an execute write without an answer: returns if the plant's counter shows ``token``
        (it took the command), else raises; the command is never sent again."""
        dq, eq = self.map.q[HANDSHAKE + "done"], self.map.q[HANDSHAKE + "execute"]
        where = self._where(eq, index)
        try:
            regs = self._block(index, [dq, eq], link)
        except PlantUnreachableError as exc:
            raise PlantUnreachableError(f"plant {self.scs.name}: {what}: no answer to the execute write at {where} "
                                        f"and none to the check of its counter ({exc}); the command may or may not "
                                        "have been taken; not resent") from None
        done = int(decode_raw(dq, regs[dq.path]))
        if done != token:
            execute = int(decode_raw(eq, regs[eq.path]))
            raise PlantError(f"plant {self.scs.name}: {what}: no answer to the execute write at {where}; "
                             f"the counter {self._where(dq, index)} shows {done}, not {token}, execute {execute}: "
                             "the command may or may not have been taken; not resent")

    def _pair(self, index: int, key: str, values, limits=None) -> list[tuple[Q, list[int]]]:
        """The two registers (actuator 1, 2) of ``heliostats.command.<key>``, written as one request
        where they are adjacent."""
        q0, q1 = (self.map.q[f"heliostats.command.{key}[{k}]"] for k in (0, 1))
        r0 = self._encode(index, q0, values[0], None if limits is None else limits[0])
        r1 = self._encode(index, q1, values[1], None if limits is None else limits[1])
        if q0.table == q1.table and q0.table != "coil" and q1.start == q0.start + q0.width:
            return [(q0, r0 + r1)]
        return [(q0, r0), (q1, r1)]

    def move_to(self, index: int, strokes_mm) -> int:
        """Command strokes (actuator 1, 2) [mm] and hold; returns the token the plant will show in
        ``status().sequence_done`` once it took the command.

        Non-finite strokes, and strokes outside ``stroke_limits_mm`` when given, are refused
        with a :class:`PlantError` before anything is written; strokes are then rounded to the
        registers' resolution, never outside the range.
        """
        s = self.guard.strokes(index, strokes_mm)
        lim = self.guard.stroke_limits_mm
        return self._command(index, HeliostatCommand.MOVE,
                             self._pair(index, "strokes_mm", s, None if lim is None else lim[index]))

    def track(self, index: int, corrections_mm, link: ModbusLink | None = None) -> int:
        """Return to tracking with these stroke corrections (actuator 1, 2) [mm]; returns the token.

        ``corrections_mm=None`` leaves the correction registers as they are: the plant tracks with
        the corrections it already has (never wipe a plant's corrections by accident). ``link``: a
        batch's connection (:meth:`track_each`).
        """
        if corrections_mm is None:
            return self._command(index, HeliostatCommand.TRACK, [], link)
        c = self.guard.corrections(index, corrections_mm)
        return self._command(index, HeliostatCommand.TRACK, self._pair(index, "corrections_mm", c), link)

    def send_tracks(self, items) -> Sent:
        """Track commands for distinct heliostats ``items`` ``[(index, corrections_mm), ...]`` sent
        while the caller goes on, up to :data:`~.modbus_batch.BATCH_LINKS` in flight at once, each
        on a connection of its own (a refresh round of 10⁴ heliostats in one period); the returned
        :class:`~.modbus_batch.Sent` gives, per item, None (taken) or the :class:`PlantError` that
        refused it. The stow gate holds for the batch as for one command."""
        if self._batch is None:
            self._batch = TrackBatch(self)
        return self._batch.send(items)

    def track_each(self, items) -> list[PlantError | None]:
        """:meth:`send_tracks`, waited for."""
        return self.send_tracks(items).results()

    def stow(self, index: int) -> int:
        """Send one heliostat to stow; returns the token."""
        return self._command(index, HeliostatCommand.STOW, [])
