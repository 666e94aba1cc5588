"""A plant's Modbus register map as data: loading, validating and addressing a map.

A map file says, per quantity the controller reads or writes, where the plant keeps it (register
table, plant-wide address or offset within a heliostat's block), how it is encoded (type, word and
byte order, scale and value offset) and, for coded quantities, what the plant's values mean
(docs/register-maps.md). The client (:mod:`helicalib.devices.modbus`), the simulated plant's server
(:mod:`helicalib.sim.modbus_map`) and the docs read the same map. Every problem is one line naming
the file and the key path (``scs-b.yaml: heliostats.status.state.bits.7: ...``).

:func:`load_register_map` loads a file or a shipped map by name; :func:`default_register_map` is
``PLANT_INTERFACE.md`` version 1. The keys are in :mod:`helicalib.devices.regschema`, the checks that
span keys in :mod:`helicalib.devices.regcheck`, encoding and decoding in :mod:`helicalib.devices.regcodec`.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from pydantic import ValidationError

from helicalib.devices.regcheck import MAX_UNITS, check_count, check_map, check_stroke_ranges
from helicalib.devices.regschema import PLACES, Defaults, MapFile, Q, Reg, get_key, resolve, writable_key
from helicalib.errors import ConfigError

MAPS_DIR = Path(__file__).with_name("maps")
DEFAULT_MAP = "plant-interface-1"


class RegisterMap:
    """A validated register map. ``q`` holds every quantity by key path; :attr:`name` its name."""

    def __init__(self, doc: MapFile, source: str):
        self.doc = doc
        self.source = source
        self.q: dict[str, Q] = {}
        self._extents: dict[str, int] = {}
        problems: list[str] = []
        d = doc.defaults
        for k, ident in enumerate(doc.identity):
            self._add(f"identity[{k}]", ident, False, False, d, problems)
        for path in PLACES:
            reg = get_key(doc, path)
            if reg is not None:
                self._add(path, reg, path.startswith("heliostats."), writable_key(path), d, problems)
        self._refuse(problems + check_map(self))

    @property
    def name(self) -> str:
        return self.doc.name

    def __repr__(self) -> str:
        return f"RegisterMap({self.name!r} from {self.source})"

    def _add(self, path: str, reg: Reg, block: bool, writable: bool, d: Defaults, problems: list[str]) -> None:
        q = resolve(path, reg, block, writable, d, problems)
        if q is not None:
            self.q[path] = q

    # -- the heliostat blocks -----------------------------------------------------------------
    def block_address(self, index: int) -> int:
        """Address of heliostat ``index``'s block (0-based, the field config's order) within its unit."""
        h = self.doc.heliostats
        if h.addresses is not None:
            return h.addresses[index]
        return h.base + h.stride * (index % h.per_unit if h.per_unit else index)

    def unit_step(self, index: int) -> int:
        """How many unit ids past the SCS endpoint's unit heliostat ``index``'s block lies
        (``heliostats.per_unit``: heliostats per unit id; 0 without it)."""
        per = self.doc.heliostats.per_unit
        return index // per if per else 0

    def unit_steps(self, n: int) -> int:
        """Unit ids the blocks of ``n`` heliostats take (1 without ``heliostats.per_unit``)."""
        per = self.doc.heliostats.per_unit
        return max(1, -(-n // per)) if per else 1

    def address(self, q: Q, index: int | None = None) -> int:
        """The protocol address of ``q``'s first register (of heliostat ``index`` for a block quantity)."""
        return self.block_address(index) + q.start if q.block else q.start

    def block_extent(self, table: str) -> int:
        """Registers of a block that answer reads in ``table`` (0: the blocks do not use it)."""
        if table not in self._extents:
            used = [r + 1 for q in self.q.values() if q.block and q.table == table for r in q.registers]
            self._extents[table] = max(max(used), self.doc.heliostats.block_size or 0) if used else 0
        return self._extents[table]

    def plant_readable(self, table: str, address: int) -> bool:
        """Whether a plant-wide register answers reads: mapped, or inside a ``readable`` range."""
        regs = self._plant_regs.get(table, ())
        return address in regs or any(r.table == table and r.first <= address <= r.last for r in self.doc.readable)

    @property
    def _plant_regs(self) -> dict[str, set[int]]:
        if not hasattr(self, "_plant_regs_cache"):
            out: dict[str, set[int]] = {}
            for q in self.q.values():
                if not q.block:
                    out.setdefault(q.table, set()).update(q.registers)
            self._plant_regs_cache = out
        return self._plant_regs_cache

    def check_count(self, n: int, first_unit: int | None = None) -> None:
        """Refuse a map that cannot address ``n`` heliostats (one line naming the key); with
        ``first_unit`` (the SCS endpoint's unit id), also one whose unit ids by block would pass
        Modbus's last unit id (``plant.scs.unit``)."""
        self._refuse(check_count(self, n))
        last = None if first_unit is None else int(first_unit) + self.unit_steps(n) - 1
        if last is not None and self.doc.heliostats.per_unit and last > MAX_UNITS:
            raise ConfigError(f"plant.scs.unit: {n} heliostats at {self.doc.heliostats.per_unit} a unit id (register "
                              f"map {self.source}) from unit {first_unit} reach unit {last}, beyond Modbus's {MAX_UNITS}")

    def check_stroke_ranges(self, drives) -> None:
        """Refuse a map whose stroke demand registers cannot hold a drive's stroke range (one line per
        key naming the drive); ``drives``: drive name → its actuators' ``(min, max)`` [mm]."""
        self._refuse(check_stroke_ranges(self, drives))

    def _refuse(self, problems: list[str]) -> None:
        if problems:
            lines = [f"{self.source}: {p}" for p in problems]
            raise ConfigError("\n".join(lines), problems=lines)


def parse_register_map(data, source: str) -> RegisterMap:
    """Validate a map document (parsed YAML); :class:`ConfigError` with one line per problem."""
    from helicalib.config import validation_error

    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys (name, plant, weather, heliostats ...)")
    try:
        doc = MapFile.model_validate(data)
    except ValidationError as exc:
        raise validation_error(exc, source) from None
    return RegisterMap(doc, source)


SHIPPED = ("plant-interface-1", "plant-interface-1-units", "scs-b")
"""The register maps shipped in ``devices/maps/`` (the folder holds OPC UA node maps too)."""


def shipped_maps() -> list[str]:
    """Names of the register maps shipped with helicalib."""
    return list(SHIPPED)


@cache
def _shipped(name: str) -> RegisterMap:
    from helicalib.config import read_yaml

    return parse_register_map(read_yaml(MAPS_DIR / f"{name}.yaml"), f"{name}.yaml")


def load_register_map(value: str | Path | RegisterMap | None, base_dir: Path | None = None) -> RegisterMap:
    """A register map: None → the default; a bare name (``scs-b``) → the shipped map; else a YAML
    file (relative to ``base_dir``, the field config's folder, when not absolute)."""
    from helicalib.config import is_map_name, read_yaml

    if isinstance(value, RegisterMap):
        return value
    if value is None:
        return default_register_map()
    text = str(value)
    if is_map_name(text):
        if text not in shipped_maps():
            raise ConfigError(f"register map {text!r}: no shipped map of that name (shipped: {', '.join(shipped_maps())}; "
                              "or give a .yaml file)")
        return _shipped(text)
    path = Path(text)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return parse_register_map(read_yaml(path), str(path))


def default_register_map() -> RegisterMap:
    """``PLANT_INTERFACE.md`` version 1 (the shipped ``plant-interface-1``)."""
    return _shipped(DEFAULT_MAP)


def register_map_of(cfg, override: str | Path | None = None) -> RegisterMap:
    """The register map of a field config's plant, checked against its heliostat count: ``override``
    (``--register-map``: a shipped name, or a file relative to the working directory), else
    ``plant.register_map`` (relative to the field config), else the default."""
    if override is not None:
        rmap = load_register_map(override, Path.cwd())
    else:
        rmap = load_register_map(cfg.plant.register_map, cfg.base_dir)
    rmap.check_count(len(cfg.heliostats), cfg.plant.scs.unit if cfg.plant.scs is not None else None)
    used = dict.fromkeys(h.drive for h in cfg.heliostats)
    rmap.check_stroke_ranges({name: [a.stroke_range_mm for a in cfg.drives[name].actuators] for name in used})
    return rmap
