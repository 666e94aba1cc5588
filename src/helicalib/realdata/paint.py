"""Read PAINT / ARTIST calibration data and convert it to helicalib's field config and observations.

Inputs (any of them, found by name under the given directories):

* ``tower-measurements.json``: the plant's WGS84 reference point and each target's measured corners;
* ``*heliostat-properties.json``: WGS84 position, size and the rigid-body kinematics of a heliostat;
* HeliOS tables (``test_axis_data.csv``: one row per axis, ``test_positions.csv``: Gauss-Krüger
  offsets) for heliostats that have no properties JSON (AA23);
* ``*calibration-properties*.json``: one calibration record each (motor steps, sun angles, target,
  UTIS and HeliOS spot centres in WGS84);
* ``test_metadata.csv`` / ``test_benchmark.csv``: map record ids to heliostat ids where the file
  name does not carry it; in PAINT's download layout (``<heliostat>/Calibration/<id>-...``,
  ``<heliostat>/Properties/...``) the heliostat folder says it;
* ``<id>-calibration-item-stac.json`` beside a record: its ``properties.datetime`` is the record's
  UTC time (PAINT's records carry none in the JSON; ``helicalib export-paint`` writes these items).

Conventions and how each is mapped (see ``docs/realdata.md``):

* sun azimuth 0 = south, +90 = east: ``s = (cos el sin az, -cos el cos az, sin el)``;
* motor steps → stroke: ``stroke_mm = 1000 · steps / increment`` with ``length_at_zero_stroke_m =
  initial_stroke_length``, so our actuator length equals PAINT's ``L(m)`` exactly;
* the actuator triangle: ``arm_fixed_m = offset``, ``arm_moving_m = pivot_radius``,
  ``gamma0_deg = φ(L0)``, ``sign = +1`` (clockwise_axis_movement 0) or ``-1`` (1), so that our axis
  angle is PAINT's angle minus its initial angle; the initial angles (axis 1 from the zenith: minus
  π/2) are folded into the custom drive's ``axis2_enu`` and ``normal0_enu``;
* mirror centre = position + the rotated ``(0, concentrator_translation_n, 0)`` =
  ``position - concentrator_translation_n · n``, i.e. ``mirror_offset_m = -0.175``;
* WGS84 → plant ENU by the exact geodetic → ECEF → ENU formulas (:mod:`helicalib.realdata.geodesy`);
* target crops: image x runs east → west (= our target u), y top → bottom (= -v).
"""

from __future__ import annotations

import copy
import csv
import json
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from helicalib.calibration.observations import Observation
from helicalib.config import MAX_COORDINATE_M, _short
from helicalib.errors import ConfigError
from helicalib.realdata.geodesy import gauss_krueger_offset_to_enu, wgs84_to_enu
from helicalib.realdata.paint_kinematics import PaintActuator, PaintKinematics, sun_vector_paint

CORNERS = ("upper_left", "upper_right", "lower_right", "lower_left")
JUELICH_MIRROR_SIZE_M = (3.22, 2.56)  # width, height of the Jülich heliostats (AA39 properties)
JUELICH_CONCENTRATOR_TRANSLATION = (0.0, 0.175, 0.0)

# defaults for the sections a PAINT import has nothing to say about (copied from field_config/demo_north.yaml)
_DEFAULT_SECTIONS = {
    "plant": {"scs": {"host": "127.0.0.1", "port": 5020, "unit": 1, "timeout_s": 2.0}, "clock": "plant"},
    "calibration": {"loop_threshold_mrad": 3.5, "max_iterations": 5},
    "gating": {"wind_max_ms": 10.0, "wind_preferred_ms": 5.0, "stow_wind_ms": 15.0, "dni_min_wm2": 300,
               "dni_preferred_wm2": 800, "cleanliness_min": 0.55, "cleanliness_preferred": 0.7},
    "acceptance": {"low_band_deg": [5, 15], "high_elevation_deg": 15, "high_window_h": 2, "min_points": 5,
                   "max_rms_mrad": 1.2},
    "tracking_test": {"threshold_mrad": 3.5,
                      "wind_bins": [{"wind_ms": 4, "min_fraction": 0.99}, {"wind_ms": 8, "min_fraction": 0.62},
                                    {"wind_ms": 11, "min_fraction": 0.33}],
                      "bin_half_width_ms": 1.0},
    "storage": {"database": "sqlite:///helicalib.db", "images_dir": "images"},
}


# ---------------------------------------------------------------------------- data classes
@dataclass(frozen=True)
class PaintTarget:
    name: str
    corners_enu: dict[str, np.ndarray]  # upper_left, upper_right, lower_right, lower_left [m, ENU]
    normal_enu: np.ndarray

    @property
    def center_enu(self) -> np.ndarray:
        return np.mean([self.corners_enu[c] for c in CORNERS], axis=0)

    @property
    def size_m(self) -> tuple[float, float]:
        c = self.corners_enu
        w = 0.5 * (np.linalg.norm(c["upper_left"] - c["upper_right"]) + np.linalg.norm(c["lower_left"] - c["lower_right"]))
        h = 0.5 * (np.linalg.norm(c["upper_left"] - c["lower_left"]) + np.linalg.norm(c["upper_right"] - c["lower_right"]))
        return float(w), float(h)


@dataclass(frozen=True)
class PaintTower:
    reference_llh: tuple[float, float, float]
    targets: dict[str, PaintTarget]
    receiver_center_enu: np.ndarray | None = None


@dataclass(frozen=True)
class PaintHeliostat:
    id: str
    kinematics: PaintKinematics
    mirror_size_m: tuple[float, float]
    source: str

    @property
    def position_enu_m(self) -> np.ndarray:
        return np.asarray(self.kinematics.position_enu_m, dtype=float)


@dataclass(frozen=True)
class PaintRecord:
    record_id: str
    heliostat_id: str | None
    motor_steps: tuple[int | float, int | float]
    target_name: str
    sun_azimuth_deg: float  # PAINT: 0 = south, +90 = east
    sun_elevation_deg: float
    utis_llh: tuple[float, float, float] | None
    helios_llh: tuple[float, float, float] | None
    path: str
    utc_time: str = ""  # the STAC item's datetime beside the record, when there is one

    @property
    def sun_enu(self) -> np.ndarray:
        return sun_vector_paint(self.sun_azimuth_deg, self.sun_elevation_deg)


@dataclass
class PaintImport:
    tower: PaintTower
    heliostats: dict[str, PaintHeliostat] = field(default_factory=dict)
    records: list[PaintRecord] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    bad: dict[str, list[str]] = field(default_factory=lambda: {"records": [], "heliostats": [], "targets": []})
    """Records, heliostats and targets skipped for a value no plant can have: one line each naming
    the file and key (``FILE: motor_position.axis_1_motor_position: expected a finite number, got nan``)."""


# ---------------------------------------------------------------------------- value checks
class BadValue(ConfigError):
    """A PAINT file holds a value no plant can have; the message names the file and the key."""


SUN_ELEVATION_DEG = (-1.0, 90.0)
"""A calibration record's sun: above the horizon (apparent elevation, refraction lifts it ≈ 0.6°)."""
MAX_STEPS = 1e9
"""Largest motor position or increment magnitude [steps] (PAINT's are below 10⁶)."""


def _number(value, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """``value`` as a finite float within [lo, hi], or :class:`BadValue` naming ``where`` (FILE: key)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BadValue(f"{where}: expected a number, got {_short(value)}")
    try:
        x = float(value)
    except OverflowError:
        raise BadValue(f"{where}: {_short(value)} is too large for a number") from None
    if not math.isfinite(x):
        raise BadValue(f"{where}: expected a finite number, got {x}")
    if not lo <= x <= hi:
        raise BadValue(f"{where}: {x:g} is outside {lo:g}..{hi:g}")
    return x


def _numbers(value, where: str, n: int, bounds=None) -> tuple[float, ...]:
    """``n`` finite numbers (a JSON list), each within its ``bounds`` (lo, hi) when given."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise BadValue(f"{where}: expected {n} numbers, got {_short(value)}")
    return tuple(_number(x, f"{where}[{k}]", *(bounds[k] if bounds else ())) for k, x in enumerate(value))


def _object(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise BadValue(f"{where}: expected an object, got {_short(value)}")
    return value


def _int(digits: str) -> int | float:
    """A JSON integer; one of more digits than any count has is read as a float (infinite when huge,
    refused by :func:`_number`) instead of stopping Python's integer-string limit with a traceback."""
    return int(digits) if len(digits) <= 30 else float(digits)


def load_json(path: str | Path):
    """A PAINT JSON file (UTF-8); integers of any length are read (see :func:`_int`)."""
    return json.loads(Path(path).read_text(encoding="utf-8-sig"), parse_int=_int)


LLH_BOUNDS = ((-90.0, 90.0), (-180.0, 180.0), (-1000.0, 10000.0))
"""WGS84 latitude, longitude [deg] and ellipsoidal height [m] of a point of a plant."""


def _llh(value, where: str) -> tuple[float, float, float]:
    return _numbers(value, where, 3, LLH_BOUNDS)


def _in_plant(enu: np.ndarray, where: str) -> np.ndarray:
    if not np.all(np.abs(enu) <= MAX_COORDINATE_M):
        raise BadValue(f"{where}: lies {float(np.max(np.abs(enu))):.0f} m from the plant's reference point "
                       f"(more than {MAX_COORDINATE_M:g} m)")
    return enu


# ---------------------------------------------------------------------------- readers
def read_tower(path: str | Path, bad: list[str] | None = None) -> PaintTower:
    """The plant reference and its planar targets. A bad reference point refuses the file
    (:class:`BadValue`); a target whose name is no helicalib id or whose values no board can have is
    left out, its line added to ``bad``."""
    from helicalib.config import Target

    d = load_json(path)
    try:
        coords = d["power_plant_properties"]["coordinates"]
    except (KeyError, TypeError):
        raise ConfigError(f"{path}: power_plant_properties.coordinates: missing") from None
    ref = _llh(coords, f"{path}: power_plant_properties.coordinates")
    targets = {}
    receiver = None
    for name, t in d.items():
        if name == "power_plant_properties" or not isinstance(t, dict):
            continue
        coords = t.get("coordinates", {})
        try:
            if t.get("type") == "planar" and isinstance(coords, dict) and all(c in coords for c in CORNERS):
                corners = {c: _in_plant(wgs84_to_enu(_llh(coords[c], f"{path}: {name}.coordinates.{c}"), ref),
                                        f"{path}: {name}.coordinates.{c}") for c in CORNERS}
                n = np.asarray(_numbers(t.get("normal_vector", [0, 1, 0]), f"{path}: {name}.normal_vector", 3,
                                        [(-1.5, 1.5)] * 3))
                if np.linalg.norm(n) < 0.5:
                    raise BadValue(f"{path}: {name}.normal_vector: expected a unit vector, got {n.tolist()}")
                target = PaintTarget(name, corners, n / np.linalg.norm(n))
                try:
                    Target.model_validate(target_config(target))
                except ValueError as exc:  # pydantic's ValidationError: a name or size no board has
                    raise BadValue(f"{path}: {_short(name)}: not a board helicalib can use "
                                   f"({_first_problem(exc)})") from None
                targets[name] = target
            elif name == "receiver" and isinstance(coords, dict) and "center" in coords:
                receiver = _in_plant(wgs84_to_enu(_llh(coords["center"], f"{path}: receiver.coordinates.center"), ref),
                                     f"{path}: receiver.coordinates.center")
        except BadValue as exc:
            if bad is None:
                raise
            bad.append(f"{exc}; target skipped")
    return PaintTower(ref, targets, receiver)


def _first_problem(exc: Exception) -> str:
    """The first problem of a pydantic ValidationError, as ``key: what``."""
    from pydantic import ValidationError

    from helicalib.config import validation_error

    return validation_error(exc).problems[0] if isinstance(exc, ValidationError) else str(exc)


HELIOS_COLUMNS = {"increment": "PulseRatio", "initial_stroke_length": "B", "offset": "C", "pivot_radius": "D",
                  "initial_angle": "AngleK", "clockwise_axis_movement": "Reversed", "min_increment": "MinCounts",
                  "max_increment": "MaxCounts", "type_axis": "Type"}
"""The HeliOS axis table's column of each PAINT actuator key (PAINT's mapping)."""


def _actuator(a: dict, where: str, columns: dict[str, str] | None = None) -> PaintActuator:
    """One actuator, every value checked; a problem names ``where`` and the key (``FILE:
    ...actuators[0].increment``) or, given ``columns``, the table's column (``FILE: line 2: PulseRatio``)."""
    def at(key: str) -> str:
        return f"{where}: {columns[key]}" if columns else f"{where}.{key}"

    a = _object(a, where)
    turn = a["clockwise_axis_movement"]
    if isinstance(turn, bool) or turn not in (0, 1):
        raise BadValue(f"{at('clockwise_axis_movement')}: expected 0 or 1, got {_short(turn)}")
    lo = _number(a.get("min_increment", 0), at("min_increment"), -MAX_STEPS, MAX_STEPS)
    hi = a.get("max_increment")
    hi = math.inf if hi is None else _number(hi, at("max_increment"), -MAX_STEPS, MAX_STEPS)
    if not lo < hi:
        raise BadValue(f"{at('max_increment')}: {hi:g} is not above the minimum {lo:g}")
    kind = a.get("type_axis", "linear")
    if not isinstance(kind, str) or kind not in ("linear", "ideal"):
        raise BadValue(f"{at('type_axis')}: expected linear or ideal, got {_short(kind)}")
    return PaintActuator(
        increment=_number(a["increment"], at("increment"), 1e-6, MAX_STEPS),
        initial_stroke_length=_number(a["initial_stroke_length"], at("initial_stroke_length"), 1e-6, 50.0),
        offset=_number(a["offset"], at("offset"), 1e-6, 20.0),
        pivot_radius=_number(a["pivot_radius"], at("pivot_radius"), 1e-6, 20.0),
        initial_angle=_number(a["initial_angle"], at("initial_angle"), -2 * math.pi, 2 * math.pi),
        clockwise_axis_movement=int(turn),
        min_increment=lo,
        max_increment=hi,
        type_axis=kind,
    )


def read_heliostat_properties(path: str | Path, heliostat_id: str, reference_llh) -> PaintHeliostat:
    """A heliostat's properties file, every value checked: :class:`BadValue` names the file and key."""
    d = load_json(path)
    k = _object(d["kinematics_properties"], f"{path}: kinematics_properties")
    pos = _in_plant(wgs84_to_enu(_llh(d["heliostat_position"], f"{path}: heliostat_position"), reference_llh),
                    f"{path}: heliostat_position")
    acts = k["actuators"]
    if not isinstance(acts, list) or len(acts) != 2:
        raise BadValue(f"{path}: kinematics_properties.actuators: expected 2 actuators, got {_short(acts)}")
    shift = (-10.0, 10.0)
    kin = PaintKinematics(
        position_enu_m=tuple(float(x) for x in pos),
        actuators=tuple(_actuator(a, f"{path}: kinematics_properties.actuators[{i}]") for i, a in enumerate(acts)),
        concentrator_translation=tuple(_number(k.get(f"concentrator_translation_{c}", 0.0),
                                               f"{path}: kinematics_properties.concentrator_translation_{c}", *shift)
                                       for c in "enu"),
        joint_translation_1=tuple(_number(k.get(f"joint_translation_{c}_1", 0.0),
                                          f"{path}: kinematics_properties.joint_translation_{c}_1", *shift) for c in "enu"),
        joint_translation_2=tuple(_number(k.get(f"joint_translation_{c}_2", 0.0),
                                          f"{path}: kinematics_properties.joint_translation_{c}_2", *shift) for c in "enu"),
        initial_orientation=_numbers(d.get("initial_orientation", [0.0, -1.0, 0.0]), f"{path}: initial_orientation", 3,
                                     [(-1.5, 1.5)] * 3),
    )
    if np.linalg.norm(kin.initial_orientation) < 0.5:
        raise BadValue(f"{path}: initial_orientation: expected a unit vector, got {list(kin.initial_orientation)}")
    size = (_number(d.get("width", JUELICH_MIRROR_SIZE_M[0]), f"{path}: width", 0.01, 50.0),
            _number(d.get("height", JUELICH_MIRROR_SIZE_M[1]), f"{path}: height", 0.01, 50.0))
    return PaintHeliostat(heliostat_id, kin, size, str(path))


def _usable(h: PaintHeliostat) -> PaintHeliostat:
    """``h`` if helicalib's drive model can hold its kinematics (the drive :func:`paint_drive` makes
    passes the field config's checks), else :class:`BadValue` naming its source and the problem."""
    from helicalib.config import Drive

    try:
        Drive.model_validate(paint_drive(h))
    except ValueError as exc:  # pydantic's ValidationError: e.g. a triangle no stroke closes (γ0 not finite)
        raise BadValue(f"{h.source}: kinematics_properties: no drive helicalib can model "
                       f"(drive {_first_problem(exc)})") from None
    return h


def heliostat_number_to_name(number: int | str) -> str:
    """HeliOS numeric id → PAINT name: 10123 → AA23 (row letter, column letter, position)."""
    s = str(number)
    return chr(ord("A") + int(s[0]) - 1) + chr(ord("A") + int(s[1:3]) - 1) + s[3:]


def read_helios_tables(axis_csv: str | Path, positions_csv: str | Path,
                       reference_altitude_m: float) -> list[PaintHeliostat | BadValue]:
    """HeliOS actuator table (A..E, PulseRatio, AngleK, Reversed) + GK positions → heliostats (or, for a
    heliostat whose rows hold a value no drive has, a :class:`BadValue` naming the file, line and column).

    Column mapping (PAINT's): A = offset_shift, B = initial_stroke_length, C = offset,
    D = pivot_radius, E = radius_shift, PulseRatio = increment, AngleK = initial_angle,
    Reversed = clockwise_axis_movement. Mirror size and concentrator translation are not in
    the tables: the Jülich values (3.22 m × 2.56 m, 0.175 m) are used.
    """
    def rows(p):
        with open(p, newline="", encoding="utf-8-sig") as f:
            return list(csv.DictReader(f))

    def cell(r, key, where):
        try:
            return float(r[key])
        except ValueError:
            raise BadValue(f"{where}: {key}: expected a number, got {_short(r[key])}") from None

    axes: dict[str, dict[int, PaintActuator]] = {}
    broken: dict[str, str] = {}
    for line, r in enumerate(rows(axis_csv), start=2):
        where = f"{axis_csv}: line {line}"
        try:
            if cell(r, "A", where) != 0.0 or cell(r, "E", where) != 0.0:
                raise ConfigError(f"{axis_csv}: heliostat {r['HeliostatId']}: non-zero offset/radius shift is not supported")
            values = {"increment": cell(r, "PulseRatio", where), "initial_stroke_length": cell(r, "B", where),
                      "offset": cell(r, "C", where), "pivot_radius": cell(r, "D", where),
                      "initial_angle": cell(r, "AngleK", where), "clockwise_axis_movement": cell(r, "Reversed", where),
                      "min_increment": cell(r, "MinCounts", where), "max_increment": cell(r, "MaxCounts", where),
                      "type_axis": r["Type"].lower()}
            if values["clockwise_axis_movement"] in (0.0, 1.0):
                values["clockwise_axis_movement"] = int(values["clockwise_axis_movement"])
            axes.setdefault(r["HeliostatId"], {})[int(r["Number"])] = _actuator(values, where, HELIOS_COLUMNS)
        except BadValue as exc:
            broken.setdefault(r["HeliostatId"], str(exc))
    out = []
    for line, r in enumerate(rows(positions_csv), start=2):
        hid = r["HeliostatId"]
        if hid in broken:
            out.append(BadValue(f"{broken[hid]}; heliostat {_short(hid)} skipped"))
            continue
        if hid not in axes or sorted(axes[hid]) != [1, 2]:
            continue
        where = f"{positions_csv}: line {line}"
        try:
            try:
                name = heliostat_number_to_name(hid)
            except (ValueError, IndexError):
                name = ""
            if not _HELIOSTAT_NAME.match(name):
                raise BadValue(f"{where}: HeliostatId: {_short(hid)} names no PAINT heliostat (AA01..ZZ99)")
            xyz = [_number(cell(r, k, where), f"{where}: {k}", -MAX_COORDINATE_M, MAX_COORDINATE_M) for k in "xyz"]
            pos = gauss_krueger_offset_to_enu(*xyz, reference_altitude_m)
            kin = PaintKinematics(tuple(float(x) for x in pos), (axes[hid][1], axes[hid][2]),
                                  concentrator_translation=JUELICH_CONCENTRATOR_TRANSLATION)
            out.append(_usable(PaintHeliostat(name, kin, JUELICH_MIRROR_SIZE_M, f"{axis_csv} + {positions_csv}")))
        except BadValue as exc:
            out.append(BadValue(f"{exc}; heliostat skipped"))
    return out


_HELIOSTAT_NAME = re.compile(r"^[A-Z]{2}\d{2}$")


def read_calibration(path: str | Path, heliostat_id: str | None = None) -> PaintRecord:
    path = Path(path)
    d = load_json(path)
    stem = path.name.replace(".json", "")
    record_id = stem.replace("-calibration-properties", "")
    if heliostat_id is None:
        m = re.match(r"^([A-Z]{2}\d{2})-", path.name)
        if m:
            heliostat_id = m.group(1)
        elif _HELIOSTAT_NAME.match(path.parent.name):
            heliostat_id = path.parent.name
        else:
            heliostat_id = _layout_heliostat(path, "Calibration")
    fs = _object(d.get("focal_spot", {}), f"{path}: focal_spot")
    motors = _object(d["motor_position"], f"{path}: motor_position")
    target = d["target_name"]
    if not isinstance(target, str):
        raise BadValue(f"{path}: target_name: expected a text, got {_short(target)}")
    return PaintRecord(
        record_id=record_id,
        heliostat_id=heliostat_id,
        motor_steps=tuple(_steps(motors[f"axis_{k}_motor_position"], f"{path}: motor_position.axis_{k}_motor_position")
                          for k in (1, 2)),
        target_name=target,
        sun_azimuth_deg=_number(d["sun_azimuth"], f"{path}: sun_azimuth", -360.0, 360.0),
        sun_elevation_deg=_number(d["sun_elevation"], f"{path}: sun_elevation", *SUN_ELEVATION_DEG),
        utis_llh=_llh(fs["UTIS"], f"{path}: focal_spot.UTIS") if fs.get("UTIS") else None,
        helios_llh=_llh(fs["HeliOS"], f"{path}: focal_spot.HeliOS") if fs.get("HeliOS") else None,
        path=str(path),
        utc_time=_item_datetime(path.with_name(f"{record_id}-calibration-item-stac.json")),
    )


def _steps(value, where: str = "motor position") -> int | float:
    """A motor position: whole steps as an int, a fractional count (helicalib's export of strokes that are
    no whole number of steps) kept as it is rather than truncated; :class:`BadValue` if it is no
    finite number of at most :data:`MAX_STEPS`."""
    v = _number(value, where, -MAX_STEPS, MAX_STEPS)
    return int(v) if v.is_integer() else v


def _layout_heliostat(path: Path, folder: str) -> str | None:
    """PAINT's download layout ``<heliostat>/Calibration/...``, ``<heliostat>/Properties/...``: the heliostat id."""
    return path.parent.parent.name if path.parent.name == folder and path.parent.parent.name else None


def _item_datetime(item: Path) -> str:
    """``properties.datetime`` of a PAINT STAC item (UTC, ISO 8601), or "" when there is no item."""
    if not item.is_file():
        return ""
    from datetime import datetime

    when = _object(_object(load_json(item), f"{item}: (top level)").get("properties", {}),
                   f"{item}: properties").get("datetime")
    if not when:
        return ""
    try:
        if not isinstance(when, str) or datetime.fromisoformat(when).utcoffset() is None:
            raise ValueError
    except ValueError:
        raise BadValue(f"{item}: properties.datetime: expected an ISO 8601 time with its UTC offset, "
                       f"got {_short(when)}") from None
    return when


def scan(dirs: list[str | Path]) -> PaintImport:
    """Find and read every PAINT file under ``dirs`` (recursively)."""
    files: list[Path] = []
    for d in dirs:
        d = Path(d)
        if d.is_file():
            files.append(d)
        elif d.is_dir():
            files.extend(sorted(p for p in d.rglob("*") if p.is_file()))
        else:
            raise ConfigError(f"{d}: no such file or directory")
    towers = [p for p in files if p.name.endswith("tower-measurements.json")]
    if not towers:
        raise ConfigError("no tower-measurements.json found in " + ", ".join(str(d) for d in dirs))
    bad_targets: list[str] = []
    tower = read_tower(towers[0], bad_targets)
    imp = PaintImport(tower)
    imp.bad["targets"] += bad_targets
    for other in towers[1:]:
        if read_tower(other, []).reference_llh != tower.reference_llh:
            imp.notes.append(f"{other}: a different plant reference than {towers[0]}; ignored")

    id_map: dict[str, str] = {}
    for p in files:
        if p.suffix == ".csv" and p.name in ("test_metadata.csv", "test_benchmark.csv") or p.name.endswith("metadata.csv"):
            with open(p, newline="", encoding="utf-8-sig") as f:
                for row in csv.DictReader(f):
                    if "Id" in row and "HeliostatId" in row and _HELIOSTAT_NAME.match(str(row["HeliostatId"])):
                        id_map[str(row["Id"])] = str(row["HeliostatId"])

    for p in files:
        if p.name.endswith("heliostat-properties.json"):
            m = re.match(r"^([A-Z]{2}\d{2})-", p.name)
            hid = m.group(1) if m else (p.parent.name if _HELIOSTAT_NAME.match(p.parent.name)
                                        else _layout_heliostat(p, "Properties"))
            if hid is None:
                imp.notes.append(f"{p}: cannot tell which heliostat this is (name it AA00-heliostat-properties.json)")
                continue
            try:
                h = _usable(read_heliostat_properties(p, hid, tower.reference_llh))
            except BadValue as exc:
                imp.bad["heliostats"].append(f"{exc}; heliostat {hid} skipped")
                continue
            if hid in imp.heliostats and imp.heliostats[hid].kinematics != h.kinematics:
                imp.notes.append(f"{p}: differs from {imp.heliostats[hid].source}; the first is kept")
                continue
            if any(a.type_axis != "linear" for a in h.kinematics.actuators):
                imp.notes.append(f"{p}: actuator type_axis 'ideal' read with the linear-actuator law (the parameters are linear ones)")
            imp.heliostats.setdefault(hid, h)

    axis = [p for p in files if p.name.endswith("axis_data.csv")]
    positions = [p for p in files if p.name.endswith("positions.csv")]
    if axis and positions:
        for h in read_helios_tables(axis[0], positions[0], tower.reference_llh[2]):
            if isinstance(h, BadValue):
                imp.bad["heliostats"].append(str(h))
                continue
            if h.id not in imp.heliostats:
                imp.heliostats[h.id] = h
                imp.notes.append(f"{h.id}: kinematics from the HeliOS tables {axis[0].name}, {positions[0].name} "
                                 f"(mirror size and concentrator translation: Jülich defaults)")

    seen = set()
    for p in files:
        if "calibration-properties" in p.name and p.suffix == ".json":
            try:
                rec = read_calibration(p)
                if rec.heliostat_id is None:
                    rec = read_calibration(p, id_map.get(rec.record_id))
            except BadValue as exc:
                imp.bad["records"].append(f"{exc}; record skipped")
                continue
            if rec.heliostat_id is None:
                imp.notes.append(f"{p}: no heliostat id (file name, folder or metadata CSV); skipped")
                continue
            key = (rec.heliostat_id, rec.motor_steps, rec.sun_azimuth_deg, rec.sun_elevation_deg)
            if key in seen:
                continue
            seen.add(key)
            imp.records.append(rec)
    return imp


# ---------------------------------------------------------------------------- conversions
def _rot(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def steps_to_stroke_mm(steps, actuator: PaintActuator) -> np.ndarray:
    """Motor steps → stroke [mm] (length beyond ``initial_stroke_length``)."""
    return 1000.0 * np.asarray(steps, dtype=float) / actuator.increment


def paint_drive(h: PaintHeliostat) -> dict:
    """A ``custom`` drive that reproduces the PAINT kinematics of ``h`` exactly (as a config mapping)."""
    kin = h.kinematics
    if any(abs(x) > 0 for x in kin.joint_translation_1 + kin.joint_translation_2) or \
            abs(kin.concentrator_translation[0]) > 0 or abs(kin.concentrator_translation[2]) > 0:
        raise ConfigError(f"{h.id}: joint translations or a sideways concentrator translation cannot be expressed "
                          "in a helicalib drive (only a mirror offset along the normal)")
    e, u = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    theta0 = [kin.actuators[0].initial_angle - math.pi / 2, kin.actuators[1].initial_angle]
    # fixed tilts of the PAINT chain (zero in published properties) act on both axes
    tilt1 = _rot([0, 1, 0], kin.first_joint_tilt_n) @ _rot(u, kin.first_joint_tilt_u)
    tilt2 = _rot(e, kin.second_joint_tilt_e) @ _rot([0, 1, 0], kin.second_joint_tilt_n)
    a1 = tilt1 @ e
    pre2 = tilt1 @ _rot(e, theta0[0]) @ tilt2
    # n = R(a1, θ1') · R(a2, θ2') · n0 with θ' = θ - θ0: R(a1, θ0_1) commutes with R(a1, θ1')
    a2 = pre2 @ u
    n0 = pre2 @ _rot(u, theta0[1]) @ np.asarray(kin.initial_orientation, dtype=float)
    acts = []
    for a in kin.actuators:
        phi0 = float(a.phi(a.initial_stroke_length))
        lo = 1000.0 * a.min_increment / a.increment
        hi = 1000.0 * a.max_increment / a.increment if math.isfinite(a.max_increment) else 1000.0
        acts.append({
            "arm_fixed_m": a.offset,
            "arm_moving_m": a.pivot_radius,
            "gamma0_deg": math.degrees(phi0),
            "sign": 1 if a.clockwise_axis_movement == 0 else -1,
            "length_at_zero_stroke_m": a.initial_stroke_length,
            "stroke_range_mm": [lo, hi],
        })
    return {
        "kind": "custom",
        "axis1_enu": a1.tolist(),
        "axis2_enu": a2.tolist(),
        "normal0_enu": n0.tolist(),
        "mirror_offset_m": -float(kin.concentrator_translation[1]),
        "mirror_size_m": list(h.mirror_size_m),
        "actuators": acts,
    }


def target_config(t: PaintTarget) -> dict:
    return {"id": t.name, "center_enu_m": t.center_enu.tolist(), "normal_enu": t.normal_enu.tolist(),
            "size_m": list(t.size_m)}


def field_config_dict(imp: PaintImport, site_name: str = "Jülich solar tower (PAINT import)") -> dict:
    """The imported plant as a field-config mapping (our schema, FIELD_CONFIG.md version 1)."""
    if not imp.heliostats:
        lines = imp.bad["heliostats"] + ["no usable heliostat properties found (heliostat-properties.json or HeliOS tables)"]
        raise ConfigError("\n".join(lines), problems=lines)
    ref = imp.tower.reference_llh
    aim = imp.tower.receiver_center_enu
    if aim is None:
        aim = np.mean([t.center_enu for t in imp.tower.targets.values()], axis=0)
    targets_used = Counter()
    heliostats = []
    for hid, h in sorted(imp.heliostats.items()):
        recs = [r for r in imp.records if r.heliostat_id == hid]
        counts = Counter(r.target_name for r in recs if r.target_name in imp.tower.targets)
        target = counts.most_common(1)[0][0] if counts else sorted(imp.tower.targets)[0]
        targets_used[target] += 1
        heliostats.append({"id": hid, "position_enu_m": h.position_enu_m.tolist(), "drive": f"paint_{hid}",
                           "target": target})
    cfg = {
        "site": {"name": site_name, "latitude_deg": ref[0], "longitude_deg": ref[1], "altitude_m": ref[2]},
        "tower": {"receiver_aim_enu_m": np.asarray(aim, dtype=float).tolist()},
        "targets": [target_config(t) for _, t in sorted(imp.tower.targets.items())],
        "cameras": [],
        "drives": {f"paint_{hid}": paint_drive(h) for hid, h in sorted(imp.heliostats.items())},
        "heliostats": heliostats,
    }
    cfg.update(copy.deepcopy(_DEFAULT_SECTIONS))
    return cfg


def spot_enu(imp: PaintImport, rec: PaintRecord, which: str = "UTIS") -> np.ndarray | None:
    llh = rec.utis_llh if which.upper() == "UTIS" else rec.helios_llh
    return None if llh is None else wgs84_to_enu(llh, imp.tower.reference_llh)


def target_uv(t: PaintTarget, enu) -> np.ndarray:
    """ENU point → (u, v) in our target frame (u = unit(z × normal), v = normal × u) about the corner centre."""
    w = t.normal_enu
    u = np.cross([0.0, 0.0, 1.0], w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    d = np.asarray(enu, dtype=float) - t.center_enu
    return np.array([d @ u, d @ v])


SPOT_OFF_PLANE_M = 1.0
"""A record's spot lies on its board: within its edges and this close to its plane [m]."""


def _unphysical(h: PaintHeliostat, t: PaintTarget, rec: PaintRecord, spot: np.ndarray, which: str) -> str | None:
    """Why a record (values each in range) still describes no pose of its heliostat, or None: a motor
    position outside the actuator's range (the drive written refuses its stroke), strokes whose
    actuator triangle does not close, a spot off its board."""
    for k, (m, a) in enumerate(zip(rec.motor_steps, h.kinematics.actuators), start=1):
        hi = a.max_increment if math.isfinite(a.max_increment) else a.increment  # paint_drive's 1000 mm
        if not a.min_increment <= m <= hi:
            return (f"motor_position.axis_{k}_motor_position: {m:g} steps lie outside the actuator's range "
                    f"{a.min_increment:g}..{hi:g} ({h.source})")
    with np.errstate(invalid="ignore"):
        _, direction = h.kinematics.beam(rec.motor_steps, rec.sun_enu)
    if not np.all(np.isfinite(direction)):
        return "motor_position: the actuators cannot reach these positions (their triangle does not close)"
    u, v = target_uv(t, spot)
    off = float(np.dot(np.asarray(spot) - t.center_enu, t.normal_enu))
    w, ht = t.size_m
    if not (abs(u) <= w / 2 and abs(v) <= ht / 2 and abs(off) <= SPOT_OFF_PLANE_M):
        return (f"focal_spot.{which}: lies off the board of {t.name} (u {u:.2f}, v {v:.2f} m on a {w:.2f} x {ht:.2f} m "
                f"board, {off:.2f} m from its plane)")
    return None


def observations(imp: PaintImport, which: str = "UTIS") -> tuple[list[Observation], list[str]]:
    """Observation rows for every record whose heliostat and target are known and whose pose is
    physical (:func:`_unphysical`; the others are added to ``imp.bad``); plus notes on the rest."""
    rows, notes = [], []
    for rec in imp.records:
        h = imp.heliostats.get(rec.heliostat_id)
        t = imp.tower.targets.get(rec.target_name)
        spot = spot_enu(imp, rec, which)
        if h is None or t is None or spot is None:
            notes.append(f"{rec.path}: skipped (heliostat {rec.heliostat_id} known: {h is not None}, "
                         f"target {rec.target_name} known: {t is not None}, {which} spot: {spot is not None})")
            continue
        problem = _unphysical(h, t, rec, spot, which)
        if problem:
            imp.bad["records"].append(f"{rec.path}: {problem}; record skipped")
            continue
        s = rec.sun_enu
        strokes = [float(steps_to_stroke_mm(m, a)) for m, a in zip(rec.motor_steps, h.kinematics.actuators)]
        uv = target_uv(t, spot)
        rows.append(Observation(
            heliostat_id=h.id, utc_time=rec.utc_time, sun_e=float(s[0]), sun_n=float(s[1]), sun_u=float(s[2]),
            stroke1_mm=strokes[0], stroke2_mm=strokes[1], target_id=t.name,
            spot_e_m=float(spot[0]), spot_n_m=float(spot[1]), spot_u_m=float(spot[2]),
            target_u_m=float(uv[0]), target_v_m=float(uv[1]), spot_method=which, source="PAINT",
            record_id=rec.record_id))
    return rows, notes
