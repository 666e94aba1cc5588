"""Encode and decode the quantities of a register map (:mod:`helicalib.devices.regmap`).

``value = raw · scale + value_offset``; ``raw`` is the register content as the quantity's type
(u16, i16, u32, i32, f32, f64) in its word order (``high_first`` | ``low_first``) and byte order
within a register (``big`` | ``little``). A quantity with ``parts`` is their sum; its registers are
the span from its first to its last register. Coded quantities (states, faults, commands) map
plant values to helicalib's names. :func:`plan_reads` groups registers into few requests.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Mapping

import numpy as np

from helicalib.devices.regschema import BIT_PRIORITY, INT_RANGE, Q

_FMT = {"u16": ">H", "i16": ">h", "u32": ">I", "i32": ">i", "f32": ">f", "f64": ">d"}
MAX_READ = 125
"""Registers in one Modbus read request."""


def _words(q: Q, raw) -> list[int]:
    data = struct.pack(_FMT[q.type], raw)
    words = [data[k:k + 2] for k in range(0, len(data), 2)]
    if q.word_order == "low_first":
        words.reverse()
    if q.byte_order == "little":
        words = [w[::-1] for w in words]
    return [int.from_bytes(w, "big") for w in words]


def _raw(q: Q, regs) -> float:
    words = [int(r).to_bytes(2, "big") for r in regs]
    if q.byte_order == "little":
        words = [w[::-1] for w in words]
    if q.word_order == "low_first":
        words.reverse()
    return struct.unpack(_FMT[q.type], b"".join(words))[0]


def raw_of(q: Q, value: float, *, clamp: bool = False, rounding=round) -> float | int:
    """The raw register value of ``value`` (rounded for integer types; ValueError if it does not fit,
    or the nearest that fits with ``clamp``)."""
    x = (float(value) - q.value_offset) / q.scale
    if q.type in ("f32", "f64"):
        if q.type == "f32" and math.isfinite(x) and abs(x) > 3.4028234663852886e38:
            if not clamp:
                raise ValueError(f"{value} does not fit an f32")
            x = math.copysign(3.4028234663852886e38, x)
        return x
    if not math.isfinite(x):
        raise ValueError(f"{value} is not a finite number")
    lo, hi = (0, 1) if q.table == "coil" else INT_RANGE[q.type]
    r = int(rounding(x))
    if not lo <= r <= hi:
        if not clamp:
            raise ValueError(f"{value}{' ' + q.unit if q.unit else ''} does not fit a {q.type}"
                             f"{f' with scale {q.scale:g}' if q.scale != 1 else ''}")
        r = min(max(r, lo), hi)
    return r


def raw_within(q: Q, value: float, lo: float, hi: float) -> float | int:
    """The raw register value of ``value`` (inside ``lo..hi``) whose decoded value stays inside:
    an integer rounded to the step on the inside at an edge; a float (f32 rounds 999.9 up to
    999.9000244) stepped by ``nextafter`` toward the inside. ValueError if it does not fit."""
    inside = lambda raw: lo <= float(raw) * q.scale + q.value_offset <= hi  # as decode() reads it
    if q.type in ("f32", "f64"):
        raw = (np.float32 if q.type == "f32" else np.float64)(raw_of(q, value))
        for _ in range(8):   # one step at scale 1; a few where the scale spreads the steps
            if inside(raw):
                break
            low = float(raw) * q.scale + q.value_offset < lo
            raw = np.nextafter(raw, raw.dtype.type(math.inf if low == (q.scale > 0) else -math.inf))
        return float(raw)
    up, down = (math.ceil, math.floor) if q.scale > 0 else (math.floor, math.ceil)
    raw = raw_of(q, value)
    if raw * q.scale + q.value_offset < lo:
        raw = raw_of(q, lo, rounding=up)
    elif raw * q.scale + q.value_offset > hi:
        raw = raw_of(q, hi, rounding=down)
    return raw


def encode(q: Q, value: float, *, clamp: bool = False) -> list[int]:
    """``value`` as the registers of ``q`` (its whole span; registers between parts are 0)."""
    if q.parts:
        out = [0] * q.width
        remaining = float(value)
        for k, p in enumerate(q.parts):
            last = k == len(q.parts) - 1
            r = raw_of(p, remaining, clamp=clamp or not last, rounding=round if last else math.floor)
            remaining -= r * p.scale + p.value_offset
            for j, w in enumerate(encode_raw(p, r)):
                out[p.start - q.start + j] = w
        return out
    return encode_raw(q, raw_of(q, value, clamp=clamp))


def encode_raw(q: Q, raw) -> list[int]:
    if q.table == "coil":
        return [int(raw)]
    return _words(q, raw)


def decode(q: Q, regs) -> float:
    """The value held by ``regs`` (the registers of ``q``'s span, in address order)."""
    if q.parts:
        return sum(decode(p, regs[p.start - q.start:p.start - q.start + p.width]) for p in q.parts)
    return decode_raw(q, regs) * q.scale + q.value_offset


def decode_raw(q: Q, regs) -> float | int:
    if q.table == "coil":
        return int(bool(regs[0]))
    return _raw(q, regs[:q.width])


def at(q: Q, image: Mapping[int, int], start: int) -> list[int]:
    """The registers of ``q`` from ``image`` (address → value), ``q`` placed at ``start``."""
    return [image[start + k] for k in range(q.width)]


# -- coded quantities ---------------------------------------------------------------------------
def state_name(q: Q, raw: int) -> str | None:
    """helicalib's name for a plant state value (an enumeration or bit fields); None: not in the map."""
    if q.values:
        return q.values.get(int(raw))
    on = {name for bit, name in q.bits.items() if int(raw) >> bit & 1}
    return next((n for n in BIT_PRIORITY if n in on), "idle")


def state_raw(q: Q, name: str) -> int | None:
    """The plant value of a helicalib name (the first plant value that stands for it); None: not in the map."""
    if q.values:
        return next((v for v, n in q.values.items() if n == name), None)
    if name == "idle":
        return 0
    bit = next((b for b, n in q.bits.items() if n == name), None)
    return None if bit is None else 1 << bit


# -- reads ---------------------------------------------------------------------------------------
def plan_reads(registers: Iterable[tuple[str, int]], readable=lambda table, address: False,
               max_count: int = MAX_READ) -> list[tuple[str, int, int]]:
    """Requests ``(table, start, count)`` that cover ``registers`` (table, address): a gap is read
    through when every register in it is ``readable(table, address)``, else a new request starts."""
    by_table: dict[str, list[int]] = {}
    for table, a in registers:
        by_table.setdefault(table, []).append(a)
    out = []
    for table in sorted(by_table):
        addrs = sorted(set(by_table[table]))
        start = prev = addrs[0]
        for a in addrs[1:]:
            gap_ok = all(readable(table, g) for g in range(prev + 1, a))
            if a - start + 1 > max_count or not gap_ok:
                out.append((table, start, prev - start + 1))
                start = a
            prev = a
        out.append((table, start, prev - start + 1))
    return out
