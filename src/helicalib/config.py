"""Field config (``../shared/FIELD_CONFIG.md``, version 1) → frozen, validated objects.

``load_field_config(path)`` reads the YAML (and ``heliostats_csv`` beside it), validates every key
with pydantic and checks the cross references. Any problem raises :class:`ConfigError` whose
``problems`` are one line each, ``FILE: key.path[3].name: what is wrong``.

helicalib's own optional keys (documented in ``docs/field-config.md``) are declared here too;
any other key is refused.
"""

from __future__ import annotations

import csv
import functools
import math
import re
import types
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import numpy as np
import yaml
from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, PrivateAttr, Tag,
                      ValidationError, field_validator, model_validator)

from helicalib.errors import ConfigError, HelicalibError

UNIT_TOLERANCE = 1e-3
"""A given unit vector may differ from length 1 by this much; it is then normalised exactly."""


# ---------------------------------------------------------------------------- value types
def _numbers(n: int):
    def check(value: Any) -> tuple[float, ...]:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != n:
            raise ValueError(f"expected {n} numbers")
        out = []
        for item in value:
            if isinstance(item, bool) or not isinstance(item, (int, float)) or not _finite(item):
                raise ValueError(f"expected {n} finite numbers, got {_short(item)}")
            out.append(float(item))
        return tuple(out)

    return BeforeValidator(check)


def _finite(x: int | float) -> bool:
    try:
        return math.isfinite(x)
    except OverflowError:  # an int too large for a float
        return False


def _short(value: Any, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters, for one-line messages about arbitrary input."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


MAX_ID_LENGTH = 64
"""Longest heliostat, target, camera id or drive name (PAINT's ``AA39``, ``H00001``, ``solar_tower_juelich_upper``)."""
ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
"""An id: ASCII letters, digits, ``.``, ``_`` and ``-``, starting with a letter or digit (no markup,
no path separators, no spaces: an id is shown on every screen and names files)."""
MAX_NAME_LENGTH = 200
"""Longest free-text name (``site.name``) in characters."""


def _safe_id(value: str) -> str:
    if not value:
        raise ValueError("expected a non-empty id")
    if len(value) > MAX_ID_LENGTH:
        raise ValueError(f"an id of {len(value)} characters: at most {MAX_ID_LENGTH}")
    if not ID_PATTERN.fullmatch(value):
        raise ValueError(f"{_short(value)}: an id holds only the letters A-Z and a-z, digits, '.', '_' and '-', "
                         "and starts with a letter or digit")
    return value


def _plain_name(value: str) -> str:
    if not value.strip():
        raise ValueError("expected a non-empty name")
    if len(value) > MAX_NAME_LENGTH:
        raise ValueError(f"a name of {len(value)} characters: at most {MAX_NAME_LENGTH}")
    if not value.isprintable():
        bad = next(c for c in value if not c.isprintable())
        raise ValueError(f"expected printable text, got the control or format character U+{ord(bad):04X}")
    return value


Id = Annotated[str, AfterValidator(_safe_id)]
Name = Annotated[str, AfterValidator(_plain_name)]


def _unit(value: tuple[float, ...]) -> tuple[float, ...]:
    norm = math.sqrt(sum(x * x for x in value))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise ValueError(f"expected a unit vector, length is {norm:.6g}")
    return tuple(x / norm for x in value)


def _nonzero_normalised(value: tuple[float, ...]) -> tuple[float, ...]:
    norm = math.sqrt(sum(x * x for x in value))
    if norm < 1e-9:
        raise ValueError("expected a non-zero vector")
    return tuple(x / norm for x in value)


Vec2 = Annotated[tuple[float, float], _numbers(2)]
Vec3 = Annotated[tuple[float, float, float], _numbers(3)]
PositiveFloat = Annotated[float, Field(gt=0)]

# Physical bounds of every dimension (docs/field-config.md, "Bounds"): beyond them a value is a typing
# error, and numbers such as 1e308 would overflow the geometry or the plant's clocks downstream.
MAX_MIRROR_SIDE_M = 50.0
"""Largest mirror side [m] (the largest heliostats built are about 12 m across)."""
MAX_BOARD_SIDE_M = 100.0
"""Largest calibration board side [m] (tower boards are some 8-15 m)."""
MAX_ARM_M = 20.0
"""Largest actuator triangle arm [m]."""
MAX_ACTUATOR_LENGTH_M = 50.0
"""Largest actuator length at zero stroke [m]."""
MAX_STROKE_MM = 100_000.0
"""Largest stroke magnitude [mm] (100 m)."""
MAX_STANDBY_OFFSET_M = 1000.0
"""Largest standby offset from the board centre [m]."""
MAX_TIMEOUT_S = 300.0
"""Longest Modbus request timeout [s]."""
MAX_MRAD = 1000.0
"""Largest angle threshold or limit [mrad] (1 rad)."""
MAX_WIND_MS = 100.0
"""Largest wind speed limit [m/s]."""
MAX_DNI_WM2 = 2000.0
"""Largest irradiance limit [W/m²] (the solar constant is 1361)."""
MAX_FOCAL_PX = 1e6
"""Largest focal length or principal-point coordinate [px]."""
MAX_DISTORTION = 1000.0
"""Largest magnitude of a lens distortion coefficient."""


def _at_most(limit: float, unit: str):
    """A check that every number of a tuple lies within ±``limit``."""
    def check(value: tuple[float, ...]) -> tuple[float, ...]:
        for k, x in enumerate(value):
            if abs(x) > limit:
                raise ValueError(f"[{k}] {x:g}{unit} is beyond the physical bound of {limit:g}{unit}")
        return value

    return AfterValidator(check)


def Side(limit: float):  # noqa: N802 - a type
    """A positive number at most ``limit`` (a length, a duration, a threshold)."""
    return Annotated[float, Field(gt=0, le=limit)]

MAX_COORDINATE_M = 100_000.0
"""Largest plant coordinate [m] (ENU): a field of 100 km is none; larger numbers are typing errors."""


def _in_plant(value: tuple[float, ...]) -> tuple[float, ...]:
    if any(abs(x) > MAX_COORDINATE_M for x in value):
        raise ValueError(f"coordinates beyond {MAX_COORDINATE_M:g} m from the tower: {value}")
    return value


PointENU = Annotated[Vec3, AfterValidator(_in_plant)]


_FRAMES: dict[tuple[float, ...], np.ndarray] = {}
"""Target frames by board normal (:attr:`Target.frame_enu`), computed once."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _numbers_are_numbers(cls, value: Any, info):
        # pydantic's lax mode reads true as 1 and "40" as 40.0: a number is written as a number
        if isinstance(value, (bool, str, bytes)) and _wants_number(cls.model_fields[info.field_name].annotation):
            raise ValueError(f"expected a number, got {_short(value)}")
        return value


@functools.lru_cache(maxsize=None)
def _wants_number(annotation: Any) -> bool:
    """Whether a field of this type takes a number and neither a bool nor a string."""
    args = get_args(annotation) if get_origin(annotation) in (Union, types.UnionType) else (annotation,)
    kinds: set[Any] = set()
    for a in args:
        kinds |= {type(x) for x in get_args(a)} if get_origin(a) is Literal else {a}
    return bool(kinds & {int, float}) and not kinds & {bool, str}


# ---------------------------------------------------------------------------- sections
class Site(_Model):
    name: Name
    latitude_deg: float = Field(ge=-90, le=90)
    longitude_deg: float = Field(ge=-180, le=180)
    altitude_m: float = Field(ge=-1000, le=10000)
    pressure_hpa: float | None = Field(default=None, gt=0, le=2000)
    temperature_c: float = Field(default=12.0, ge=-100, le=100)

    @property
    def pressure_hpa_effective(self) -> float:
        """``pressure_hpa`` or, when absent, the standard atmosphere at ``altitude_m`` [hPa]."""
        if self.pressure_hpa is not None:
            return self.pressure_hpa
        from pvlib.atmosphere import alt2pres

        return float(alt2pres(self.altitude_m)) / 100.0


class Tower(_Model):
    receiver_aim_enu_m: PointENU


_CORNERS = (("TL", -1, 1), ("TR", 1, 1), ("BR", 1, -1), ("BL", -1, -1))


class Marks(_Model):
    """T/GRLM 02-2014 annex A.1: four black right-angle (L) marks, ``kind: right-angles`` (the default)."""

    kind: Literal["right-angles"] = "right-angles"
    vertices_m: tuple[Vec2, Vec2, Vec2, Vec2]
    arm_m: PositiveFloat
    thickness_m: PositiveFloat

    @field_validator("vertices_m")
    @classmethod
    def _quadrilateral(cls, value):
        # each L's arms run toward the board centre (vision.marks.mark_model_m), so vertex k must lie in
        # its own quadrant; four marks that are identical, collinear or out of order make no homography
        for k in range(4):
            for j in range(k):
                if value[j] == value[k]:
                    raise ValueError(f"vertices [{j}] and [{k}] are the same point ({value[k][0]:g}, {value[k][1]:g}); "
                                     "four distinct marks (TL, TR, BR, BL) are needed for the board's homography")
        for k, ((name, su, sv), (u, v)) in enumerate(zip(_CORNERS, value)):
            if not (u * su > 0 and v * sv > 0):
                raise ValueError(f"vertex [{k}] ({u:g}, {v:g}) is not the {name} mark: expected the vertices TL, TR, BR, BL, "
                                 f"each in its own quadrant of the board (u {'<' if su < 0 else '>'} 0, "
                                 f"v {'<' if sv < 0 else '>'} 0)")
        pts = np.asarray(value, dtype=float)
        pts = pts / np.max(np.abs(pts))  # > 0: every vertex lies in its quadrant
        for k in range(4):
            a, b, c = pts[k - 1], pts[k], pts[(k + 1) % 4]
            turn = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
            if not turn < -1e-6:  # clockwise with v up, strictly convex
                raise ValueError(f"vertex [{k}]: the four vertices make no convex quadrilateral (three nearly in a line); "
                                 "they cannot define the board's homography")
        return value

    @field_validator("arm_m")
    @classmethod
    def _arm_fits(cls, value: float, info):
        vertices = info.data.get("vertices_m")
        if vertices is not None:
            room = min(min(abs(u), abs(v)) for u, v in vertices)
            if value > room:
                raise ValueError(f"{value:g} m: longer than the {room:g} m from a vertex to the board's centre line; "
                                 "the marks' arms would overlap")
        return value

    @field_validator("thickness_m")
    @classmethod
    def _thinner_than_arm(cls, value: float, info):
        arm = info.data.get("arm_m")
        if arm is not None and value >= arm:
            raise ValueError(f"must be smaller than arm_m ({arm})")
        return value


DOT_POSITIONS: dict[str, tuple[int, int]] = {
    "top-left": (-1, 1), "top": (0, 1), "top-right": (1, 1),
    "left": (-1, 0), "centre": (0, 0), "right": (1, 0),
    "bottom-left": (-1, -1), "bottom": (0, -1), "bottom-right": (1, -1)}
"""The nine dots of a 田 board by name → (column, row) in pitches, u to the right, v up."""


class DotMarks(_Model):
    """Nine round dots of two sizes in a 3 × 3 (田) grid, ``kind: dots`` (the 2019 calibration article).

    ``layout`` gives the rows top to bottom, left to right, ``L`` large and ``s`` small; the dot named
    by ``reference`` is the reference measuring point and lies at the board centre (u, v) = (0, 0),
    the grid around it.
    """

    kind: Literal["dots"]
    large_diameter_m: PositiveFloat = 1.7
    small_diameter_m: PositiveFloat = 0.85
    layout: tuple[str, str, str] = ("LsL", "sLs", "LsL")
    reference: Literal["top-left", "top", "top-right", "left", "centre", "right", "bottom-left", "bottom",
                       "bottom-right"] = "centre"
    pitch_m: PositiveFloat = 4.25  # after the sizes and layout: its check needs them

    @field_validator("layout")
    @classmethod
    def _rows(cls, value):
        for i, row in enumerate(value):
            if len(row) != 3 or set(row) - {"L", "s"}:
                raise ValueError(f"row [{i}] {_short(row)}: expected three letters, L (large dot) or s (small dot), "
                                 "e.g. [LsL, sLs, LsL]")
        return value

    @field_validator("small_diameter_m")
    @classmethod
    def _smaller(cls, value: float, info):
        large = info.data.get("large_diameter_m")
        if large is not None and value > large:
            raise ValueError(f"{value:g} m is larger than large_diameter_m ({large:g} m)")
        return value

    @field_validator("pitch_m")
    @classmethod
    def _apart(cls, value: float, info):
        # neighbours along a row or column at least a quarter of a large dot apart, so the finder separates them
        large, small, layout = (info.data.get(k) for k in ("large_diameter_m", "small_diameter_m", "layout"))
        if None in (large, small, layout):
            return value
        d = np.array([[large if c == "L" else small for c in row] for row in layout])
        widest = max(float(np.max(d[:, :-1] + d[:, 1:])), float(np.max(d[:-1, :] + d[1:, :]))) / 2
        if value - widest < 0.25 * large:
            raise ValueError(f"{value:g} m leaves neighbouring dots less than a quarter of a large dot apart "
                             f"(needs at least {widest + 0.25 * large:g} m)")
        return value

    def dots_m(self) -> np.ndarray:
        """Dot centres (9, 2) [m, target frame], rows top to bottom, each left to right."""
        ref = np.array(DOT_POSITIONS[self.reference], dtype=float)
        cols, rows = np.meshgrid([-1.0, 0.0, 1.0], [1.0, 0.0, -1.0])
        return (np.column_stack([cols.ravel(), rows.ravel()]) - ref) * self.pitch_m

    def diameters_m(self) -> np.ndarray:
        """Dot diameters (9,) [m], in the order of :meth:`dots_m`."""
        return np.array([self.large_diameter_m if c == "L" else self.small_diameter_m for row in self.layout
                         for c in row])


def _marks_kind(value: Any) -> str:
    kind = value.get("kind", "right-angles") if isinstance(value, Mapping) else getattr(value, "kind", None)
    return f"kind={kind}" if isinstance(kind, str) else "kind=?"


AnyMarks = Annotated[Annotated[Marks, Tag("kind=right-angles")] | Annotated[DotMarks, Tag("kind=dots")],
                     Discriminator(_marks_kind, custom_error_type="marks_kind",
                                   custom_error_message="kind: expected right-angles (the default) or dots")]
"""``marks`` of a target: the kind is told by ``kind`` (absent: right-angles, T/GRLM's four L marks)."""


class Target(_Model):
    id: Id
    center_enu_m: PointENU
    normal_enu: Vec3
    size_m: Annotated[tuple[Side(MAX_BOARD_SIDE_M), Side(MAX_BOARD_SIDE_M)], _numbers(2)]
    standby_offset_m: Annotated[tuple[float, ...], BeforeValidator(lambda v: _standby(v)),
                                _at_most(MAX_STANDBY_OFFSET_M, " m")] | None = None
    marks: AnyMarks | None = None

    _normal = field_validator("normal_enu")(classmethod(lambda cls, v: _unit(v)))

    @field_validator("marks")
    @classmethod
    def _marks_on_board(cls, value, info):
        size = info.data.get("size_m")
        if isinstance(value, DotMarks) and size is not None:
            dots, radii = value.dots_m(), value.diameters_m() / 2
            for (u, v), r, name in zip(dots, radii, DOT_POSITIONS):
                if abs(u) + r > size[0] / 2 + 1e-9 or abs(v) + r > size[1] / 2 + 1e-9:
                    raise ValueError(f"the {name} dot (centre ({u:g}, {v:g}) m, diameter {2 * r:g} m) runs off the "
                                     f"{size[0]:g} x {size[1]:g} m board; a smaller pitch_m or a larger board")
        elif value is not None and size is not None:
            for k, (u, v) in enumerate(value.vertices_m):
                if abs(u) > size[0] / 2 + 1e-9 or abs(v) > size[1] / 2 + 1e-9:
                    raise ValueError(f"vertices_m[{k}] ({u:g}, {v:g}) lies off the {size[0]:g} x {size[1]:g} m board")
        return value

    @field_validator("standby_offset_m")
    @classmethod
    def _standby_off_board(cls, value, info):
        size = info.data.get("size_m")
        if value is not None and size is not None:
            if abs(value[0]) <= size[0] / 2 and abs(value[1]) <= size[1] / 2:
                raise ValueError("the standby point lies on the board; it must keep the waiting beam off it")
        return value

    # -- derived geometry -------------------------------------------------------------
    @property
    def frame_enu(self) -> np.ndarray:
        """Rows u, v, w of the target frame in ENU, shape (3, 3).

        u = unit(z_up × normal) (right as seen from the field), v = normal × u (up the board),
        w = normal (toward the field). Computed once per target (read-only; a visit converts
        points through it several times per measurement).
        """
        key = tuple(float(x) for x in self.normal_enu)
        frame = _FRAMES.get(key)
        if frame is None:
            w = np.asarray(self.normal_enu)
            u = np.cross([0.0, 0.0, 1.0], w)
            if np.linalg.norm(u) < 1e-9:  # horizontal board (normal up): u = east by convention
                u = np.array([1.0, 0.0, 0.0])
            u = u / np.linalg.norm(u)
            v = np.cross(w, u)
            frame = np.stack([u, v, w])
            frame.setflags(write=False)
            if len(_FRAMES) > 4096:
                _FRAMES.clear()
            _FRAMES[key] = frame
        return frame

    @property
    def standby_uvw_m(self) -> tuple[float, float, float]:
        """The standby point in the target frame (u, v, w) [m]; the default lies beside the board."""
        if self.standby_offset_m is not None:
            s = tuple(self.standby_offset_m) + (0.0,) * (3 - len(self.standby_offset_m))
            return (float(s[0]), float(s[1]), float(s[2]))
        width = self.size_m[0]
        return (-(width / 2 + max(width / 2, 6.0)), 0.0, 0.0)

    def uvw_to_enu(self, uvw_m: np.ndarray) -> np.ndarray:
        """Target-frame points (..., 2 or 3) [m] → ENU points (..., 3) [m]."""
        uvw = np.asarray(uvw_m, dtype=float)
        if uvw.shape[-1] == 2:
            uvw = np.concatenate([uvw, np.zeros(uvw.shape[:-1] + (1,))], axis=-1)
        return np.asarray(self.center_enu_m) + uvw @ self.frame_enu

    def enu_to_uvw(self, enu_m: np.ndarray) -> np.ndarray:
        """ENU points (..., 3) [m] → target-frame (u, v, w) (..., 3) [m]."""
        return (np.asarray(enu_m, dtype=float) - np.asarray(self.center_enu_m)) @ self.frame_enu.T


def _standby(value: Any) -> tuple[float, ...]:
    if isinstance(value, Sequence) and not isinstance(value, str) and len(value) in (2, 3):
        return _numbers(len(value)).func(value)
    raise ValueError("expected 2 or 3 numbers (u, v[, w])")


class Intrinsics(_Model):
    fx: Side(MAX_FOCAL_PX)
    fy: Side(MAX_FOCAL_PX)
    cx: float = Field(ge=-MAX_FOCAL_PX, le=MAX_FOCAL_PX)
    cy: float = Field(ge=-MAX_FOCAL_PX, le=MAX_FOCAL_PX)


MAX_FRAME_SIDE_PX = 20000
"""Largest frame side a camera may give [px] (a 150-megapixel back is 14204 px wide)."""


class GenICam(_Model):
    """A GenICam camera's producer and feature names (``cameras[].genicam``)."""

    cti: str | None = None               # the GenTL producer (.cti); default: $GENICAM_GENTL64_PATH
    exposure_feature: str = "ExposureTime"   # SFNC: microseconds
    gain_feature: str = "Gain"


class Camera(_Model):
    id: Id
    target: str
    url: str
    intrinsics: Intrinsics | None = None
    distortion: Annotated[tuple[float, ...], BeforeValidator(lambda v: _distortion(v)),
                          _at_most(MAX_DISTORTION, "")] | None = None
    # helicalib's own optional keys: where the camera stands and its frame size (the simulated
    # plant renders from them; a real camera's frames say their own size)
    position_enu_m: PointENU | None = None
    resolution_px: Annotated[tuple[int, int], _numbers(2), BeforeValidator(lambda v: v)] = (1280, 1024)
    # helicalib's own optional key: the camera's FLUX.yaml (docs/flux.md), relative to the field
    # config; its Fe turns the camera into a flux meter (cleanliness measured at every valid visit)
    flux_calibration: str | None = None
    # helicalib's own optional keys: the kind of camera (docs/plant-interface.md, "Cameras").
    # http: PLANT_INTERFACE.md's snapshot camera at url; stream: an RTSP or HTTP MJPEG stream at url,
    # whose exposure (when it has one to set) is set at exposure_url; genicam: a GigE Vision / USB3
    # Vision camera through a GenTL producer (url genicam://<serial>, the extra helicalib[genicam])
    kind: Literal["http", "stream", "genicam"] = "http"
    exposure_url: str | None = None
    genicam: GenICam | None = None
    # a stream or GenICam camera's delay from exposure to arrival [ms]: its frames' capture time is
    # their arrival less this (measure it once: docs/cameras.md); an HTTP camera says its own time
    latency_ms: float = Field(default=0.0, ge=0, le=10000)

    @field_validator("resolution_px")
    @classmethod
    def _pixels(cls, value):
        w, h = value
        if w != int(w) or h != int(h) or not (64 <= w <= MAX_FRAME_SIDE_PX and 64 <= h <= MAX_FRAME_SIDE_PX):
            raise ValueError(f"expected two whole numbers in 64..{MAX_FRAME_SIDE_PX} (width, height)")
        return (int(w), int(h))

    @property
    def camera_matrix(self) -> np.ndarray | None:
        if self.intrinsics is None:
            return None
        k = self.intrinsics
        return np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])


def _distortion(value: Any) -> tuple[float, ...]:
    if isinstance(value, Sequence) and not isinstance(value, str) and len(value) in (4, 5, 8):
        return _numbers(len(value)).func(value)
    raise ValueError("expected 4, 5 or 8 numbers (OpenCV order k1 k2 p1 p2 [k3 ...])")


class Actuator(_Model):
    arm_fixed_m: Side(MAX_ARM_M)
    arm_moving_m: Side(MAX_ARM_M)
    gamma0_deg: float = Field(ge=-360, le=360)  # γ at θ = 0; may lie outside (0, 180) if the operating γ stays inside
    sign: Literal[1, -1]
    length_at_zero_stroke_m: Side(MAX_ACTUATOR_LENGTH_M)
    stroke_range_mm: Annotated[tuple[float, float], _numbers(2), _at_most(MAX_STROKE_MM, " mm")]

    @field_validator("stroke_range_mm")
    @classmethod
    def _ordered(cls, value):
        if not value[0] < value[1]:
            raise ValueError(f"stroke range is reversed or empty: [{value[0]}, {value[1]}]; expected [min, max]")
        return value


DriveKind = Literal["azimuth-elevation", "tilt-roll", "custom"]

PRESETS: dict[str, tuple[tuple[float, float, float], ...]] = {
    "azimuth-elevation": ((0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "tilt-roll": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
}


class Drive(_Model):
    kind: DriveKind
    mirror_offset_m: float = Field(ge=-10, le=10)
    mirror_size_m: Annotated[tuple[Side(MAX_MIRROR_SIDE_M), Side(MAX_MIRROR_SIDE_M)], _numbers(2)]
    actuators: tuple[Actuator, Actuator]
    axis1_enu: Vec3 | None = None
    axis2_enu: Vec3 | None = None
    normal0_enu: Vec3 | None = None

    _norm = field_validator("axis1_enu", "axis2_enu", "normal0_enu")(
        classmethod(lambda cls, v: None if v is None else _nonzero_normalised(v))
    )

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a1, a2, n0) as unit vectors in ENU, from the preset or the custom keys."""
        if self.kind == "custom":
            return tuple(np.asarray(x, dtype=float) for x in (self.axis1_enu, self.axis2_enu, self.normal0_enu))
        return tuple(np.asarray(x, dtype=float) for x in PRESETS[self.kind])


class Heliostat(_Model):
    id: Id
    position_enu_m: PointENU
    drive: str
    target: str


class Endpoint(_Model):
    host: str = Field(min_length=1, max_length=253)
    port: int = Field(ge=1, le=65535)
    unit: int = Field(default=1, ge=0, le=255)
    timeout_s: Side(MAX_TIMEOUT_S) = 2.0


OPCUA_POLICIES = ("None", "Basic256Sha256", "Aes128Sha256RsaOaep", "Aes256Sha256RsaPss")
"""OPC UA security policies the client offers (asyncua's names)."""


class OpcUa(_Model):
    """helicalib's own optional key ``plant.opcua``: an SCS that speaks OPC UA (docs/plant-interface.md)."""

    endpoint: str = Field(min_length=1, max_length=1000)   # opc.tcp://host:port/path
    node_map: str | None = None          # a node-map YAML (relative to the field config) or a shipped map's name
    security_policy: Literal[OPCUA_POLICIES] = "None"
    security_mode: Literal["Sign", "SignAndEncrypt"] = "SignAndEncrypt"
    certificate: str | None = None       # the client's certificate (PEM or DER), relative to the field config
    private_key: str | None = None       # its private key (PEM)
    server_certificate: str | None = None
    username: str | None = None
    password_env: str | None = None      # the environment variable that holds the password (never the password)
    timeout_s: Side(MAX_TIMEOUT_S) = 4.0

    @field_validator("endpoint")
    @classmethod
    def _opc_tcp(cls, value: str) -> str:
        if not value.startswith("opc.tcp://"):
            raise ValueError(f"expected an opc.tcp:// address, got {_short(value)}")
        return value


class Plant(_Model):
    # helicalib's own optional key: how the SCS is reached (modbus: scs + register_map; opcua: opcua)
    protocol: Literal["modbus", "opcua"] = "modbus"
    scs: Endpoint | None = None          # required with protocol modbus (FIELD_CONFIG.md)
    weather: Endpoint | None = None
    clock: Literal["plant", "system"] = "plant"
    # helicalib's own optional keys: the plant's Modbus register map (a YAML file relative to the
    # field config, or a shipped map's name; default: PLANT_INTERFACE.md), and the OPC UA server
    register_map: str | None = None
    opcua: OpcUa | None = None

    @model_validator(mode="after")
    def _protocol_keys(self):
        if self.protocol == "modbus" and self.scs is None:
            raise ValueError("scs: required (the SCS's Modbus TCP endpoint; or protocol: opcua with an opcua section)")
        if self.protocol == "opcua" and self.opcua is None:
            raise ValueError("opcua: required with protocol: opcua (endpoint, node_map, security)")
        return self

    @property
    def weather_endpoint(self) -> Endpoint | None:
        return self.weather or self.scs


class Calibration(_Model):
    loop_threshold_mrad: Side(MAX_MRAD)
    max_iterations: int = Field(ge=1, le=100)
    # helicalib's own optional keys
    after_frames: int = Field(default=1, ge=1, le=50)
    spot_method: Literal["grlm", "grlm-centroid", "centroid"] = "grlm-centroid"
    settle_timeout_s: Side(86400.0) = 300.0
    reflectivity_clean: float = Field(default=0.93, gt=0, le=1)  # clean mirror, for the measured cleanliness
    approach_mm: float = Field(default=1.0, ge=0, le=20)  # last move in the tracking direction (backlash)
    max_jitter_mrad: float = Field(default=2.0, gt=0, le=MAX_MRAD)  # several after frames: their spread limit, as an angle
    share_targets: bool = True  # gaps planner: a free board may take heliostats of a busy one (docs/campaign.md)
    max_capture_skew_s: float = Field(default=5.0, gt=0, le=3600)  # a frame's capture time vs the plant clock


class Gating(_Model):
    wind_max_ms: Side(MAX_WIND_MS)
    wind_preferred_ms: Side(MAX_WIND_MS)
    stow_wind_ms: Side(MAX_WIND_MS)
    dni_min_wm2: float = Field(ge=0, le=MAX_DNI_WM2)
    dni_preferred_wm2: float = Field(ge=0, le=MAX_DNI_WM2)
    cleanliness_min: float = Field(ge=0, le=1)
    cleanliness_preferred: float = Field(ge=0, le=1)


class Acceptance(_Model):
    low_band_deg: Annotated[tuple[float, float], _numbers(2), _at_most(90.0, "°")]
    high_elevation_deg: float = Field(ge=-90, le=90)
    high_window_h: Side(24.0)
    min_points: int = Field(ge=1, le=100_000)
    max_rms_mrad: Side(MAX_MRAD)

    @field_validator("low_band_deg")
    @classmethod
    def _band(cls, value):
        if not value[0] < value[1]:
            raise ValueError(f"band is reversed or empty: [{value[0]}, {value[1]}]")
        return value


class WindBin(_Model):
    wind_ms: float = Field(ge=0, le=MAX_WIND_MS)
    min_fraction: float = Field(ge=0, le=1)


class TrackingTest(_Model):
    threshold_mrad: Side(MAX_MRAD)
    wind_bins: tuple[WindBin, ...] = Field(min_length=1)
    bin_half_width_ms: Side(MAX_WIND_MS)


class Storage(_Model):
    database: str
    images_dir: str = Field(min_length=1)

    @field_validator("database")
    @classmethod
    def _sqlite_url(cls, value: str):
        if not value.startswith("sqlite:///") or len(value) <= len("sqlite:///"):
            raise ValueError("expected a URL 'sqlite:///relative/or/absolute/path.db'")
        return value


class FieldConfig(_Model):
    site: Site
    tower: Tower
    targets: tuple[Target, ...] = Field(min_length=1)
    cameras: tuple[Camera, ...]
    drives: dict[Id, Drive] = Field(min_length=1)
    heliostats: tuple[Heliostat, ...] | None = None
    heliostats_csv: str | None = None
    plant: Plant
    calibration: Calibration
    gating: Gating
    acceptance: Acceptance
    tracking_test: TrackingTest
    storage: Storage

    _source: Path | None = PrivateAttr(default=None)

    # -- lookups ----------------------------------------------------------------------
    @property
    def source(self) -> Path | None:
        """The file this config was read from (None when built in memory)."""
        return self._source

    @property
    def base_dir(self) -> Path:
        return self._source.parent if self._source is not None else Path.cwd()

    def resolve_path(self, relative: str | Path) -> Path:
        """A path from the config, resolved next to the config file."""
        p = Path(relative)
        return p if p.is_absolute() else (self.base_dir / p)

    @property
    def database_path(self) -> Path:
        return self.resolve_path(self.storage.database[len("sqlite:///") :])

    @property
    def images_path(self) -> Path:
        return self.resolve_path(self.storage.images_dir)

    def flux_calibration_path(self, camera: Camera) -> Path | None:
        """The camera's FLUX.yaml (``cameras[].flux_calibration``) resolved next to the config, or None."""
        return None if camera.flux_calibration is None else self.resolve_path(camera.flux_calibration)

    def target(self, target_id: str) -> Target:
        for t in self.targets:
            if t.id == target_id:
                return t
        raise ConfigError(f"{self._where()}targets: no target {_short(target_id)}")

    def heliostat(self, heliostat_id: str) -> Heliostat:
        idx = self.heliostat_index(heliostat_id)
        return self.heliostats[idx]

    def heliostat_index(self, heliostat_id: str) -> int:
        """0-based block index of a heliostat (order of ``heliostats``), as in the plant interface."""
        index = self.__dict__.get("_index_cache")
        if index is None:
            index = {h.id: i for i, h in enumerate(self.heliostats)}
            self.__dict__["_index_cache"] = index
        try:
            return index[heliostat_id]
        except KeyError:
            raise ConfigError(f"{self._where()}heliostats: no heliostat {_short(heliostat_id)}") from None

    def drive_of(self, heliostat_id: str) -> Drive:
        return self.drives[self.heliostat(heliostat_id).drive]

    def cameras_for(self, target_id: str) -> tuple[Camera, ...]:
        return tuple(c for c in self.cameras if c.target == target_id)

    def require_cameras(self) -> None:
        """Refuse, in one line, a field without any camera for a command that measures (run, check,
        simulate): such a file (a PAINT import) describes a plant for fitting and reports only."""
        if not self.cameras:
            raise ConfigError(f"{self._where()}cameras: none given: this field can be fitted, reported and "
                              "exported, not measured; give every target a camera (cameras[].target)")

    def heliostat_positions_enu_m(self) -> np.ndarray:
        """Pivot positions of all heliostats, shape (N, 3) [m, ENU]."""
        return np.array([h.position_enu_m for h in self.heliostats], dtype=float).reshape(-1, 3)

    def _where(self) -> str:
        return f"{self._source}: " if self._source is not None else ""


# ---------------------------------------------------------------------------- loading
SQLITE_MAGIC = b"SQLite format 3\x00"
"""The first 16 bytes of every SQLite database file (a helicalib campaign database is one)."""


def read_text(path: str | Path, error: type[HelicalibError] = ConfigError) -> str:
    """A text file's contents (UTF-8, a leading byte-order mark dropped).

    A missing or unreadable file, or bytes that are not UTF-8, raise ``error`` naming the file and,
    for a bad byte, its line and column.
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: file not found" if not path.exists() else f"{path}: not a file")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if raw.startswith(SQLITE_MAGIC):
        raise error(f"{path}: an SQLite database, not a text file")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise error(f"{path}: line {line}, column {column}: not UTF-8 text "
                    f"(byte 0x{raw[exc.start]:02x}); save the file as UTF-8") from None


def read_csv_rows(path: str | Path, error: type[HelicalibError] = ConfigError,
                  comments: bool = False) -> list[tuple[int, list[str]]]:
    """The rows of a UTF-8 CSV file as ``(line number, cells)``; blank rows are skipped.

    ``comments``: lines starting with ``#`` before the first row are skipped. Bad bytes or CSV
    syntax (e.g. an unterminated quote) raise ``error`` naming the file and line.
    """
    import io

    text = read_text(path, error)
    skipped = 0
    if comments:
        lines = text.splitlines(keepends=True)
        while skipped < len(lines) and lines[skipped].startswith("#"):
            skipped += 1
        text = "".join(lines[skipped:])
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = []
    try:
        line = 1
        for row in reader:
            if row and any(cell.strip() for cell in row):
                rows.append((skipped + line, row))
            line = reader.line_num + 1
    except csv.Error as exc:
        raise error(f"{path}: line {skipped + reader.line_num}: not valid CSV ({exc})") from None
    return rows


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping (YAML would keep the last silently)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:
                    continue  # an unhashable key: construct_mapping itself refuses it
                if first is not None:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {_short(key)} (first at line {first.line + 1})", key_node.start_mark)
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)



def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file; a missing file, bytes that are not UTF-8, bad YAML or a key given twice is a
    :class:`ConfigError` naming file, line and column."""
    path = Path(path)
    text = read_text(path)
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).replace("\n", " ")
        raise ConfigError(f"{path}: {at}not valid YAML ({problem})") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid YAML (nested too deeply)") from None


def validation_error(exc: ValidationError, source: str | Path | None = None, rename=None,
                     prefix: str = "") -> ConfigError:
    """A pydantic error as a :class:`ConfigError`: one line per problem, ``FILE: key.path[3]: what``.

    ``rename`` maps a key path to the one to show (e.g. rows of a CSV); ``prefix`` is put before
    every key path (a document validated as part of a larger one).
    """
    where = f"{source}: " if source is not None else ""
    lines: list[str] = []
    for err in exc.errors():
        loc = _loc_to_path(_clean_loc(err["loc"]))
        if prefix:
            loc = prefix if loc == "(top level)" else f"{prefix}{'' if loc.startswith('[') else '.'}{loc}"
        if rename is not None:
            loc = rename(loc)
        line = f"{where}{loc}: {_message(err)}"
        if line not in lines:
            lines.append(line)
    return ConfigError("\n".join(lines), problems=lines)


def _loc_to_path(loc: Sequence[Any]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _message(err: Mapping[str, Any]) -> str:
    msg = str(err["msg"])
    for prefix in ("Value error, ", "Assertion failed, "):
        if msg.startswith(prefix):
            msg = msg[len(prefix) :]
    if err["type"] == "extra_forbidden":
        return "unknown key"
    if err["type"] == "missing":
        return "missing required key"
    return msg


def _clean_loc(loc: Sequence[Any]) -> list[Any]:
    # pydantic inserts the branch name of union / tagged types ("tuple[float, float]", "function-before"...)
    # and the tag of a tagged union ("kind=dots": the marks of a target)
    return [p for p in loc if not (isinstance(p, str) and ("[" in p or "-" in p and p.startswith("function")
                                                           or p.startswith("kind=")))]


def _read_heliostats_csv(path: Path, where: str) -> list[dict[str, Any]]:
    if not path.is_file():
        raise ConfigError(f"{where}heliostats_csv: file not found: {path}")
    want = ["id", "e_m", "n_m", "u_m", "drive", "target"]
    lines = read_csv_rows(path)
    if not lines or [h.strip() for h in lines[0][1]] != want:
        got = ",".join(lines[0][1]) if lines else "an empty file"
        raise ConfigError(f"{path}: line 1: expected the header {','.join(want)}, got {_short(got, 60)}")
    rows = []
    for line_no, cells in lines[1:]:
        if len(cells) != len(want):
            raise ConfigError(f"{path}: line {line_no}: expected {len(want)} fields "
                              f"({','.join(want)}), got {len(cells)}")
        row = dict(zip(want, (c.strip() for c in cells)))
        pos = []
        for key in ("e_m", "n_m", "u_m"):
            try:
                value = float(row[key])
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise ConfigError(f"{path}: line {line_no}: {key}: expected a finite number, got {_short(row[key])}")
            pos.append(value)
        rows.append({"id": row["id"], "position_enu_m": pos, "drive": row["drive"], "target": row["target"]})
    return rows


def _cross_check(cfg: FieldConfig, heliostat_loc: str) -> list[str]:
    problems: list[str] = []
    target_ids = [t.id for t in cfg.targets]
    for i, tid in enumerate(target_ids):
        if tid in target_ids[:i]:
            problems.append(f"targets[{i}].id: duplicate target id {_short(tid)}")
    camera_ids = [c.id for c in cfg.cameras]
    for i, cam in enumerate(cfg.cameras):
        if cam.id in camera_ids[:i]:
            problems.append(f"cameras[{i}].id: duplicate camera id {_short(cam.id)}")
        if cam.target not in target_ids:
            problems.append(f"cameras[{i}].target: unknown target {_short(cam.target)} (defined: {', '.join(target_ids)})")
    seen: set[str] = set()
    for i, h in enumerate(cfg.heliostats or ()):
        if h.id in seen:
            problems.append(f"{heliostat_loc}[{i}].id: duplicate heliostat id {_short(h.id)}")
        seen.add(h.id)
        if h.drive not in cfg.drives:
            problems.append(f"{heliostat_loc}[{i}].drive: unknown drive {_short(h.drive)} (defined: {', '.join(cfg.drives)})")
        if h.target not in target_ids:
            problems.append(f"{heliostat_loc}[{i}].target: unknown target {_short(h.target)} (defined: {', '.join(target_ids)})")
    problems += _apart_from_their_boards(cfg, heliostat_loc)
    problems += _in_front_of_their_boards(cfg, heliostat_loc)
    problems += _apart_from_each_other(cfg, heliostat_loc)
    if cfg.cameras:  # a field without any camera describes a plant (an import) and is not run
        for i, t in enumerate(cfg.targets):
            if not cfg.cameras_for(t.id):
                problems.append(f"targets[{i}]: no camera looks at target {_short(t.id)} (give it one in cameras[], "
                                "with target: " + t.id + "); every board is measured by its camera")
    problems += _beams_off_other_boards(cfg)
    for name, d in cfg.drives.items():
        if d.kind == "custom" and None in (d.axis1_enu, d.axis2_enu, d.normal0_enu):
            problems.append(f"drives.{name}: kind custom needs axis1_enu, axis2_enu and normal0_enu")
        if d.kind != "custom" and any(x is not None for x in (d.axis1_enu, d.axis2_enu, d.normal0_enu)):
            problems.append(f"drives.{name}: axis1_enu/axis2_enu/normal0_enu are only for kind custom")
    g = cfg.gating
    if not g.wind_preferred_ms <= g.wind_max_ms <= g.stow_wind_ms:
        problems.append("gating: expected wind_preferred_ms <= wind_max_ms <= stow_wind_ms")
    if g.dni_preferred_wm2 < g.dni_min_wm2:
        problems.append("gating.dni_preferred_wm2: smaller than dni_min_wm2")
    if g.cleanliness_preferred < g.cleanliness_min:
        problems.append("gating.cleanliness_preferred: smaller than cleanliness_min")
    return problems


def _apart_from_their_boards(cfg: FieldConfig, heliostat_loc: str) -> list[str]:
    """A heliostat's pivot cannot lie on its own board's centre (its beam would have no direction)."""
    centre = {t.id: np.asarray(t.center_enu_m) for t in cfg.targets}
    return [f"{heliostat_loc}[{i}].position_enu_m: {_short(h.id)} stands within 1 m of the centre of its "
            f"target {_short(h.target)}" for i, h in enumerate(cfg.heliostats or ())
            if h.target in centre and np.linalg.norm(np.asarray(h.position_enu_m) - centre[h.target]) < 1.0][:20]


def _in_front_of_their_boards(cfg: FieldConfig, heliostat_loc: str) -> list[str]:
    """A heliostat's beam reaches its board's front (white, marked) face only from in front of the
    board's plane: its pivot must lie on the side the board's normal points to."""
    if not cfg.heliostats:
        return []
    boards = {t.id: t for t in cfg.targets}
    pos = cfg.heliostat_positions_enu_m()
    problems = []
    for i, h in enumerate(cfg.heliostats):
        t = boards.get(h.target)
        if t is None:
            continue
        ahead = float(np.dot(pos[i] - np.asarray(t.center_enu_m), t.normal_enu))
        if ahead <= 0.0:
            problems.append(f"{heliostat_loc}[{i}].position_enu_m: {_short(h.id)} stands {-ahead:.1f} m behind the "
                            f"board of its target {_short(h.target)} (the board faces {_facing(t.normal_enu)}); its "
                            "beam cannot reach the board's front")
    return problems[:20]


def _facing(normal: Sequence[float]) -> str:
    """A board normal in words: "north", "south-east", "up"."""
    e, n, u = normal
    if abs(u) > 0.9:
        return "up" if u > 0 else "down"
    az = math.degrees(math.atan2(e, n)) % 360
    return ("north", "north-east", "east", "south-east", "south", "south-west", "west", "north-west")[round(az / 45) % 8]


def _apart_from_each_other(cfg: FieldConfig, heliostat_loc: str) -> list[str]:
    """Two pivots closer than half the smaller mirror side of the two stand at one place: their mirrors
    would collide (a position given twice, as a copied row)."""
    from scipy.spatial import cKDTree

    if not cfg.heliostats or len(cfg.heliostats) < 2:
        return []
    pos = cfg.heliostat_positions_enu_m()
    half = np.array([min(cfg.drives[h.drive].mirror_size_m) / 2 if h.drive in cfg.drives else 0.0
                     for h in cfg.heliostats])
    problems = []
    for i, j in sorted(cKDTree(pos).query_pairs(float(half.max()))):
        d = float(np.linalg.norm(pos[i] - pos[j]))
        if d < min(half[i], half[j]) or d == 0.0:
            a, b = cfg.heliostats[i], cfg.heliostats[j]
            problems.append(f"{heliostat_loc}[{j}].position_enu_m: {_short(b.id)} stands {d:.2f} m from "
                            f"{_short(a.id)} ({heliostat_loc}[{i}]): closer than half a mirror, the two would collide")
    return problems[:20]


STANDBY_CLEARANCE_M = 1.0
"""A beam waiting at a standby point keeps its aim this far off every other board (its spot is larger)."""


def _beams_off_other_boards(cfg: FieldConfig) -> list[str]:
    """A beam on a board, or waiting at its standby point, must not cross another board: the campaign
    gives a board to one beam at a time and keeps the others' beams at their own boards or standby
    points, so boards that overlap as the field sees them, or a standby point whose beams fall on a
    neighbouring board, put a second spot into a board's measurements. Rays from each heliostat's pivot
    through its own board's centre, corners and edge middles are intersected with every other board
    before that point (a board in front takes the beam), the ray through its standby point with every
    other board grown by :data:`STANDBY_CLEARANCE_M` anywhere beyond the pivot (the beam goes on); a
    hit is refused, naming the first heliostat and the point."""
    from helicalib.geometry.optics import intersect_target

    targets = list(cfg.targets)
    if len(targets) < 2 or not cfg.heliostats:
        return []
    pivots = np.array([h.position_enu_m for h in cfg.heliostats], dtype=float)
    own = np.array([h.target for h in cfg.heliostats])
    problems = []
    for i, a in enumerate(targets):
        sel = np.nonzero(own == a.id)[0]
        if not len(sel):
            continue
        hw, hh = a.size_m[0] / 2, a.size_m[1] / 2
        names = ["centre", "top-left corner", "top edge", "top-right corner", "right edge", "bottom-right corner",
                 "bottom edge", "bottom-left corner", "left edge", "standby point"]
        uvw = np.array([[0, 0, 0], [-hw, hh, 0], [0, hh, 0], [hw, hh, 0], [hw, 0, 0], [hw, -hh, 0], [0, -hh, 0],
                        [-hw, -hh, 0], [-hw, 0, 0], a.standby_uvw_m], dtype=float)
        aims = a.uvw_to_enu(uvw)  # (P, 3)
        d = aims[None, :, :] - pivots[sel][:, None, :]  # (H, P, 3)
        for b in targets:
            if b.id == a.id:
                continue
            x, at, valid = intersect_target(pivots[sel][:, None, :], d, b)  # x: (u, v) on b; NaN if missed
            t = np.sum((at - pivots[sel][:, None, :]) * d, axis=-1) / np.sum(d * d, axis=-1)  # 1 at the aim
            # a board point's beam stops at that board, so only a board before it (t < 1) takes it, and
            # 5 cm inside its edge (boards meeting edge to edge, as a tower's stacked boards, are fine);
            # the beam through a standby point goes on (t > 0) and keeps 1 m off the other boards
            before = np.ones_like(t, dtype=bool)
            before[:, :-1] = t[:, :-1] < 1.0 - 1e-6
            grow = np.full(len(uvw), -0.05)
            grow[-1] = STANDBY_CLEARANCE_M
            with np.errstate(invalid="ignore"):
                hit = valid & before & (np.abs(x[..., 0]) < b.size_m[0] / 2 + grow) \
                    & (np.abs(x[..., 1]) < b.size_m[1] / 2 + grow)
            if hit.any():
                k, j = (int(v[0]) for v in np.nonzero(hit))
                who = f"the beam of {_short(cfg.heliostats[sel[k]].id)}"
                where = (f"the board of target {_short(b.id)} (u {x[k, j, 0]:.1f}, v {x[k, j, 1]:.1f} m; "
                         f"{int(hit.any(axis=1).sum())} of the {len(sel)} heliostats of {_short(a.id)})")
                if j == len(names) - 1:
                    problems.append(f"targets[{i}].standby_offset_m: {who} waiting at the standby point of target "
                                    f"{_short(a.id)} lands on {where}: keep standby points off every board")
                else:
                    problems.append(f"targets[{i}].center_enu_m: {who} aimed at the {names[j]} of target "
                                    f"{_short(a.id)} meets {where} first: a board stands in front of another")
    return problems


def parse_field_config(data: Any, source: str | Path | None = None) -> FieldConfig:
    """Validate an already-parsed field config mapping; ``source`` names the file in messages."""
    where = f"{source}: " if source is not None else ""
    if data is None:
        raise ConfigError(f"{where}(top level): the file is empty; expected a mapping of sections (site, tower, ...)")
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}(top level): expected a mapping of sections, got {type(data).__name__}")
    data = dict(data)
    base = Path(source).parent if source is not None else Path.cwd()
    heliostat_loc = "heliostats"
    has_list, has_csv = data.get("heliostats") is not None, data.get("heliostats_csv") is not None
    if has_list == has_csv:
        raise ConfigError(f"{where}heliostats: give exactly one of 'heliostats' or 'heliostats_csv'")
    if has_list and isinstance(data["heliostats"], Sequence) and not isinstance(data["heliostats"], str) \
            and len(data["heliostats"]) == 0:
        raise ConfigError(f"{where}heliostats: empty list; a field needs at least one heliostat")
    if has_csv:
        csv_path = Path(str(data["heliostats_csv"]))
        csv_path = csv_path if csv_path.is_absolute() else base / csv_path
        data["heliostats"] = _read_heliostats_csv(csv_path, where)
        heliostat_loc = f"heliostats_csv({csv_path.name})"
        if not data["heliostats"]:
            raise ConfigError(f"{where}heliostats_csv: {csv_path} lists no heliostats")
    try:
        cfg = FieldConfig.model_validate(data)
    except ValidationError as exc:
        rename = (lambda loc: heliostat_loc + loc[len("heliostats"):] if loc.startswith("heliostats[") else loc) \
            if has_csv else None
        raise validation_error(exc, source, rename) from None
    problems = [f"{where}{p}" for p in _cross_check(cfg, heliostat_loc)]
    for i, cam in enumerate(cfg.cameras):
        if cam.flux_calibration is not None:
            p = Path(cam.flux_calibration)
            if not (p if p.is_absolute() else base / p).is_file():
                problems.append(f"{where}cameras[{i}].flux_calibration: file not found: {base / p}")
    problems += [f"{where}{p}" for p in _device_files(cfg, base)]
    if problems:
        raise ConfigError("\n".join(problems), problems=problems)
    if source is not None:
        cfg._source = Path(source).resolve()
    return cfg


def is_map_name(value: str) -> bool:
    """A shipped map is named by a bare word (``scs-b``); anything with a folder or a suffix is a file."""
    return "/" not in value and "\\" not in value and not value.endswith((".yaml", ".yml"))


def _device_files(cfg: FieldConfig, base: Path) -> list[str]:
    """The plant's and the cameras' files that must exist (a map named by a shipped name is checked
    when it is loaded); one line each naming the key."""
    out = []
    plant = cfg.plant
    files = [("plant.register_map", plant.register_map)]
    if plant.opcua is not None:
        files += [(f"plant.opcua.{k}", getattr(plant.opcua, k))
                  for k in ("node_map", "certificate", "private_key", "server_certificate")]
    for i, cam in enumerate(cfg.cameras):
        if cam.genicam is not None and cam.genicam.cti is not None:
            files.append((f"cameras[{i}].genicam.cti", cam.genicam.cti))
    for key, value in files:
        if value is None or (key.endswith(("register_map", "node_map")) and is_map_name(value)):
            continue
        p = Path(value)
        if not (p if p.is_absolute() else base / p).is_file():
            out.append(f"{key}: file not found: {base / p}")
    for i, cam in enumerate(cfg.cameras):
        if cam.kind != "genicam" and cam.genicam is not None:
            out.append(f"cameras[{i}].genicam: only for kind: genicam (this camera is kind: {cam.kind})")
        if cam.exposure_url is not None and cam.kind != "stream":
            out.append(f"cameras[{i}].exposure_url: only for kind: stream (an http camera takes ?exposure_ms= "
                       "at its url)")
    return out


def load_field_config(path: str | Path) -> FieldConfig:
    """Read and validate a field config YAML file (and its heliostat CSV)."""
    path = Path(path)
    _not_a_database(path)
    return parse_field_config(read_yaml(path), path)


def _not_a_database(path: Path) -> None:
    """A database given where the field config belongs (``run helicalib.db``) is refused in one line
    that says so, naming the config its newest campaign was run with when the database tells."""
    try:
        with path.open("rb") as f:
            head = f.read(len(SQLITE_MAGIC))
    except OSError:
        return  # read_text names the problem
    if head != SQLITE_MAGIC:
        return
    import sqlite3

    kind, hint = "an SQLite database", ""
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=0.5)
        try:
            if con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'campaigns'").fetchone():
                kind = "a helicalib database"
                row = con.execute("SELECT config_path FROM campaigns ORDER BY id DESC LIMIT 1").fetchone()
                if row and isinstance(row[0], str) and row[0] and len(row[0]) <= 300 and row[0].isprintable():
                    hint = f" (its newest campaign ran with {row[0]})"
        finally:
            con.close()
    except sqlite3.Error:
        pass
    raise ConfigError(f"{path}: this is {kind}, not a field config; give the field config YAML{hint}")


def clear_standby_points(data: Mapping[str, Any]) -> dict:
    """``data`` with a standby point given to every target that has none, on the first side of its
    board (left, right, below, above; as far out as the default) whose waiting beams land on no
    other board: an importer's boards (PAINT has no standby points) then pass the check of
    :func:`_beams_off_other_boards` where the default side would put a beam on a neighbour. Targets
    that state theirs keep it; when no side clears, the default is kept (and refused by the check)."""
    import copy

    data = copy.deepcopy(dict(data))
    targets = data.get("targets") or []
    open_ = [i for i, t in enumerate(targets) if isinstance(t, Mapping) and t.get("standby_offset_m") is None]
    for i in open_:
        w, h = (float(x) for x in targets[i]["size_m"])
        du, dv = w / 2 + max(w / 2, 6.0), h / 2 + max(h / 2, 6.0)
        for side in ([-du, 0.0], [du, 0.0], [0.0, -dv], [0.0, dv]):
            targets[i]["standby_offset_m"] = side
            try:
                parse_field_config(data)
            except ConfigError as exc:
                if any(p.startswith(f"targets[{i}].standby_offset_m") for p in exc.problems):
                    continue
            break
        else:
            targets[i]["standby_offset_m"] = None
    for t in targets:
        if isinstance(t, Mapping) and t.get("standby_offset_m") is None:
            t.pop("standby_offset_m", None)
    return data


def write_field_config(data: Mapping[str, Any], path: str | Path) -> FieldConfig:
    """Write a field config mapping as YAML, then load it back (so every file written is valid)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(_plain(data), sort_keys=False, default_flow_style=None, width=110))
    return load_field_config(path)


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    return value
