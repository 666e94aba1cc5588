"""The simulated plant's Modbus registers, laid out by a register map, independent of any transport.

:class:`PlantRegisters` answers register reads and writes for a :class:`SimulatedPlant` in the
layout of a :class:`~helicalib.devices.regmap.RegisterMap` (default: ``PLANT_INTERFACE.md``):
reads compose the image of a table (holding, input, coil) from the plant's state at the current
plant time (registers in a ``readable`` range or a heliostat block but not mapped read 0; others
are refused with exception 2); a write touching any register that is not a command register is
refused whole (exception 2); otherwise the values are stored, the field command is acted on at
every write, and a heliostat command is acted on per the map's handshake (``sequence``: when the
write changes the sequence number; ``execute``: when it sets the execute register, which is then
set back to 0 and the command counter counts up), after all registers of the write are stored.
Every call first advances the plant to ``clock.now_s()`` under one lock, so a Modbus server thread
and HTTP camera threads can share a plant.
"""

from __future__ import annotations

import bisect
import threading

from helicalib.devices.regcodec import decode, decode_raw, encode, encode_raw, state_raw
from helicalib.devices.registers import FaultCode, FieldCommand, HeliostatCommand, HeliostatState
from helicalib.devices.regmap import RegisterMap, load_register_map
from helicalib.devices.regschema import Q

ILLEGAL_ADDRESS = 2
"""Modbus exception code of a refused read or write."""
HS = "heliostats.command.handshake."
UNKNOWN = 0xFFFF
"""What the server shows for a plant state or fault the map has no value for."""
_FIELD_COMMANDS = {"none": FieldCommand.NONE, "stow": FieldCommand.STOW_ALL, "resume": FieldCommand.RESUME_TRACKING}


class PlantRegisters:
    """Register image of a simulated plant.

    Parameters
    ----------
    plant : SimulatedPlant
    clock : object with ``now_s()`` (plant time [UTC s]) and attribute ``rate``
    lock : threading.Lock shared with the cameras (one is made if None)
    register_map : RegisterMap, a shipped map's name or a YAML path, optional
        The layout served (default: ``PLANT_INTERFACE.md``).
    served : bool
        False when the plant is served over OPC UA: the registers then only lend their lock and
        :meth:`sync` to the other services, and the map's reach (2016 heliostats for
        ``PLANT_INTERFACE.md``) does not limit the field.
    """

    def __init__(self, plant, clock, lock: threading.Lock | None = None, register_map=None, served: bool = True):
        self.plant = plant
        self.clock = clock
        self.lock = lock or threading.RLock()
        self.map: RegisterMap = load_register_map(register_map)
        self.n = plant.heliostat_count()
        if served:
            self.map.check_count(self.n)
        self.written: dict[tuple[str, int], int] = {}
        """Command registers as written, by (table, address); a block on another unit id than the
        first (``heliostats.per_unit``) at address + 65536 · its unit step."""
        scs = plant.cfg.plant.scs
        self.first_unit = scs.unit if scs is not None else 1
        self.block_units = [self.first_unit + k for k in range(self.map.unit_steps(self.n))]
        """The unit ids that answer heliostat blocks (one without ``heliostats.per_unit``)."""
        m = self.map
        self._plant_w = {(q.table, r): q for q in m.q.values() if q.writable and not q.block for r in q.registers}
        self._block_w = {(q.table, r): q for q in m.q.values() if q.writable and q.block for r in q.registers}
        self._extent = {t: m.block_extent(t) for t in ("holding", "input", "coil")}
        h = m.doc.heliostats
        self._starts = sorted((m.block_address(i), i) for i in range(self.n)) if h.addresses is not None else None

    def sync(self) -> None:
        """Advance the plant to the clock's time (call with the lock held)."""
        now = float(self.clock.now_s())
        if now > self.plant.t_s:
            self.plant.advance_to(now)

    # -- where an address lies --------------------------------------------------------------
    def _step(self, unit: int | None) -> int:
        """The unit step of a request to ``unit`` (0 without ``heliostats.per_unit``; -1: no blocks there)."""
        if unit is None or len(self.block_units) == 1:
            return 0
        step = int(unit) - self.first_unit
        return step if 0 <= step < len(self.block_units) else -1

    def _key(self, table: str, address: int, step: int) -> tuple[str, int]:
        """Where a written register is kept: a block's at its unit step's own address space."""
        return (table, address + 65536 * step) if step > 0 and self._block_of(table, address, step) else (table, address)

    def _block_of(self, table: str, address: int, step: int = 0) -> tuple[int, int] | None:
        """(heliostat index, offset) of a register inside a block's readable extent, or None."""
        extent = self._extent[table]
        if not extent or self.n == 0 or step < 0:
            return None
        if self._starts is None:
            h = self.map.doc.heliostats
            i, off = divmod(address - h.base, h.stride)
            if h.per_unit:
                if i >= h.per_unit:
                    return None
                i += step * h.per_unit
            return (i, off) if address >= h.base and i < self.n and off < extent else None
        k = bisect.bisect_right(self._starts, (address, self.n)) - 1
        if k < 0:
            return None
        start, i = self._starts[k]
        return (i, address - start) if address - start < extent else None

    def _readable(self, table: str, address: int, step: int = 0) -> bool:
        return self.map.plant_readable(table, address) or self._block_of(table, address, step) is not None

    # -- reads ------------------------------------------------------------------------------
    def read(self, address: int, count: int, table: str = "holding", unit: int | None = None) -> list[int] | int:
        """``count`` registers of ``table`` from ``address`` (on ``unit``, which picks the block of
        heliostats with ``heliostats.per_unit``), or the exception code 2."""
        step = self._step(unit)
        if count < 1 or address < 0 or address + count > 65536:
            return ILLEGAL_ADDRESS
        if not all(self._readable(table, address + k, step) for k in range(count)):
            return ILLEGAL_ADDRESS
        with self.lock:
            self.sync()
            return self._image(table, address, count, step)

    def _image(self, table: str, address: int, count: int, step: int = 0) -> list[int]:
        image: dict[int, int] = {}
        if any(self.map.plant_readable(table, address + k) for k in range(count)):
            image.update(self._plant_values(table))
        blocks = {b[0] for k in range(count) if (b := self._block_of(table, address + k, step)) is not None}
        for i in blocks:
            image.update(self._block_values(table, i))
        return [int(image.get(address + k, self.written.get(self._key(table, address + k, step), 0)))
                for k in range(count)]

    def _put(self, image: dict[int, int], q: Q, address: int, value: float) -> None:
        for k, v in enumerate(encode(q, value, clamp=True)):
            image[address + k] = v

    def _plant_values(self, table: str) -> dict[int, int]:
        p, m = self.plant, self.map
        t, _ = p.plant_time()
        w = p.weather()
        values = {"plant.heliostat_count": self.n, "plant.target_count": len(p.cfg.targets), "plant.clock.time": t,
                  "plant.clock.rate": getattr(self.clock, "rate", p.rate), "weather.wind_ms": w.wind_ms,
                  "weather.wind_direction_deg": w.wind_direction_deg, "weather.dni_wm2": w.dni_wm2,
                  "weather.temperature_c": w.temperature_c, "weather.pressure_hpa": w.pressure_hpa}
        image: dict[int, int] = {}
        for path, q in m.q.items():
            if q.block or q.table != table or q.writable:
                continue
            if path.startswith("identity["):
                value = q.equals
            elif path == "plant.field_state":
                value = state_raw(q, p.field_state().name.lower())
            else:
                value = values[path]
            self._put(image, q, q.start, UNKNOWN if value is None else value)
        return image

    def _block_values(self, table: str, i: int) -> dict[int, int]:
        """Heliostat ``i``'s block from its status alone (the cost of one heliostat, not the field's)."""
        m = self.map
        st = self.plant.status(i)
        base = m.block_address(i)
        q = m.q
        image: dict[int, int] = {}
        sq, fq = q["heliostats.status.state"], q["heliostats.status.fault"]
        if sq.table == table:
            name = HeliostatState(int(st.state)).name.lower()
            raw = state_raw(sq, name)
            raw = state_raw(sq, "fault") if raw is None else raw
            image.update(zip(range(base + sq.start, base + sq.start + sq.width), encode_raw(sq, raw)))
        if fq.table == table:
            raw = state_raw(fq, FaultCode(int(st.fault)).name.lower())
            image.update(zip(range(base + fq.start, base + fq.start + fq.width),
                             encode_raw(fq, UNKNOWN if raw is None else raw)))
        for path, value in ((HS + "done", int(st.sequence_done) & 0xFFFF),
                            ("heliostats.status.strokes_mm[0]", st.strokes_mm[0]),
                            ("heliostats.status.strokes_mm[1]", st.strokes_mm[1]),
                            ("heliostats.status.cleanliness", st.cleanliness)):
            if q[path].table == table:
                self._put(image, q[path], base + q[path].start, value)
        return image

    # -- writes -----------------------------------------------------------------------------
    def _command_register(self, table: str, address: int, step: int = 0) -> tuple[int | None, Q] | None:
        """(heliostat index or None, the command quantity) of a writable register, else None."""
        q = self._plant_w.get((table, address))
        if q is not None:
            return None, q
        b = self._block_of(table, address, step)
        if b is None:
            return None
        q = self._block_w.get((table, b[1]))
        return None if q is None else (b[0], q)

    def writable(self, address: int, table: str = "holding", unit: int | None = None) -> bool:
        return self._command_register(table, address, self._step(unit)) is not None

    def write(self, address: int, values, table: str = "holding", unit: int | None = None) -> int | None:
        """Store ``values`` from ``address`` (on ``unit``, as for :meth:`read`); returns None, or
        exception code 2 (nothing stored)."""
        values = [int(v) & 0xFFFF for v in values]
        step = self._step(unit)
        if not values or address < 0 or address + len(values) > 65536:
            return ILLEGAL_ADDRESS
        targets = [self._command_register(table, address + k, step) for k in range(len(values))]
        if any(t is None for t in targets):
            return ILLEGAL_ADDRESS
        with self.lock:
            self.sync()
            field_written = False
            acts: dict[int, str] = {}
            for k, v in enumerate(values):
                self.written[self._key(table, address + k, step)] = v
                i, q = targets[k]
                if i is None:
                    field_written = True
                elif q.path in (HS + "sequence", HS + "execute"):
                    acts[i] = q.path
            if field_written:
                fq = self.map.q["plant.field_command"]
                raw = int(decode_raw(fq, self._regs(fq)))
                name = next((n for n, v in fq.values.items() if v == raw), "none")
                self.plant.field_command(int(_FIELD_COMMANDS[name]))
            for i, path in acts.items():
                self._act(i, path)
        return None

    def _regs(self, q: Q, i: int | None = None) -> list[int]:
        return [self.written.get(self._written_at(q, i, k), 0) for k in range(q.width)]

    def _written_at(self, q: Q, i: int | None, k: int = 0) -> tuple[str, int]:
        step = self.map.unit_step(i) if q.block and i is not None else 0
        return (q.table, self.map.address(q, i) + k + 65536 * step)

    def _act(self, i: int, path: str) -> None:
        q, p = self.map.q, self.plant
        hq = q[path]
        if path == HS + "sequence":
            seq = int(decode_raw(hq, self._regs(hq, i)))
        else:
            if not int(decode_raw(hq, self._regs(hq, i))):
                return                                  # execute written back to 0: nothing to do
            self.written[self._written_at(hq, i)] = 0
            seq = (int(p.sequence_done[i]) + 1) & 0xFFFF
        mq = q["heliostats.command.mode"]
        raw = int(decode_raw(mq, self._regs(mq, i)))
        name = next((n for n, v in mq.values.items() if v == raw), None)
        command = int(HeliostatCommand[name.upper()]) if name is not None else -1   # -1: an unknown command
        strokes = [decode(q[f"heliostats.command.strokes_mm[{k}]"], self._regs(q[f"heliostats.command.strokes_mm[{k}]"], i))
                   for k in (0, 1)]
        corr = [decode(q[f"heliostats.command.corrections_mm[{k}]"],
                       self._regs(q[f"heliostats.command.corrections_mm[{k}]"], i)) for k in (0, 1)]
        p.write_command(i, command, seq, strokes_mm=strokes, corrections_mm=corr)
