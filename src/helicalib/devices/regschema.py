"""The register map file's schema: the YAML keys (pydantic, unknown keys refused), helicalib's
names for coded values, and :class:`Q`, a quantity with the map's defaults applied.

:func:`resolve` turns one key of a map into a :class:`Q` (or a one-line problem naming the key).
The checks that span keys are in :mod:`helicalib.devices.regcheck`; the loaded map is
:class:`helicalib.devices.regmap.RegisterMap`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


Table = Literal["holding", "input", "coil"]
RegType = Literal["u16", "i16", "u32", "i32", "f32", "f64"]
WordOrder = Literal["high_first", "low_first"]
ByteOrder = Literal["big", "little"]
WIDTH = {"u16": 1, "i16": 1, "u32": 2, "i32": 2, "f32": 2, "f64": 4}
INT_RANGE = {"u16": (0, 0xFFFF), "i16": (-0x8000, 0x7FFF), "u32": (0, 0xFFFFFFFF), "i32": (-0x80000000, 0x7FFFFFFF)}

STATE_NAMES = ("idle", "tracking", "moving", "holding", "stowed", "fault", "offline")
BIT_PRIORITY = ("fault", "offline", "stowed", "moving", "holding", "tracking")
"""Several status bits set: the first of these wins; none set: idle."""
FAULT_NAMES = ("none", "stroke_out_of_range", "refused_during_stow", "unknown_command")
FIELD_STATE_NAMES = ("tracking", "stowing", "stowed")
MODE_NAMES = ("none", "track", "move", "stow")
FIELD_COMMAND_NAMES = ("none", "stow", "resume")


class _Map(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Reg(_Map):
    """One quantity: where it lives and how it is encoded (or ``parts`` whose values add up)."""

    address: int | None = Field(default=None, ge=0, le=65535)
    offset: int | None = Field(default=None, ge=0, le=65535)
    table: Table | None = None
    type: RegType = "u16"
    word_order: WordOrder | None = None
    byte_order: ByteOrder | None = None
    scale: float = 1.0
    value_offset: float = 0.0
    unit: str = Field(default="", max_length=40)
    meaning: str = Field(default="", max_length=200)
    parts: list[Reg] | None = Field(default=None, min_length=2, max_length=4)


class Coded(Reg):
    """A quantity whose plant values stand for names: an enumeration or bit fields."""

    values: dict[int, str] | None = None
    bits: dict[int, str] | None = None


class Command(Reg):
    """A command register: helicalib's command names → the plant's values."""

    values: dict[str, int]


class Identity(Reg):
    """A register whose value must be ``equals`` (an interface version)."""

    equals: int


class Clock(_Map):
    time: Reg
    rate: Reg | None = None


class PlantBlock(_Map):
    heliostat_count: Reg
    target_count: Reg | None = None
    field_state: Coded
    field_command: Command
    clock: Clock


class WeatherBlock(_Map):
    wind_ms: Reg
    wind_direction_deg: Reg
    dni_wm2: Reg
    temperature_c: Reg
    pressure_hpa: Reg


class Handshake(_Map):
    kind: Literal["sequence", "execute"]
    sequence: Reg | None = None
    execute: Reg | None = None
    done: Reg | None = None


class HeliostatCommands(_Map):
    mode: Command
    handshake: Handshake
    strokes_mm: tuple[Reg, Reg]
    corrections_mm: tuple[Reg, Reg]


class HeliostatStatusRegs(_Map):
    state: Coded
    fault: Coded
    strokes_mm: tuple[Reg, Reg]
    cleanliness: Reg


class Heliostats(_Map):
    base: int | None = Field(default=None, ge=0, le=65535)
    stride: int | None = Field(default=None, ge=1, le=65535)
    addresses: list[int] | None = Field(default=None, min_length=1)
    block_size: int | None = Field(default=None, ge=1, le=65535)
    per_unit: int | None = Field(default=None, ge=1, le=65535)
    command: HeliostatCommands
    status: HeliostatStatusRegs


class Defaults(_Map):
    table: Table = "holding"
    command_table: Table | None = None
    word_order: WordOrder = "high_first"
    byte_order: ByteOrder = "big"


class Readable(_Map):
    table: Table
    first: int = Field(ge=0, le=65535)
    last: int = Field(ge=0, le=65535)


class MapFile(_Map):
    name: str = Field(min_length=1, max_length=80)
    title: str = Field(default="", max_length=200)
    defaults: Defaults = Defaults()
    identity: list[Identity] = []
    readable: list[Readable] = []
    plant: PlantBlock
    weather: WeatherBlock
    heliostats: Heliostats


@dataclass(frozen=True)
class Q:
    """A resolved quantity (defaults applied). ``start``/``width``: its span of registers, as an
    address (plant-wide) or an offset in a heliostat block; ``parts``: quantities that add up."""

    path: str
    table: str
    type: str
    start: int
    width: int
    block: bool
    writable: bool
    word_order: str = "high_first"
    byte_order: str = "big"
    scale: float = 1.0
    value_offset: float = 0.0
    unit: str = ""
    meaning: str = ""
    parts: tuple[Q, ...] = ()
    values: dict = field(default_factory=dict, compare=False)
    bits: dict = field(default_factory=dict, compare=False)
    equals: int | None = None

    @property
    def registers(self) -> list[int]:
        """Every register (address or offset) the quantity occupies."""
        if self.parts:
            return [r for p in self.parts for r in p.registers]
        return list(range(self.start, self.start + self.width))


PLACES = (
    "plant.heliostat_count", "plant.target_count", "plant.field_state", "plant.field_command", "plant.clock.time",
    "plant.clock.rate", "weather.wind_ms", "weather.wind_direction_deg", "weather.dni_wm2", "weather.temperature_c",
    "weather.pressure_hpa", "heliostats.command.mode", "heliostats.command.handshake.sequence",
    "heliostats.command.handshake.execute", "heliostats.command.handshake.done", "heliostats.command.strokes_mm[0]",
    "heliostats.command.strokes_mm[1]", "heliostats.command.corrections_mm[0]", "heliostats.command.corrections_mm[1]",
    "heliostats.status.state", "heliostats.status.fault", "heliostats.status.strokes_mm[0]",
    "heliostats.status.strokes_mm[1]", "heliostats.status.cleanliness",
)
"""Every quantity's key path; those under ``heliostats`` are per heliostat (an offset in its block)."""
READ_ONLY_COMMAND_KEYS = ("heliostats.command.handshake.done",)
"""Keys under a command section that the plant writes (the handshake's acknowledgement)."""


def writable_key(path: str) -> bool:
    """Whether the quantity at ``path`` is a command register (written by helicalib)."""
    return (path == "plant.field_command" or path.startswith("heliostats.command.")) and path not in READ_ONLY_COMMAND_KEYS


def get_key(doc: MapFile, path: str):
    """The model at a key path such as ``heliostats.status.strokes_mm[0]`` (None: the map leaves it out)."""
    obj = doc
    for part in path.replace("[", ".").replace("]", "").split("."):
        obj = obj[int(part)] if part.isdigit() else getattr(obj, part)
        if obj is None:
            return None
    return obj


def resolve(path: str, reg: Reg, block: bool, writable: bool, d: Defaults, problems: list[str],
             table: str | None = None) -> Q | None:
    table = reg.table or table or ((d.command_table or d.table) if writable else d.table)
    where = "offset" if block else "address"
    wrong = "address" if block else "offset"
    if not (math.isfinite(reg.scale) and reg.scale != 0):
        problems.append(f"{path}.scale: {reg.scale}: expected a finite number other than 0")
        return None
    if not math.isfinite(reg.value_offset):
        problems.append(f"{path}.value_offset: {reg.value_offset}: expected a finite number")
        return None
    common = dict(word_order=reg.word_order or d.word_order, byte_order=reg.byte_order or d.byte_order,
                  scale=reg.scale, value_offset=reg.value_offset, unit=reg.unit, meaning=reg.meaning,
                  values=getattr(reg, "values", None) or {}, bits=getattr(reg, "bits", None) or {},
                  equals=getattr(reg, "equals", None))
    if reg.parts is not None:
        if reg.address is not None or reg.offset is not None:
            problems.append(f"{path}: either parts or an {where}, not both")
            return None
        parts = []
        for k, p in enumerate(reg.parts):
            if p.parts is not None:
                problems.append(f"{path}.parts[{k}].parts: parts cannot have parts")
                return None
            q = resolve(f"{path}.parts[{k}]", p, block, writable, d, problems, table)
            if q is None:
                return None
            if q.table != table:
                problems.append(f"{path}.parts[{k}].table: {q.table}: the parts of a quantity share one table ({table})")
                return None
            parts.append(q)
        lo = min(min(p.registers) for p in parts)
        hi = max(max(p.registers) for p in parts)
        return Q(path, table, "sum", lo, hi - lo + 1, block, writable, parts=tuple(parts), **common)
    if getattr(reg, wrong) is not None:
        problems.append(f"{path}.{wrong}: {'a heliostat quantity takes an offset in its block' if block else 'a plant-wide quantity takes an address'}")
        return None
    start = getattr(reg, where)
    if start is None:
        problems.append(f"{path}.{where}: missing required key")
        return None
    width = 1 if table == "coil" else WIDTH[reg.type]
    if table == "coil" and (reg.type != "u16" or reg.scale != 1 or reg.value_offset != 0):
        problems.append(f"{path}.type: a coil holds one bit (type u16, no scale or value_offset), got {reg.type}")
        return None
    return Q(path, table, reg.type, start, width, block, writable, **common)
