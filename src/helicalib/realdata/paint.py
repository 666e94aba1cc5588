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


# ---------------------------------------------------------------------------- readers
def read_tower(path: str | Path) -> PaintTower:
    d = json.loads(Path(path).read_text())
    try:
        ref = tuple(float(x) for x in d["power_plant_properties"]["coordinates"])
    except (KeyError, TypeError):
        raise ConfigError(f"{path}: power_plant_properties.coordinates: missing") from None
    targets = {}
    receiver = None
    for name, t in d.items():
        if name == "power_plant_properties" or not isinstance(t, dict):
            continue
        coords = t.get("coordinates", {})
        if t.get("type") == "planar" and all(c in coords for c in CORNERS):
            corners = {c: wgs84_to_enu(coords[c], ref) for c in CORNERS}
            n = np.asarray(t.get("normal_vector", [0, 1, 0]), dtype=float)
            targets[name] = PaintTarget(name, corners, n / np.linalg.norm(n))
        elif name == "receiver" and "center" in coords:
            receiver = wgs84_to_enu(coords["center"], ref)
    return PaintTower(ref, targets, receiver)


def _actuator(a: dict) -> PaintActuator:
    return PaintActuator(
        increment=float(a["increment"]),
        initial_stroke_length=float(a["initial_stroke_length"]),
        offset=float(a["offset"]),
        pivot_radius=float(a["pivot_radius"]),
        initial_angle=float(a["initial_angle"]),
        clockwise_axis_movement=int(a["clockwise_axis_movement"]),
        min_increment=float(a.get("min_increment", 0)),
        max_increment=float(a.get("max_increment", float("inf"))),
        type_axis=str(a.get("type_axis", "linear")),
    )


def read_heliostat_properties(path: str | Path, heliostat_id: str, reference_llh) -> PaintHeliostat:
    d = json.loads(Path(path).read_text())
    k = d["kinematics_properties"]
    pos = wgs84_to_enu(d["heliostat_position"], reference_llh)
    kin = PaintKinematics(
        position_enu_m=tuple(float(x) for x in pos),
        actuators=tuple(_actuator(a) for a in k["actuators"]),
        concentrator_translation=tuple(float(k.get(f"concentrator_translation_{c}", 0.0)) for c in "enu"),
        joint_translation_1=tuple(float(k.get(f"joint_translation_{c}_1", 0.0)) for c in "enu"),
        joint_translation_2=tuple(float(k.get(f"joint_translation_{c}_2", 0.0)) for c in "enu"),
        initial_orientation=tuple(float(x) for x in d.get("initial_orientation", (0.0, -1.0, 0.0))),
    )
    size = (float(d.get("width", JUELICH_MIRROR_SIZE_M[0])), float(d.get("height", JUELICH_MIRROR_SIZE_M[1])))
    return PaintHeliostat(heliostat_id, kin, size, str(path))


def heliostat_number_to_name(number: int | str) -> str:
    """HeliOS numeric id → PAINT name: 10123 → AA23 (row letter, column letter, position)."""
    s = str(number)
    return chr(ord("A") + int(s[0]) - 1) + chr(ord("A") + int(s[1:3]) - 1) + s[3:]


def read_helios_tables(axis_csv: str | Path, positions_csv: str | Path, reference_altitude_m: float) -> list[PaintHeliostat]:
    """HeliOS actuator table (A..E, PulseRatio, AngleK, Reversed) + GK positions → heliostats.

    Column mapping (PAINT's): A = offset_shift, B = initial_stroke_length, C = offset,
    D = pivot_radius, E = radius_shift, PulseRatio = increment, AngleK = initial_angle,
    Reversed = clockwise_axis_movement. Mirror size and concentrator translation are not in
    the tables: the Jülich values (3.22 m × 2.56 m, 0.175 m) are used.
    """
    def rows(p):
        with open(p, newline="", encoding="utf-8-sig") as f:
            return list(csv.DictReader(f))

    axes: dict[str, dict[int, PaintActuator]] = {}
    for r in rows(axis_csv):
        if float(r["A"]) != 0.0 or float(r["E"]) != 0.0:
            raise ConfigError(f"{axis_csv}: heliostat {r['HeliostatId']}: non-zero offset/radius shift is not supported")
        axes.setdefault(r["HeliostatId"], {})[int(r["Number"])] = PaintActuator(
            increment=float(r["PulseRatio"]), initial_stroke_length=float(r["B"]), offset=float(r["C"]),
            pivot_radius=float(r["D"]), initial_angle=float(r["AngleK"]), clockwise_axis_movement=int(r["Reversed"]),
            min_increment=float(r["MinCounts"]), max_increment=float(r["MaxCounts"]), type_axis=r["Type"].lower())
    out = []
    for r in rows(positions_csv):
        hid = r["HeliostatId"]
        if hid not in axes or sorted(axes[hid]) != [1, 2]:
            continue
        pos = gauss_krueger_offset_to_enu(float(r["x"]), float(r["y"]), float(r["z"]), reference_altitude_m)
        kin = PaintKinematics(tuple(float(x) for x in pos), (axes[hid][1], axes[hid][2]),
                              concentrator_translation=JUELICH_CONCENTRATOR_TRANSLATION)
        out.append(PaintHeliostat(heliostat_number_to_name(hid), kin, JUELICH_MIRROR_SIZE_M, f"{axis_csv} + {positions_csv}"))
    return out


_HELIOSTAT_NAME = re.compile(r"^[A-Z]{2}\d{2}$")


def read_calibration(path: str | Path, heliostat_id: str | None = None) -> PaintRecord:
    path = Path(path)
    d = json.loads(path.read_text())
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
    fs = d.get("focal_spot", {})
    return PaintRecord(
        record_id=record_id,
        heliostat_id=heliostat_id,
        motor_steps=(_steps(d["motor_position"]["axis_1_motor_position"]),
                     _steps(d["motor_position"]["axis_2_motor_position"])),
        target_name=str(d["target_name"]),
        sun_azimuth_deg=float(d["sun_azimuth"]),
        sun_elevation_deg=float(d["sun_elevation"]),
        utis_llh=tuple(float(x) for x in fs["UTIS"]) if fs.get("UTIS") else None,
        helios_llh=tuple(float(x) for x in fs["HeliOS"]) if fs.get("HeliOS") else None,
        path=str(path),
        utc_time=_item_datetime(path.with_name(f"{record_id}-calibration-item-stac.json")),
    )


def _steps(value) -> int | float:
    """A motor position: whole steps as an int, a fractional count (helicalib's export of strokes that are
    no whole number of steps) kept as it is rather than truncated."""
    v = float(value)
    return int(v) if v.is_integer() else v


def _layout_heliostat(path: Path, folder: str) -> str | None:
    """PAINT's download layout ``<heliostat>/Calibration/...``, ``<heliostat>/Properties/...``: the heliostat id."""
    return path.parent.parent.name if path.parent.name == folder and path.parent.parent.name else None


def _item_datetime(item: Path) -> str:
    """``properties.datetime`` of a PAINT STAC item (UTC, ISO 8601), or "" when there is no item."""
    if not item.is_file():
        return ""
    when = json.loads(item.read_text()).get("properties", {}).get("datetime")
    return str(when) if when else ""


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
    tower = read_tower(towers[0])
    imp = PaintImport(tower)
    for other in towers[1:]:
        if read_tower(other).reference_llh != tower.reference_llh:
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
            h = read_heliostat_properties(p, hid, tower.reference_llh)
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
            if h.id not in imp.heliostats:
                imp.heliostats[h.id] = h
                imp.notes.append(f"{h.id}: kinematics from the HeliOS tables {axis[0].name}, {positions[0].name} "
                                 f"(mirror size and concentrator translation: Jülich defaults)")

    seen = set()
    for p in files:
        if "calibration-properties" in p.name and p.suffix == ".json":
            rec = read_calibration(p)
            if rec.heliostat_id is None:
                rec = read_calibration(p, id_map.get(rec.record_id))
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
        raise ConfigError("no heliostat properties found (heliostat-properties.json or HeliOS tables)")
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


def observations(imp: PaintImport, which: str = "UTIS") -> tuple[list[Observation], list[str]]:
    """Observation rows for every record whose heliostat and target are known; plus notes on the rest."""
    rows, notes = [], []
    for rec in imp.records:
        h = imp.heliostats.get(rec.heliostat_id)
        t = imp.tower.targets.get(rec.target_name)
        spot = spot_enu(imp, rec, which)
        if h is None or t is None or spot is None:
            notes.append(f"{rec.path}: skipped (heliostat {rec.heliostat_id} known: {h is not None}, "
                         f"target {rec.target_name} known: {t is not None}, {which} spot: {spot is not None})")
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
