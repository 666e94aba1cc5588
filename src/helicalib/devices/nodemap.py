"""An OPC UA plant's node map: where each quantity of the plant interface lives in its address space.

A node map (YAML, ``docs/opcua.md``) names, per quantity, a node id (``ns=2;s=Field.State``) or a
browse path from the Objects folder (``2:Plant/2:Field/2:State``); per-heliostat nodes carry a
placeholder: ``{id}`` (the heliostat's id, ``H0001``), ``{index}`` (its 0-based block index) or
``{n}`` (``index + 1``). Numbers may be scaled (helicalib value = raw × ``scale`` + ``offset``);
enumerations map the plant's values to helicalib's states and fault codes. Commands are method
calls: the object and method nodes and the order of the method's input arguments.

:func:`load_node_map` validates a map on load; every problem is one line naming the file and the
key path. The client (:mod:`helicalib.devices.opcua`), the simulated plant's OPC UA server
(:mod:`helicalib.sim.opcua_server`) and the docs read the same map.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, ValidationError, ValidationInfo, field_validator, model_validator

from helicalib.config import _Model, read_yaml, validation_error
from helicalib.devices.registers import FaultCode, FieldCommand, FieldState, HeliostatState
from helicalib.errors import ConfigError

MAPS_DIR = Path(__file__).parent / "maps"
DEFAULT_MAP = "opcua-default"
PLACEHOLDERS = ("id", "index", "n")
NODE_ID = re.compile(r"(ns=\d+;)?(i=\d+|s=.+|g=[0-9A-Fa-f-]{36}|b=.+)")
PATH_PART = re.compile(r"\d+:[^/:]+")
ARG_NAMES = {"sequence": "UInt32", "command": "Int32", "stroke_1_mm": "Double", "stroke_2_mm": "Double",
             "correction_1_mm": "Double", "correction_2_mm": "Double", "index": "Int32", "id": "String"}
"""What a method argument may carry, and its OPC UA type unless the map gives one (``sequence:UInt16``)."""
INT_RANGES = {"SByte": (-2**7, 2**7 - 1), "Byte": (0, 2**8 - 1), "Int16": (-2**15, 2**15 - 1),
              "UInt16": (0, 2**16 - 1), "Int32": (-2**31, 2**31 - 1), "UInt32": (0, 2**32 - 1),
              "Int64": (-2**63, 2**63 - 1), "UInt64": (0, 2**64 - 1)}
"""The values each OPC UA integer type holds."""
ARG_TYPES = (*INT_RANGES, "Float", "Double", "String")
MM_ARGS = frozenset({"stroke_1_mm", "stroke_2_mm", "correction_1_mm", "correction_2_mm"})
"""Arguments in mm: sent as Float or Double only (an integer type would truncate a range-checked stroke)."""


def check_node(value: str, per_heliostat: bool | None) -> str:
    """A node reference as a map writes it: a node id or a browse path, with placeholders where a
    node belongs to one heliostat (``per_heliostat``: True required, False refused, None either)."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"expected a node id (ns=2;s=...) or a browse path (2:Plant/2:Field), got {value!r}")
    names = set(re.findall(r"{(\w*)}", value))
    if names - set(PLACEHOLDERS):
        raise ValueError(f"{value!r}: unknown placeholder {{{sorted(names - set(PLACEHOLDERS))[0]}}} "
                         "(use {id}, {index} or {n})")
    if names and per_heliostat is False:
        raise ValueError(f"{value!r}: a placeholder in a node that is not a heliostat's")
    if per_heliostat and not names:
        raise ValueError(f"{value!r}: a heliostat's node needs a placeholder ({{id}}, {{index}} or {{n}})")
    probe = value.format(id="H1", index=0, n=1)
    if not (NODE_ID.fullmatch(probe) or all(PATH_PART.fullmatch(p) for p in probe.strip("/").split("/"))):
        raise ValueError(f"{value!r}: neither a node id (ns=2;s=Name, ns=2;i=17) nor a browse path "
                         "of namespace:Name parts (2:Plant/2:Field)")
    return value


PlantNode = Annotated[str, AfterValidator(lambda v: check_node(v, False))]
"""A node of the field or the weather station (no placeholder)."""
HeliostatNode = Annotated[str, AfterValidator(lambda v: check_node(v, True))]
"""A node of one heliostat (a placeholder: ``{id}``, ``{index}`` or ``{n}``)."""
AnyNode = Annotated[str, AfterValidator(lambda v: check_node(v, None))]
"""A method or its object: one per heliostat, or one for all (the heliostat then an argument)."""


def is_node_id(ref: str) -> bool:
    """Whether a (filled-in) reference is a node id rather than a browse path."""
    return bool(NODE_ID.fullmatch(ref))


def fill(ref: str, index: int, heliostat_id: str) -> str:
    """A per-heliostat reference for one heliostat."""
    return ref.format(id=heliostat_id, index=index, n=index + 1)


class Number(_Model):
    """A numeric variable of the plant: helicalib value = raw × ``scale`` + ``offset``."""

    node: PlantNode
    scale: float = 1.0
    offset: float = 0.0

    def value(self, raw) -> float:
        return float(raw) * self.scale + self.offset

    def raw(self, value: float) -> float:
        return (float(value) - self.offset) / self.scale

    @field_validator("scale")
    @classmethod
    def _nonzero(cls, value: float) -> float:
        if value == 0:
            raise ValueError("a scale of 0 loses the value")
        return value


class HeliostatNumber(Number):
    node: HeliostatNode


def _names(enum, what: str):
    def check(values: dict[int, str] | None):
        for raw, name in (values or {}).items():
            if name not in enum.__members__:
                raise ValueError(f"{raw}: {name!r} is not a helicalib {what} ({', '.join(enum.__members__)})")
        return values
    return AfterValidator(check)


class FieldStateEnum(_Model):
    """An enumerated variable: the plant's values → helicalib's names (default: helicalib's own codes)."""

    node: PlantNode
    values: Annotated[dict[int, str] | None, _names(FieldState, "field state")] = None


class StateEnum(_Model):
    node: HeliostatNode
    values: Annotated[dict[int, str] | None, _names(HeliostatState, "heliostat state")] = None


class FaultEnum(_Model):
    node: HeliostatNode
    values: Annotated[dict[int, str] | None, _names(FaultCode, "fault code")] = None


def _number(value):
    """A bare node reference is short for ``{node: ...}``."""
    return {"node": value} if isinstance(value, str) else value


class FieldNodes(_Model):
    heliostat_count: PlantNode
    state: FieldStateEnum
    plant_time: PlantNode
    """A DateTime variable, or a Double of UTC seconds."""
    plant_time_rate: Number | None = None
    """Plant seconds per real second (a simulator's); absent: 1."""

    @field_validator("plant_time_rate", "state", mode="before")
    @classmethod
    def _short_forms(cls, value):
        return _number(value)


class WeatherNodes(_Model):
    wind_ms: Number
    wind_direction_deg: Number
    dni_wm2: Number
    temperature_c: Number
    pressure_hpa: Number

    @field_validator("*", mode="before")
    @classmethod
    def _short_forms(cls, value):
        return _number(value)


class HeliostatNodes(_Model):
    state: StateEnum
    sequence_done: HeliostatNode
    fault: FaultEnum
    stroke_1_mm: HeliostatNumber
    stroke_2_mm: HeliostatNumber
    cleanliness: HeliostatNumber
    """0..1 after scaling (a plant in percent: ``scale: 0.01``)."""

    @field_validator("state", "fault", "stroke_1_mm", "stroke_2_mm", "cleanliness", mode="before")
    @classmethod
    def _short_forms(cls, value):
        return _number(value)

    def order(self) -> tuple[str, ...]:
        """The per-heliostat references in the order a status read asks them."""
        return (self.state.node, self.sequence_done, self.fault.node, self.stroke_1_mm.node, self.stroke_2_mm.node,
                self.cleanliness.node)


class Method(_Model):
    """A command as a method call: ``object`` (the method's parent) and ``method`` nodes, and the
    input arguments in order (``name`` or ``name:Type``)."""

    object: AnyNode
    method: AnyNode
    args: list[str] = Field(default_factory=list)

    @field_validator("args")
    @classmethod
    def _args(cls, value: list[str]) -> list[str]:
        for a in value:
            name, _, kind = a.partition(":")
            if name not in ARG_NAMES:
                raise ValueError(f"argument {a!r}: not one of {', '.join(ARG_NAMES)}")
            if kind and kind not in ARG_TYPES:
                raise ValueError(f"argument {a!r}: type {kind!r} not one of {', '.join(ARG_TYPES)}")
            kind = kind or ARG_NAMES[name]
            if name in MM_ARGS and kind not in ("Float", "Double"):
                raise ValueError(f"argument {a!r}: an OPC UA method takes strokes in mm as Float or Double")
            if name == "id" and kind != "String":
                raise ValueError(f"argument {a!r}: a heliostat's id is a String")
            if name in ("sequence", "command", "index") and kind not in INT_RANGES:
                raise ValueError(f"argument {a!r}: {name} is an integer ({', '.join(INT_RANGES)})")
        return value

    def typed_args(self) -> list[tuple[str, str]]:
        """(name, OPC UA type) of each input argument."""
        out = []
        for a in self.args:
            name, _, kind = a.partition(":")
            out.append((name, kind or ARG_NAMES[name]))
        return out

    def type_of(self, name: str) -> str | None:
        """The OPC UA type of argument ``name``; None if the method does not take it."""
        return dict(self.typed_args()).get(name)


def check_fits(kind: str | None, value: int, what: str) -> None:
    """A ValueError unless the integer ``value`` fits the OPC UA type ``kind`` (None: not an argument)."""
    if kind in INT_RANGES:
        lo, hi = INT_RANGES[kind]
        if not lo <= value <= hi:
            raise ValueError(f"{what} {value} does not fit the argument's type {kind} ({lo}..{hi})")


class FieldMethod(Method):
    object: PlantNode
    method: PlantNode
    values: dict[str, int] = Field(default_factory=lambda: {"STOW_ALL": 1, "RESUME_TRACKING": 2})
    """helicalib's field command → the value the plant's method takes as ``command``."""

    @model_validator(mode="after")
    def _values(self):
        for name, raw in self.values.items():
            if name not in FieldCommand.__members__ or name == "NONE":
                raise ValueError(f"values: {name!r} is not a field command (STOW_ALL, RESUME_TRACKING)")
            check_fits(self.type_of("command"), raw, f"values: {name}:")
        return self


class Commands(_Model):
    style: Literal["method"] = "method"
    sequence_modulus: int = Field(default=65536, ge=2, le=2**32)
    """Sequence numbers run 0..modulus-1 and wrap (declared first: the methods' check reads it)."""
    field: FieldMethod
    move: Method
    track: Method
    resume: Method | None = None
    """Track with the plant's own corrections (``track(i, None)``); absent: such a track is refused."""
    stow: Method

    @field_validator("move", "track", "resume", "stow")
    @classmethod
    def _sequence(cls, m: Method | None, info: ValidationInfo) -> Method | None:
        if m is None:
            return m
        kind = m.type_of("sequence")
        if kind is None:
            raise ValueError("args: a heliostat command carries its sequence number (add 'sequence')")
        modulus = info.data.get("sequence_modulus")
        if modulus is not None:
            check_fits(kind, modulus - 1, f"args: sequence:{kind} cannot carry sequence_modulus {modulus}:")
        return m


class NodeMap(_Model):
    """A validated node map."""

    version: Literal[1] = 1
    name: str = ""
    field: FieldNodes
    weather: WeatherNodes
    heliostat: HeliostatNodes
    commands: Commands
    source: str = ""

    def state_of(self, raw: int) -> HeliostatState | None:
        return _lookup(self.heliostat.state.values, raw, HeliostatState)

    def fault_of(self, raw: int) -> FaultCode | None:
        return _lookup(self.heliostat.fault.values, raw, FaultCode)

    def field_state_of(self, raw: int) -> FieldState | None:
        return _lookup(self.field.state.values, raw, FieldState)

    def raw_state(self, state: int) -> int:
        """The plant's value of a helicalib heliostat state (the simulated server's side)."""
        return _reverse(self.heliostat.state.values, HeliostatState(int(state)))

    def raw_fault(self, fault: int) -> int:
        return _reverse(self.heliostat.fault.values, FaultCode(int(fault)))

    def raw_field_state(self, state: int) -> int:
        return _reverse(self.field.state.values, FieldState(int(state)))


def _lookup(values: dict[int, str] | None, raw: int, enum):
    if values is None:
        try:
            return enum(int(raw))
        except ValueError:
            return None
    name = values.get(int(raw))
    return None if name is None else enum[name]


def _reverse(values: dict[int, str] | None, member) -> int:
    if values is None:
        return int(member)
    for raw, name in values.items():
        if name == member.name:
            return raw
    return int(member)


def map_path(name_or_path: str | Path | None, resolve=None) -> Path:
    """The file of a node map: a shipped map's bare name (``opcua-default``), or a path (``resolve``
    turns a relative one into a path next to the field config). None: the shipped default."""
    if name_or_path is None:
        name_or_path = DEFAULT_MAP
    text = str(name_or_path)
    if "/" not in text and "\\" not in text and not text.endswith((".yaml", ".yml")):
        path = MAPS_DIR / f"{text}.yaml"
        if not path.is_file():
            shipped = sorted(p.stem for p in MAPS_DIR.glob("opcua*.yaml"))
            raise ConfigError(f"node map {text!r}: no shipped map of that name (shipped: {', '.join(shipped)})")
        return path
    return Path(resolve(text)) if resolve is not None else Path(text)


def load_node_map(name_or_path: str | Path | None = None, resolve=None) -> NodeMap:
    """Read and validate a node map; a problem is a :class:`ConfigError` of one line per problem,
    ``FILE: key.path: what is wrong``."""
    path = map_path(name_or_path, resolve)
    if not path.is_file():
        raise ConfigError(f"{path}: node map not found")
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a node map is a mapping of sections (field, weather, heliostat, commands)")
    try:
        nm = NodeMap.model_validate({**data, "source": str(path)})
    except ValidationError as exc:
        raise validation_error(exc, path) from None
    return nm
