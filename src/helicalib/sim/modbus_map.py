"""The simulated plant's holding registers (``PLANT_INTERFACE.md``), independent of any transport.

:class:`PlantRegisters` answers register reads and writes for a :class:`SimulatedPlant`:
reads compose the register image from the plant's state at the current plant time (addresses in
the map but unused read 0; addresses past the last heliostat block are refused with exception 2);
a write touching any read-only or unused register is refused whole (exception 2); otherwise the
values are stored, the field command is acted on at every write, and a heliostat command is acted
on when the write changes its sequence number (after all registers of the write are stored). Every
call first advances the plant to ``clock.now_s()`` under one lock, so a Modbus server thread and
HTTP camera threads can share a plant.
"""

from __future__ import annotations

import threading

import numpy as np

from helicalib.devices import registers as R

ILLEGAL_ADDRESS = 2
"""Modbus exception code of a refused read or write."""


class PlantRegisters:
    """Register image of a simulated plant.

    Parameters
    ----------
    plant : SimulatedPlant
    clock : object with ``now_s()`` (plant time [UTC s]) and attribute ``rate``
    lock : threading.Lock shared with the cameras (one is made if None)
    """

    def __init__(self, plant, clock, lock: threading.Lock | None = None):
        self.plant = plant
        self.clock = clock
        self.lock = lock or threading.RLock()
        self.n = plant.heliostat_count()
        self.end = R.heliostat_address(self.n)
        # raw writable registers: field command and every heliostat block (values as written)
        self.field_command_reg = 0
        self.raw = np.zeros((self.n, R.HELIOSTAT_STRIDE), dtype=np.int64)

    def sync(self) -> None:
        """Advance the plant to the clock's time (call with the lock held)."""
        now = float(self.clock.now_s())
        if now > self.plant.t_s:
            self.plant.advance_to(now)

    # -- reads ------------------------------------------------------------------------------
    def read(self, address: int, count: int) -> list[int] | int:
        """``count`` registers from ``address``, or the exception code 2."""
        if count < 1 or address < 0 or address + count > self.end:
            return ILLEGAL_ADDRESS
        with self.lock:
            self.sync()
            return self._image(address, count)

    def _image(self, address: int, count: int) -> list[int]:
        p = self.plant
        out = [0] * count
        fixed = {}
        if address < R.HELIOSTAT_BASE:
            t, _ = p.plant_time()
            w = p.weather()
            fixed = {R.REG_VERSION: R.INTERFACE_VERSION, R.REG_HELIOSTAT_COUNT: self.n,
                     R.REG_TARGET_COUNT: len(p.cfg.targets), R.REG_FIELD_COMMAND: self.field_command_reg,
                     R.REG_FIELD_STATE: int(p.field_state())}
            for base, regs in ((R.REG_PLANT_TIME, R.encode_f64(t)),
                               (R.REG_PLANT_TIME_RATE, R.encode_f32(getattr(self.clock, "rate", p.rate))),
                               (R.REG_WIND_SPEED, R.encode_f32(w.wind_ms)),
                               (R.REG_WIND_DIRECTION, R.encode_f32(w.wind_direction_deg)),
                               (R.REG_DNI, R.encode_f32(w.dni_wm2)),
                               (R.REG_TEMPERATURE, R.encode_f32(w.temperature_c)),
                               (R.REG_PRESSURE, R.encode_f32(w.pressure_hpa))):
                fixed.update({base + k: v for k, v in enumerate(regs)})
        last = address + count - 1
        blocks = range(max(0, (address - R.HELIOSTAT_BASE) // R.HELIOSTAT_STRIDE),
                       max(0, (last - R.HELIOSTAT_BASE) // R.HELIOSTAT_STRIDE + 1)) if last >= R.HELIOSTAT_BASE else ()
        if len(blocks):
            clean = p.soiling.cleanliness(p.t_s)
            for i in blocks:
                fixed.update(self._block(i, clean[i]))
        for k in range(count):
            out[k] = int(fixed.get(address + k, 0))
        return out

    def _block(self, i: int, cleanliness: float) -> dict[int, int]:
        p = self.plant
        base = R.heliostat_address(i)
        regs = {base + off: int(self.raw[i, off]) for off in R.WRITABLE_HELIOSTAT_OFFSETS}
        regs[base + R.OFF_STATE] = int(p.state[i])
        regs[base + R.OFF_SEQUENCE_DONE] = int(p.sequence_done[i])
        regs[base + R.OFF_FAULT] = int(p.fault[i])
        for off, value in ((R.OFF_STROKE_ACT_1, p.strokes_mm[i, 0]), (R.OFF_STROKE_ACT_2, p.strokes_mm[i, 1]),
                           (R.OFF_CLEANLINESS, cleanliness)):
            hi, lo = R.encode_f32(value)
            regs[base + off], regs[base + off + 1] = hi, lo
        return regs

    # -- writes -----------------------------------------------------------------------------
    @staticmethod
    def writable(address: int) -> bool:
        if address in R.WRITABLE_FIELD:
            return True
        if address < R.HELIOSTAT_BASE:
            return False
        return (address - R.HELIOSTAT_BASE) % R.HELIOSTAT_STRIDE in R.WRITABLE_HELIOSTAT_OFFSETS

    def write(self, address: int, values) -> int | None:
        """Store ``values`` from ``address``; returns None, or exception code 2 (nothing stored)."""
        values = [int(v) & 0xFFFF for v in values]
        if not values or address < 0 or address + len(values) > self.end:
            return ILLEGAL_ADDRESS
        if not all(self.writable(address + k) for k in range(len(values))):
            return ILLEGAL_ADDRESS
        with self.lock:
            self.sync()
            field_written = False
            sequences: dict[int, int] = {}
            for k, v in enumerate(values):
                a = address + k
                if a == R.REG_FIELD_COMMAND:
                    self.field_command_reg = v
                    field_written = True
                    continue
                i, off = divmod(a - R.HELIOSTAT_BASE, R.HELIOSTAT_STRIDE)
                self.raw[i, off] = v
                if off == R.OFF_SEQUENCE:
                    sequences[i] = v
            if field_written:
                self.plant.field_command(self.field_command_reg)
            for i, seq in sequences.items():
                self._act(i, seq)
        return None

    def _act(self, i: int, seq: int) -> None:
        r = self.raw[i]
        strokes = [R.decode_f32(r[R.OFF_STROKE_CMD_1:R.OFF_STROKE_CMD_1 + 2]),
                   R.decode_f32(r[R.OFF_STROKE_CMD_2:R.OFF_STROKE_CMD_2 + 2])]
        corr = [R.decode_f32(r[R.OFF_TRACK_CORR_1:R.OFF_TRACK_CORR_1 + 2]),
                R.decode_f32(r[R.OFF_TRACK_CORR_2:R.OFF_TRACK_CORR_2 + 2])]
        self.plant.write_command(i, int(r[R.OFF_COMMAND]), seq, strokes_mm=strokes, corrections_mm=corr)
