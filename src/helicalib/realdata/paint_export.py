"""Write calibration observations in PAINT's layout: the exact inverse of :mod:`helicalib.realdata.paint`.

Pure functions from a field config and observation rows (:class:`helicalib.calibration.observations.Observation`)
to PAINT's JSON documents, plus :class:`PaintWriter` (heliostat by heliostat, for a campaign streamed
from its database) and :func:`write_export` (rows in memory), which lay them out on disk the way PAINT's
download client and ARTIST's loaders expect them::

    OUT/catalog.json                                   STAC catalogue (root), relative links
    OUT/tower-measurements.json                        plant reference + every board's corners (WGS84)
    OUT/tower-measurements-item-stac.json
    OUT/<heliostat>/<heliostat>-calibration-collection-stac.json
    OUT/<heliostat>/Properties/<heliostat>-heliostat-properties.json   position, size, linkage
    OUT/<heliostat>/Calibration/<id>-calibration-properties.json        motor positions, target, spot, sun
    OUT/<heliostat>/Calibration/<id>-calibration-item-stac.json         time, sun, assets
    OUT/<heliostat>/Calibration/<id>-raw.png, <id>-before.png           the record's frames (when given)

Mapping (each the inverse of the importer's, see ``docs/realdata.md``):

* sun: PAINT azimuth ``atan2(e, -n)`` (0 = south, +90 = east), elevation ``atan2(u, hypot(e, n))``;
* motor position ``= stroke_mm · increment / 1000`` (increment in steps per metre of actuator length);
  a whole number of steps is written as an integer, any other count as it is (a plant that reports
  strokes in mm has no whole steps; rounding would lose up to half a step);
* plant ENU → WGS84: Newton iteration on the importer's own exact WGS84 → ENU formula, so that the
  importer gives back the ENU point to rounding (about 1e-9 m);
* board corners ``c ∓ (W/2) u ± (H/2) v`` (left as seen from the field = −u), normal = the board's;
* linkage: a drive whose axis 1 is east, axis 2 ⟂ axis 1 and zero-pose normal ⟂ axis 2 (tilt-roll, and
  every PAINT import) is PAINT's chain exactly: ``offset = arm_fixed_m``, ``pivot_radius =
  arm_moving_m``, ``initial_stroke_length = length_at_zero_stroke_m``, ``clockwise_axis_movement`` 0
  for ``sign`` +1, and the axis offsets folded into ``initial_angle``; ``concentrator_translation_n =
  -mirror_offset_m``. Other drives (azimuth-elevation) have no PAINT linkage and are refused.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from helicalib.calibration.observations import Observation
from helicalib.errors import ConfigError
from helicalib.realdata.geodesy import WGS84_A, WGS84_F, wgs84_to_enu

STAC_VERSION = "1.0.0"
VIEW_EXTENSION = "https://stac-extensions.github.io/view/v1.0.0/schema.json"
MIME_JSON = "application/json"
MIME_GEOJSON = "application/geo+json"
MIME_PNG = "image/png"
DEFAULT_INCREMENT_STEPS_PER_M = 1000.0
"""Steps per metre when neither the drive nor the caller gives one: one step = one millimetre of stroke,
the unit of the field config and of the plant's stroke registers, so motor position = stroke in mm."""
TOWER_FILE = "tower-measurements.json"
CATALOG_FILE = "catalog.json"


# ---------------------------------------------------------------------------- conversions
def enu_to_wgs84(points_enu, reference_llh, tol_m: float = 1e-12, max_iter: int = 10) -> np.ndarray:
    """Plant ENU [m] (..., 3) → WGS84 [lat°, lon°, alt m] (..., 3): the inverse of ``geodesy.wgs84_to_enu``.

    Newton's method on the forward formula itself (the step from the local radii of curvature), so the
    importer's own conversion of the result gives back ``points_enu`` to its rounding.
    """
    pts = np.asarray(points_enu, dtype=float)
    ref = np.asarray(reference_llh, dtype=float)
    llh = np.broadcast_to(ref, pts.shape).copy()
    e2 = WGS84_F * (2.0 - WGS84_F)
    for _ in range(max_iter):
        d = pts - wgs84_to_enu(llh, ref)
        lat = np.radians(llh[..., 0])
        w = np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        n_radius = WGS84_A / w
        m_radius = WGS84_A * (1.0 - e2) / w**3
        llh[..., 0] += np.degrees(d[..., 1] / (m_radius + llh[..., 2]))
        llh[..., 1] += np.degrees(d[..., 0] / ((n_radius + llh[..., 2]) * np.cos(lat)))
        llh[..., 2] += d[..., 2]
        if np.all(np.abs(d) < tol_m):
            break
    return llh


def paint_sun_angles(sun_enu) -> tuple[np.ndarray, np.ndarray]:
    """Unit sun vectors (..., 3) → PAINT's (azimuth°, elevation°): azimuth 0 = south, +90 = east."""
    s = np.asarray(sun_enu, dtype=float)
    az = np.degrees(np.arctan2(s[..., 0], -s[..., 1]))
    el = np.degrees(np.arctan2(s[..., 2], np.hypot(s[..., 0], s[..., 1])))
    return az, el


def north_azimuth_deg(paint_azimuth_deg) -> np.ndarray:
    """PAINT azimuth (0 = south, +90 = east) → azimuth from north, clockwise, in [0, 360) (STAC ``view:``)."""
    return np.mod(180.0 - np.asarray(paint_azimuth_deg, dtype=float), 360.0)


def stroke_to_steps(stroke_mm: float, increment_steps_per_m: float) -> int | float:
    """Stroke [mm] → motor position [steps]; an int when it is a whole number of steps."""
    v = float(stroke_mm) * float(increment_steps_per_m) / 1000.0
    return int(v) if v.is_integer() else v


def _rot_e(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _phi(a, length_m: float) -> float:
    """The actuator triangle's angle at the axis for actuator length ``length_m`` [rad]."""
    o, r = a.arm_fixed_m, a.arm_moving_m
    return math.acos((o * o + r * r - length_m**2) / (2.0 * o * r))


# ---------------------------------------------------------------------------- documents
def heliostat_properties(cfg, heliostat_id: str, increment_steps_per_m: float = DEFAULT_INCREMENT_STEPS_PER_M,
                         tol: float = 1e-9) -> dict:
    """PAINT's ``heliostat-properties.json`` of one heliostat: WGS84 position, size, one flat facet, linkage."""
    h = cfg.heliostat(heliostat_id)
    drive = cfg.drives[h.drive]
    where = f"drives.{h.drive}"
    a1, a2, n0 = drive.axes
    east = np.array([1.0, 0.0, 0.0])
    if np.linalg.norm(a1 - east) > tol:
        raise ConfigError(f"{where}: axis 1 {np.round(a1, 6).tolist()} is not east; PAINT's kinematics turn axis 1 "
                          f"about east, so a {drive.kind} drive has no PAINT linkage")
    if abs(float(a2 @ east)) > tol or abs(float(n0 @ a2)) > tol:
        raise ConfigError(f"{where}: axis 2 must be perpendicular to axis 1 and the zero-pose normal to axis 2 "
                          "for PAINT's kinematics")
    alpha = math.atan2(-a2[1], a2[2])  # a2 = Re(alpha) · up
    w = _rot_e(-alpha) @ n0  # horizontal: = Ru(beta) · (0, -1, 0)
    beta = math.atan2(w[0], -w[1])
    actuators = []
    for k, (a, base) in enumerate(zip(drive.actuators, (alpha + math.pi / 2, beta))):
        # ours: θ = sign (φ(ℓ) - γ0); PAINT: θ_P = θ0 + sign (φ(ℓ) - φ(L0)); θ_P = θ + base (+ π/2 for axis 1)
        gamma0 = math.radians(a.gamma0_deg)
        initial_angle = base + a.sign * (_phi(a, a.length_at_zero_stroke_m) - gamma0)
        lo, hi = a.stroke_range_mm
        actuators.append({
            "type_axis": "linear",
            "min_increment": stroke_to_steps(lo, increment_steps_per_m),
            "max_increment": stroke_to_steps(hi, increment_steps_per_m),
            "increment": float(increment_steps_per_m),
            "offset_shift": 0,
            "initial_stroke_length": float(a.length_at_zero_stroke_m),
            "offset": float(a.arm_fixed_m),
            "pivot_radius": float(a.arm_moving_m),
            "radius_shift": 0,
            "clockwise_axis_movement": 0 if a.sign == 1 else 1,
            "initial_angle": float(initial_angle),
        })
    width, height = drive.mirror_size_m
    kin = {"actuators": actuators}
    for j in (1, 2):
        kin.update({f"joint_translation_{c}_{j}": 0.0 for c in "enu"})
    kin.update({"concentrator_translation_e": 0.0, "concentrator_translation_n": -float(drive.mirror_offset_m),
                "concentrator_translation_u": 0.0})
    ref = reference_llh(cfg)
    return {
        "heliostat_position": enu_to_wgs84(h.position_enu_m, ref).tolist(),
        "height": float(height),
        "width": float(width),
        "initial_orientation": [0.0, -1.0, 0.0],
        "kinematics_properties": kin,
        "facet_properties": {  # no facet data in a field config: one flat facet, the whole mirror
            "canting_type": "flat",
            "number_of_facets": 1,
            "facets": [{"translation_vector": [0.0, 0.0, 0.0], "canting_e": [width / 2, 0.0, 0.0],
                        "canting_n": [0.0, height / 2, 0.0]}],
        },
    }


def reference_llh(cfg) -> tuple[float, float, float]:
    """The plant's WGS84 reference point (the ENU origin): the site's latitude, longitude, altitude."""
    return (float(cfg.site.latitude_deg), float(cfg.site.longitude_deg), float(cfg.site.altitude_m))


def board_corners_enu(target) -> dict[str, np.ndarray]:
    """A board's corners in ENU; PAINT's left/right as seen from the field (left = -u)."""
    u, v, _ = target.frame_enu
    c = np.asarray(target.center_enu_m, dtype=float)
    hw, hh = target.size_m[0] / 2.0, target.size_m[1] / 2.0
    return {"upper_left": c - hw * u + hh * v, "upper_right": c + hw * u + hh * v,
            "lower_right": c + hw * u - hh * v, "lower_left": c - hw * u - hh * v}


def tower_measurements(cfg) -> dict:
    """PAINT's ``tower-measurements.json``: the plant reference, then every board as a planar target area."""
    ref = reference_llh(cfg)
    out: dict = {"power_plant_properties": {"ID": cfg.site.name, "coordinates": list(ref)}}
    for t in cfg.targets:
        corners = board_corners_enu(t)
        coords = {"center": enu_to_wgs84(t.center_enu_m, ref).tolist()}
        coords.update({k: enu_to_wgs84(p, ref).tolist() for k, p in corners.items()})
        out[t.id] = {"type": "planar", "normal_vector": [float(x) for x in t.frame_enu[2]], "coordinates": coords}
    return out


def calibration_properties(obs: Observation, reference, increment_steps_per_m: float) -> dict:
    """PAINT's ``*-calibration-properties.json`` of one observation (the spot centre as ``focal_spot.UTIS``)."""
    az, el = paint_sun_angles(obs.sun_enu)
    return {
        "motor_position": {"axis_1_motor_position": stroke_to_steps(obs.stroke1_mm, increment_steps_per_m),
                           "axis_2_motor_position": stroke_to_steps(obs.stroke2_mm, increment_steps_per_m)},
        "target_name": obs.target_id,
        "focal_spot": {"UTIS": enu_to_wgs84(obs.spot_enu_m, reference).tolist()},
        "sun_elevation": float(el),
        "sun_azimuth": float(az),
    }


def stac_datetime(utc_time: str) -> str:
    """An observation's ISO 8601 time as RFC 3339 UTC (``...Z``), nanoseconds kept."""
    import pandas as pd

    ts = pd.Timestamp(utc_time)
    ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")
    frac = f"{ts.microsecond * 1000 + ts.nanosecond:09d}".rstrip("0")
    return ts.strftime("%Y-%m-%dT%H:%M:%S") + (f".{frac}" if frac else "") + "Z"


def _lonlat(llh) -> list[float]:
    return [float(llh[1]), float(llh[0]), float(llh[2])]


def _bbox(lonlat_points) -> list[float]:
    p = np.asarray(lonlat_points, dtype=float)
    return p.min(axis=0).tolist() + p.max(axis=0).tolist()


def _board_polygon(tower: dict, target_id: str) -> list[list[float]]:
    c = tower[target_id]["coordinates"]
    ring = [_lonlat(c[k]) for k in ("upper_left", "upper_right", "lower_right", "lower_left", "upper_left")]
    return ring


def _link(rel: str, href: str, title: str | None = None, media: str = MIME_JSON) -> dict:
    d = {"rel": rel, "href": href, "type": media}
    if title:
        d["title"] = title
    return d


# ---------------------------------------------------------------------------- the export
@dataclass(frozen=True)
class Frames:
    """Frame files of one record: ``raw`` (the frame with the spot) and ``before`` (the board without it)."""

    raw: Path | None = None
    before: Path | None = None


def record_name(record_id: str) -> str:
    """A record id usable in PAINT's file names (``<id>-calibration-properties.json``; ARTIST takes the
    part before the first ``-`` as the id)."""
    rid = str(record_id).strip()
    if not rid or any(ch in rid for ch in "-/\\ ") or rid in (".", ".."):
        raise ConfigError(f"record_id {rid[:40]!r}: PAINT needs a record id without '-', '/', spaces")
    return rid


def heliostat_name(heliostat_id: str) -> str:
    """A heliostat id usable as PAINT's folder and file-name prefix (``<id>/Properties/<id>-heliostat-
    properties.json``; PAINT's readers take the part before the first ``-``): no '-', no path
    separator, no space, not starting with a dot (it must stay inside the export)."""
    hid = str(heliostat_id)
    if not hid or hid.startswith(".") or any(ch in hid for ch in "-/\\ ") or hid != hid.strip():
        raise ConfigError(f"heliostat {hid[:40]!r}: PAINT needs an id without '-', '/', '\\', spaces or a "
                          "leading dot (it names the heliostat's folder and files)")
    return hid


def write_export(cfg, rows: Sequence[Observation], out_dir: str | Path, *,
                 frames: Mapping[str, Frames] | None = None,
                 increment_steps_per_m: float = DEFAULT_INCREMENT_STEPS_PER_M,
                 description: str = "helicalib calibration records", progress=None) -> dict:
    """Write ``rows`` (observations of heliostats of ``cfg``) in PAINT's layout with a STAC catalogue.

    ``frames`` maps a record id to its frame files (copied as ``<id>-raw.png`` / ``<id>-before.png``).
    ``progress(done, total)`` is called after each heliostat. Returns a summary (files, counts).
    All rows in memory: a campaign database streams through :class:`PaintWriter` instead.
    """
    frames = frames or {}
    writer = PaintWriter(cfg, out_dir, increment_steps_per_m=increment_steps_per_m, description=description)
    by_heliostat: dict[str, list[Observation]] = {}
    for r in rows:
        writer.check(r)
        by_heliostat.setdefault(heliostat_name(r.heliostat_id), []).append(r)
    done, total = 0, len(rows)
    for hid, recs in sorted(by_heliostat.items()):
        writer.write_heliostat(hid, recs, frames, checked=True)
        done += len(recs)
        if progress is not None:
            progress(done, total)
    return writer.finish()


class PaintWriter:
    """Writes a PAINT export heliostat by heliostat: at most one heliostat's records in memory.

    Give each heliostat's records once, heliostats in id order (the catalogue lists them in the order
    given), then call :meth:`finish` (the catalogue and the tower item with the records' time span).
    """

    def __init__(self, cfg, out_dir: str | Path, *, increment_steps_per_m: float = DEFAULT_INCREMENT_STEPS_PER_M,
                 description: str = "helicalib calibration records"):
        if not (math.isfinite(increment_steps_per_m) and increment_steps_per_m > 0):
            raise ConfigError(f"increment {increment_steps_per_m}: expected a positive number of steps per metre")
        self.cfg, self.increment, self.description = cfg, float(increment_steps_per_m), description
        self.out = Path(out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.ref = reference_llh(cfg)
        self.targets = {t.id for t in cfg.targets}
        self.tower = tower_measurements(cfg)
        self.catalog_links = [_link("self", f"./{CATALOG_FILE}"), _link("root", f"./{CATALOG_FILE}"),
                              _link("item", "./tower-measurements-item-stac.json", "Tower measurements")]
        self.counts: dict[str, int] = {}
        self.records = self.with_frames = 0
        self._seen: set[str] = set()
        self._times = None, None

    def check(self, r: Observation) -> str:
        """A record's PAINT name, after checking that it is new, its board and its heliostat are the field's."""
        rid = record_name(r.record_id)
        if rid in self._seen:
            raise ConfigError(f"record_id {rid}: appears twice; PAINT's file names need unique record ids")
        self._seen.add(rid)
        if r.target_id not in self.targets:
            raise ConfigError(f"record {rid}: target_id {r.target_id!r}: not a target of the field config")
        self.cfg.heliostat(r.heliostat_id)
        return rid

    def write_heliostat(self, hid: str, recs: Sequence[Observation], frames: Mapping[str, Frames] | None = None,
                        checked: bool = False) -> int:
        """Write one heliostat's properties, records (with their frames) and collection; returns the count."""
        if not checked:
            for r in recs:
                self.check(r)
        hid = heliostat_name(hid)
        frames = frames or {}
        hdir = self.out / hid
        (hdir / "Calibration").mkdir(parents=True, exist_ok=True)
        (hdir / "Properties").mkdir(parents=True, exist_ok=True)
        props_name = f"{hid}-heliostat-properties.json"
        _write_json(hdir / "Properties" / props_name, heliostat_properties(self.cfg, hid, self.increment))
        coll_id = f"{hid}-calibration-collection"
        coll_file = f"{coll_id}-stac.json"
        item_links = []
        for r in recs:
            rid = record_name(r.record_id)
            fr = frames.get(rid)
            _write_calibration_record(hdir / "Calibration", r, rid, coll_id, coll_file, self.tower, self.ref,
                                      self.increment, fr)
            item_links.append(_link("item", f"./Calibration/{rid}-calibration-item-stac.json", media=MIME_GEOJSON))
            self.with_frames += _has_frames(fr)
        az, el = paint_sun_angles(np.array([r.sun_enu for r in recs]))
        boards = sorted({r.target_id for r in recs})
        span = _time_range(recs)
        self._times = tuple(_extreme(a, b, pick) for a, b, pick in zip(self._times, span, (min, max)))
        collection = {
            "type": "Collection", "stac_version": STAC_VERSION, "stac_extensions": [],
            "id": coll_id, "title": f"Calibration records of heliostat {hid}",
            "description": f"{self.description}: {len(recs)} calibration records of heliostat {hid}",
            "license": "other",
            "extent": {"spatial": {"bbox": [_bbox([p for b in boards for p in _board_polygon(self.tower, b)])]},
                       "temporal": {"interval": [span]}},
            "summaries": {"view:sun_azimuth": {"minimum": float(north_azimuth_deg(az).min()),
                                               "maximum": float(north_azimuth_deg(az).max())},
                          "view:sun_elevation": {"minimum": float(el.min()), "maximum": float(el.max())},
                          "target_name": boards},
            "links": [_link("self", f"./{coll_file}"), _link("root", f"../{CATALOG_FILE}"),
                      _link("parent", f"../{CATALOG_FILE}")] + item_links,
            "assets": {"heliostat_properties": {"href": f"./Properties/{props_name}", "type": MIME_JSON,
                                                "roles": ["metadata"],
                                                "title": f"Position, size and kinematics of {hid}"}},
        }
        _write_json(hdir / coll_file, collection)
        self.catalog_links.append(_link("child", f"./{hid}/{coll_file}", f"Heliostat {hid}"))
        self.counts[hid] = self.counts.get(hid, 0) + len(recs)
        self.records += len(recs)
        return len(recs)

    def finish(self) -> dict:
        """Write the tower item and the catalogue; returns the export's summary (files, counts)."""
        out, ref = self.out, self.ref
        _write_json(out / TOWER_FILE, self.tower)
        tower_item = {
            "type": "Feature", "stac_version": STAC_VERSION, "stac_extensions": [],
            "id": "tower-measurements",
            "geometry": {"type": "Point", "coordinates": _lonlat(ref)}, "bbox": _bbox([_lonlat(ref)]),
            "properties": {"datetime": None, "start_datetime": self._times[0], "end_datetime": self._times[1],
                           "title": f"Targets of {self.cfg.site.name}"},
            "links": [_link("self", "./tower-measurements-item-stac.json"), _link("root", f"./{CATALOG_FILE}"),
                      _link("parent", f"./{CATALOG_FILE}")],
            "assets": {"tower_measurements": {"href": f"./{TOWER_FILE}", "type": MIME_JSON, "roles": ["metadata"],
                                              "title": "Plant reference and target corners (WGS84)"}},
        }
        _write_json(out / "tower-measurements-item-stac.json", tower_item)
        _write_json(out / CATALOG_FILE, {
            "type": "Catalog", "stac_version": STAC_VERSION, "stac_extensions": [],
            "id": "helicalib-paint-export", "title": f"{self.cfg.site.name}: calibration records",
            "description": f"{self.description}, in PAINT's layout (tower-measurements.json, per heliostat "
                           "Properties/ and Calibration/)",
            "links": self.catalog_links,
        })
        return {"out": str(out), "catalog": str(out / CATALOG_FILE), "tower_measurements": str(out / TOWER_FILE),
                "records": self.records, "heliostats": dict(self.counts), "increment_steps_per_m": self.increment,
                "frames": self.with_frames}


def _extreme(a: str | None, b: str | None, pick) -> str | None:
    """The earlier (``min``) or later (``max``) of two RFC 3339 UTC times, either may be None."""
    if a is None or b is None:
        return b if a is None else a
    import pandas as pd

    return a if pick(pd.Timestamp(a), pd.Timestamp(b)) == pd.Timestamp(a) else b


def _has_frames(fr: Frames | None) -> bool:
    return fr is not None and (fr.raw is not None or fr.before is not None)


def _write_calibration_record(folder: Path, r: Observation, rid: str, coll_id: str, coll_file: str, tower: dict,
                              ref, increment: float, fr: Frames | None) -> None:
    _write_json(folder / f"{rid}-calibration-properties.json", calibration_properties(r, ref, increment))
    assets = {"calibration_properties": {"href": f"./{rid}-calibration-properties.json", "type": MIME_JSON,
                                         "roles": ["metadata"],
                                         "title": f"Motor positions, target, focal spot and sun of record {rid}"}}
    for kind, src, title in (("raw_image", fr.raw if fr else None, "Camera frame with the focal spot"),
                             ("before_image", fr.before if fr else None, "Camera frame of the board without the spot")):
        if src is None:
            continue
        name = f"{rid}-{'raw' if kind == 'raw_image' else 'before'}.png"
        shutil.copyfile(src, folder / name)
        assets[kind] = {"href": f"./{name}", "type": MIME_PNG, "roles": ["data"], "title": title}
    az, el = paint_sun_angles(r.sun_enu)
    polygon = _board_polygon(tower, r.target_id)
    item = {
        "type": "Feature", "stac_version": STAC_VERSION, "stac_extensions": [VIEW_EXTENSION],
        "id": rid, "collection": coll_id,
        "geometry": {"type": "Polygon", "coordinates": [polygon]}, "bbox": _bbox(polygon),
        "properties": {
            "datetime": stac_datetime(r.utc_time) if r.utc_time else None,
            "view:sun_azimuth": float(north_azimuth_deg(az)),  # STAC: from north, clockwise
            "view:sun_elevation": float(el),
            "heliostat_id": r.heliostat_id, "target_name": r.target_id,
            "spot_method": r.spot_method, "source": r.source,
        },
        "links": [_link("self", f"./{rid}-calibration-item-stac.json", media=MIME_GEOJSON),
                  _link("root", f"../../{CATALOG_FILE}"), _link("parent", f"../{coll_file}"),
                  _link("collection", f"../{coll_file}")],
        "assets": assets,
    }
    _write_json(folder / f"{rid}-calibration-item-stac.json", item)


def _time_range(rows) -> list[str | None]:
    """[first, last] observation time as RFC 3339 (None when no row has a time)."""
    import pandas as pd

    times = [pd.Timestamp(r.utc_time) for r in rows if r.utc_time]
    return [stac_datetime(min(times).isoformat()), stac_datetime(max(times).isoformat())] if times else [None, None]


def _write_json(path: Path, data) -> None:
    path.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n")
