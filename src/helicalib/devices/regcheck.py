"""The checks of a register map that span its keys: codes and names, handshakes, overlapping
registers, block strides, writable tables, and (once the field size is known) the address space.

Each problem is one line ``key.path: what is wrong`` (the caller puts the file name in front);
``m`` is a :class:`helicalib.devices.regmap.RegisterMap` (its ``q``, ``doc`` and block addresses).
"""

from __future__ import annotations

from collections import defaultdict

from helicalib.devices.regschema import (
    FAULT_NAMES,
    FIELD_COMMAND_NAMES,
    FIELD_STATE_NAMES,
    INT_RANGE,
    MODE_NAMES,
    STATE_NAMES,
    WIDTH,
    Q,
)

CODED = {  # key path: (allowed names, required names, how the plant's values are given)
    "plant.field_state": (FIELD_STATE_NAMES, FIELD_STATE_NAMES, "values"),
    "heliostats.status.state": (STATE_NAMES, ("tracking", "moving", "holding", "stowed", "fault"), "either"),
    "heliostats.status.fault": (FAULT_NAMES, ("none",), "values"),
    "plant.field_command": (FIELD_COMMAND_NAMES, ("stow", "resume"), "command"),
    "heliostats.command.mode": (MODE_NAMES, ("track", "move", "stow"), "command"),
}


MAX_UNITS = 247
"""Modbus unit (device) ids a plant can answer on: 1..247."""
STROKE_DEMANDS = ("heliostats.command.strokes_mm[0]", "heliostats.command.strokes_mm[1]")


def check_map(m) -> list[str]:
    out: list[str] = []
    for path, q in m.q.items():
        out += _check_code(path, q)
    out += _check_handshake(m)
    out += [f"{path}.parts: a stroke demand is one register quantity (parts are rounded apart: the sum "
            "could leave the stroke range)" for path in STROKE_DEMANDS if path in m.q and m.q[path].parts]
    out += _check_writable(m)
    out += _check_overlaps(m)
    out += _check_blocks(m)
    for k, r in enumerate(m.doc.readable):
        if r.last < r.first:
            out.append(f"readable[{k}].last: {r.last} is before first ({r.first})")
    return out


def _fits(q: Q, value: int) -> bool:
    if q.table == "coil":
        return value in (0, 1)
    lo, hi = INT_RANGE.get(q.type, (None, None))
    return lo is not None and lo <= value <= hi


def _check_code(path: str, q: Q) -> list[str]:
    spec = CODED.get(path)
    has_values, has_bits = bool(q.values), bool(q.bits)
    if spec is None:
        return []
    allowed, required, how = spec
    out = []
    if q.type not in INT_RANGE or q.scale != 1 or q.value_offset != 0 or q.parts:
        return [f"{path}.type: a coded quantity is one unscaled integer (u16, i16, u32, i32), got {q.type}"]
    if how == "command":
        seen: dict[int, str] = {}
        for name, value in q.values.items():
            if name not in allowed:
                out.append(f"{path}.values.{name}: unknown command name (expected {', '.join(allowed)})")
            elif not _fits(q, value):
                out.append(f"{path}.values.{name}: {value} does not fit a {q.type}")
            elif value in seen:
                out.append(f"{path}.values.{name}: {value} is also the value of {seen[value]}")
            seen.setdefault(value, name)
        names = q.values
    elif has_values == has_bits or (has_bits and how != "either"):
        return [f"{path}: give {'either values or bits' if how == 'either' else 'values'} "
                f"(plant value: name, names {', '.join(allowed)})"]
    elif has_values:
        for value, name in q.values.items():
            if name not in allowed:
                out.append(f"{path}.values.{value}: unknown name {name!r} (expected {', '.join(allowed)})")
            elif not _fits(q, value):
                out.append(f"{path}.values.{value}: does not fit a {q.type}")
        names = set(q.values.values())
        if path == "heliostats.status.state":
            required = (*required, "idle")
    else:
        used: dict[str, int] = {}
        bits = 16 * WIDTH[q.type]
        for bit, name in q.bits.items():
            if name not in allowed or name == "idle":
                out.append(f"{path}.bits.{bit}: unknown state {name!r} (expected {', '.join(STATE_NAMES[1:])}; "
                           "idle is no bit set)")
            elif not 0 <= bit < bits:
                out.append(f"{path}.bits.{bit}: a {q.type} has bits 0..{bits - 1}")
            elif name in used:
                out.append(f"{path}.bits.{bit}: {name} is also bit {used[name]}")
            used.setdefault(name, bit)
        names = set(q.bits.values())
    missing = [n for n in required if n not in names]
    if missing and not out:
        out.append(f"{path}: no plant value for {', '.join(missing)}")
    return out


def _check_handshake(m) -> list[str]:
    hs = m.doc.heliostats.command.handshake
    need = ("sequence", "done") if hs.kind == "sequence" else ("execute", "done")
    other = "execute" if hs.kind == "sequence" else "sequence"
    base = "heliostats.command.handshake"
    out = [f"{base}.{k}: missing required key (a {hs.kind} handshake needs {' and '.join(need)})"
           for k in need if getattr(hs, k) is None]
    if getattr(hs, other) is not None:
        out.append(f"{base}.{other}: not part of a {hs.kind} handshake")
    for k in need:
        q = m.q.get(f"{base}.{k}")
        if q is not None and (q.type != "u16" or q.parts or q.scale != 1 or q.table == "coil"):
            out.append(f"{base}.{k}.type: a handshake register is one u16 register")
    return out


def _check_writable(m) -> list[str]:
    return [f"{q.path}.table: input registers cannot be written (a command register is holding or coil)"
            for q in m.q.values() if q.writable and q.table == "input"]


def _check_overlaps(m) -> list[str]:
    out = []
    seen: dict[tuple[bool, str, int], str] = {}
    for q in m.q.values():
        for r in q.registers:
            key = (q.block, q.table, r)
            if key in seen and seen[key] != q.path:
                where = f"offset {r}" if q.block else f"address {r}"
                out.append(f"{q.path}: {q.table} {where} is also {seen[key]}")
                break
            seen[key] = q.path
    return out


def _check_blocks(m) -> list[str]:
    h = m.doc.heliostats
    if (h.addresses is None) == (h.base is None or h.stride is None) or (h.addresses is not None and
                                                                           (h.base, h.stride) != (None, None)):
        return ["heliostats: give base and stride, or addresses (one block address per heliostat)"]
    extent = _extents(m)
    widest = max(extent.values(), default=0)
    out = []
    if h.per_unit is not None and h.addresses is not None:
        out.append("heliostats.per_unit: blocks by unit id need base and stride, not addresses")
    if h.block_size is not None and h.block_size < widest:
        out.append(f"heliostats.block_size: {h.block_size} is smaller than the block's extent {widest}")
    if h.stride is not None and extent:
        table, e = max(sorted(extent.items()), key=lambda kv: kv[1])
        if h.stride < max(e, h.block_size or 0):
            out.append(f"heliostats.stride: {h.stride} is smaller than the block's extent "
                       f"{max(e, h.block_size or 0)} ({table} offsets 0..{e - 1})")
    if h.addresses is not None:
        ordered = sorted(h.addresses)
        for a, b in zip(ordered, ordered[1:]):
            if b - a < widest:
                k = h.addresses.index(b)
                out.append(f"heliostats.addresses[{k}]: {b} overlaps the block at {a} (blocks span {widest} registers)")
                break
    return out


def _extents(m) -> dict[str, int]:
    ext: dict[str, int] = defaultdict(int)
    for q in m.q.values():
        if q.block:
            ext[q.table] = max(ext[q.table], max(q.registers) + 1)
    return dict(ext)


def check_count(m, n: int) -> list[str]:
    """Problems of ``m`` with a field of ``n`` heliostats (addresses past 65535, a short address table,
    plant-wide registers inside the heliostat blocks)."""
    h = m.doc.heliostats
    if h.addresses is not None and len(h.addresses) != n:
        return [f"heliostats.addresses: {len(h.addresses)} block addresses for a field of {n} heliostats"]
    if n == 0:
        return []
    if m.unit_steps(n) > MAX_UNITS:
        return [f"heliostats.per_unit: {n} heliostats at {h.per_unit} per unit need {m.unit_steps(n)} unit ids, "
                f"more than Modbus's {MAX_UNITS}"]
    last_i = min(n, h.per_unit or n) - 1
    starts = [m.block_address(i) for i in ((0, last_i) if h.addresses is None else range(n))]
    lo = min(starts)
    ends = {table: max(starts) + max(e, h.block_size or 0) - 1 for table, e in _extents(m).items()}
    table, last = max(ends.items(), key=lambda kv: kv[1])
    if last > 65535:
        key = "heliostats.addresses" if h.addresses is not None else "heliostats.stride"
        return [f"{key}: the {table} blocks of {n} heliostats end at address {last}, beyond 65535"]
    return [f"{q.path}.address: {q.start} lies inside the heliostat blocks ({q.table} {lo}..{ends[q.table]})"
            for q in m.q.values() if not q.block and q.table in ends and any(lo <= r <= ends[q.table] for r in q.registers)]


def check_stroke_ranges(m, drives) -> list[str]:
    """Problems of stroke demand registers that cannot hold a drive's whole stroke range (a u16 with
    scale 0.01 ends at 655.35 mm); ``drives``: drive name → its actuators' ``(min, max)`` [mm]."""
    out = []
    for k, path in enumerate(STROKE_DEMANDS):
        q = m.q.get(path)
        if q is None or q.parts or q.type not in INT_RANGE:
            continue                                  # floats hold any stroke; parts are refused above
        raw_lo, raw_hi = (0, 1) if q.table == "coil" else INT_RANGE[q.type]
        lo, hi = sorted((raw_lo * q.scale + q.value_offset, raw_hi * q.scale + q.value_offset))
        for name, ranges in drives.items():
            s_lo, s_hi = ranges[k]
            if s_lo < lo or s_hi > hi:
                scale = f" with scale {q.scale:g}" if q.scale != 1 else ""
                offset = f" and value_offset {q.value_offset:g}" if q.value_offset else ""
                out.append(f"{path}: a {q.type}{scale}{offset} holds {lo:g}..{hi:g} mm, drive {name}'s actuator {k + 1} "
                           f"strokes {s_lo:g}..{s_hi:g} mm")
                break
    return out
