"""FLUX.yaml: one camera's flux calibration (F_e, correction files, component errors).

Every key is documented in ``docs/flux.md``; an example is ``field_config/flux_demo.yaml``. The file
is validated with pydantic (unknown keys refused); problems are one line each,
``FILE: key.path: what is wrong``. Relative paths of correction files are resolved next to the
FLUX.yaml. :func:`load_flux_calibration` reads the YAML, :func:`load_correction_data` then reads the
named files into arrays (the only I/O of :mod:`helicalib.flux` besides the command).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, model_validator

from helicalib.config import read_csv_rows, read_yaml, validation_error
from helicalib.errors import ConfigError
from helicalib.flux import calibration as cal
from helicalib.flux.corrections import ResponseCurve, correct_frame, flat_field_factors, nonuniformity_error, response_curve

Positive = Field(gt=0)
Fraction = Field(gt=0, le=1)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class TwoRadiometer(_Model):
    ea_wm2: float = Positive
    eb_wm2: float = Positive
    eb_prime_wm2: float = Positive
    gav_grey: float = Positive


class SunCalibration(_Model):
    sun_grey_sum: float = Positive
    dni_wm2: float = Positive
    nd_transmittance: float = Fraction
    board_reflectance: float = Fraction
    pixel_solid_angle_sr: float | None = Field(default=None, gt=0)


class Fe(_Model):
    value_wm2_per_grey: float | None = Field(default=None, gt=0)
    two_radiometer: TwoRadiometer | None = None
    sun: SunCalibration | None = None

    @model_validator(mode="after")
    def _exactly_one(self):
        given = [k for k in ("value_wm2_per_grey", "two_radiometer", "sun") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of value_wm2_per_grey, two_radiometer, sun"
                             + (f" (got {', '.join(given)})" if given else ""))
        return self


class Dark(_Model):
    grey: float | None = Field(default=None, ge=0)
    frame: str | None = None

    @model_validator(mode="after")
    def _one(self):
        if (self.grey is None) == (self.frame is None):
            raise ValueError("give exactly one of grey, frame")
        return self


class Nonlinearity(_Model):
    curve_csv: str | None = None
    input: tuple[float, ...] | None = None
    grey: tuple[float, ...] | None = None
    linear_up_to_grey: float | None = Field(default=None, gt=0)

    @model_validator(mode="after")
    def _one(self):
        inline = self.input is not None or self.grey is not None
        if inline == (self.curve_csv is not None):
            raise ValueError("give either curve_csv or both input and grey")
        if inline and (self.input is None or self.grey is None or len(self.input) != len(self.grey)):
            raise ValueError("input and grey must both be given, with the same number of values")
        return self


class FlatField(_Model):
    frame: str


class NonLambertian(_Model):
    incidence_deg: tuple[float, ...] | None = None
    relative: tuple[float, ...] | None = None
    view_deg: tuple[float, ...] | None = None
    view_relative: tuple[float, ...] | None = None

    @model_validator(mode="after")
    def _tables(self):
        pairs = (("incidence_deg", "relative"), ("view_deg", "view_relative"))
        if all(getattr(self, a) is None and getattr(self, b) is None for a, b in pairs):
            raise ValueError("give incidence_deg/relative and/or view_deg/view_relative")
        for a, b in pairs:
            x, y = getattr(self, a), getattr(self, b)
            if (x is None) != (y is None):
                raise ValueError(f"{a} and {b} go together")
            if x is not None:
                if len(x) != len(y) or len(x) < 2:
                    raise ValueError(f"{a} and {b} need the same number (>= 2) of values")
                if any(q <= p for p, q in zip(x, x[1:])):
                    raise ValueError(f"{a} must be strictly increasing")
                if any(not v > 0 for v in y):
                    raise ValueError(f"{b} values must be positive (E_j / E_0)")
        return self


class Corrections(_Model):
    dark: Dark | None = None
    nonlinearity: Nonlinearity | None = None
    flat_field: FlatField | None = None
    distortion: bool = False
    non_lambertian: NonLambertian | None = None


class ComponentErrors(_Model):
    dark: float | None = Field(default=None, ge=0, le=1)
    nonlinearity: float | None = Field(default=None, ge=0, le=1)
    nonuniformity: float | None = Field(default=None, ge=0, le=1)
    non_lambertian: float | None = Field(default=None, ge=0, le=1)
    calibration: float | None = Field(default=None, ge=0, le=1)

    def given(self) -> dict[str, float]:
        return {k: v for k, v in self.model_dump().items() if v is not None}


class CleanlinessModel(_Model):
    reflectivity_clean: float = Fraction
    atmosphere: Literal["clear", "hazy", "none"] = "clear"


class FluxCalibration(_Model):
    """The validated contents of a FLUX.yaml (see ``docs/flux.md``)."""

    camera: str | None = None
    grid_cell_m: float | None = Field(default=None, gt=0)
    fe: Fe
    corrections: Corrections = Corrections()
    errors: ComponentErrors = ComponentErrors()
    cleanliness: CleanlinessModel | None = None
    exposure_ms: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    """The camera's exposure at which ``fe`` holds [ms] (a camera that sets its exposure,
    PLANT_INTERFACE 1.1): frames taken at another exposure scale Fe by its ratio."""

    _source: Path | None = PrivateAttr(default=None)

    @property
    def source(self) -> Path | None:
        return self._source

    def resolve(self, relative: str) -> Path:
        """A file named in this FLUX.yaml, resolved next to it."""
        p = Path(relative)
        base = self._source.parent if self._source is not None else Path.cwd()
        return p if p.is_absolute() else base / p

    def fe_wm2_per_grey(self, camera_matrix: np.ndarray | None = None) -> float:
        """F_e [W/m² per grey] by the configured method; the sun method may need the camera matrix."""
        f = self.fe
        if f.value_wm2_per_grey is not None:
            return float(f.value_wm2_per_grey)
        if f.two_radiometer is not None:
            t = f.two_radiometer
            return cal.fe_two_radiometer(t.ea_wm2, t.eb_wm2, t.eb_prime_wm2, t.gav_grey)
        s = f.sun
        omega = s.pixel_solid_angle_sr
        if omega is None:
            if camera_matrix is None:
                raise ConfigError(f"{self._where()}fe.sun.pixel_solid_angle_sr: missing, and the camera has no "
                                  "intrinsics to derive it from")
            omega = 1.0 / (float(camera_matrix[0, 0]) * float(camera_matrix[1, 1]))
        return cal.fe_camera_on_sun(s.sun_grey_sum, omega, s.dni_wm2, s.nd_transmittance, s.board_reflectance)

    def _where(self) -> str:
        return f"{self._source}: " if self._source is not None else ""


def parse_flux_calibration(data: Any, source: str | Path | None = None) -> FluxCalibration:
    """Validate an already-parsed FLUX.yaml mapping; ``source`` names the file in messages."""
    where = f"{source}: " if source is not None else ""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}(top level): expected a mapping, got {type(data).__name__}")
    try:
        out = FluxCalibration.model_validate(data)
    except ValidationError as exc:
        raise validation_error(exc, source) from None
    if source is not None:
        out._source = Path(source).resolve()
    return out


def load_flux_calibration(path: str | Path) -> FluxCalibration:
    """Read and validate a FLUX.yaml file."""
    path = Path(path)
    return parse_flux_calibration(read_yaml(path), path)


# ----------------------------------------------------------------------------- correction data
@dataclass(frozen=True)
class CorrectionData:
    """The correction inputs of a FLUX.yaml, read into arrays, with a record of what was loaded."""

    dark_grey: float | None = None
    response: ResponseCurve | None = None
    flat_factors: np.ndarray | None = None
    record: dict[str, Any] = field(default_factory=dict)


def _read_grey(path: Path, key: str, where: str) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise ConfigError(f"{where}{key}: file not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ConfigError(f"{where}{key}: not a readable image: {path}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return img.astype(float)


def _read_curve(path: Path, where: str) -> tuple[list[float], list[float]]:
    if not path.is_file():
        raise ConfigError(f"{where}corrections.nonlinearity.curve_csv: file not found: {path}")
    rows = read_csv_rows(path)
    if not rows or [h.strip() for h in rows[0][1]] != ["input", "grey"]:
        got = ",".join(rows[0][1])[:60] if rows else "an empty file"
        raise ConfigError(f"{path}: line 1: expected the header input,grey, got {got!r}")
    xs, ys = [], []
    for line_no, cells in rows[1:]:
        try:
            if len(cells) != 2:
                raise ValueError
            x, y = float(cells[0]), float(cells[1])
        except ValueError:
            raise ConfigError(f"{path}: line {line_no}: expected two numbers, input and grey") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ConfigError(f"{path}: line {line_no}: input and grey must be finite")
        xs.append(x)
        ys.append(y)
    return xs, ys


def load_correction_data(fc: FluxCalibration) -> CorrectionData:
    """Read the dark frame, response curve and flat-field frame a FLUX.yaml names.

    Returns the arrays the pure corrections take and a ``record`` (plain data) of each correction:
    its source and the figures derived from it (mean dark output, K0/K1, ε_NU of the flat frame).
    """
    where = fc._where()
    c = fc.corrections
    record: dict[str, Any] = {}
    dark = None
    if c.dark is not None:
        if c.dark.frame is not None:
            dark = float(_read_grey(fc.resolve(c.dark.frame), "corrections.dark.frame", where).mean())
            record["dark"] = {"source": str(fc.resolve(c.dark.frame)), "dark_grey": round(dark, 4)}
        else:
            dark = float(c.dark.grey)
            record["dark"] = {"source": "FLUX.yaml", "dark_grey": dark}
    response = None
    if c.nonlinearity is not None:
        n = c.nonlinearity
        if n.curve_csv is not None:
            xs, ys = _read_curve(fc.resolve(n.curve_csv), where)
            src = str(fc.resolve(n.curve_csv))
        else:
            xs, ys, src = list(n.input), list(n.grey), "FLUX.yaml"
        try:
            response = response_curve(xs, ys, n.linear_up_to_grey)
        except ValueError as err:
            raise ConfigError(f"{where}corrections.nonlinearity: {err}") from None
        record["nonlinearity"] = {"source": src, "points": len(xs), "k0_grey": round(response.k0_grey, 5),
                                  "k1_grey_per_input": round(response.k1_grey_per_input, 6),
                                  "linear_up_to_grey": round(response.linear_up_to_grey, 3)}
    flat = None
    if c.flat_field is not None:
        path = fc.resolve(c.flat_field.frame)
        raw = _read_grey(path, "corrections.flat_field.frame", where)
        corrected = correct_frame(raw, dark_grey=dark, response=response)
        try:
            flat = flat_field_factors(corrected)
            eps_nu = nonuniformity_error(corrected)
        except ValueError as err:
            raise ConfigError(f"{where}corrections.flat_field.frame: {err}") from None
        record["flat_field"] = {"source": str(path), "shape_px": [int(raw.shape[1]), int(raw.shape[0])],
                                "nonuniformity_error": round(eps_nu, 6)}
    return CorrectionData(dark_grey=dark, response=response, flat_factors=flat, record=record)


def flux_calibration_of(cfg, cam) -> tuple[float | None, str | None]:
    """(Fe [W/m² per grey] or None, atmosphere model) of a configured camera, from its FLUX.yaml."""
    path = cfg.flux_calibration_path(cam)
    if path is None:
        return None, "clear"
    fc = load_flux_calibration(path)
    fe = fc.fe_wm2_per_grey(cam.camera_matrix)
    return fe, (fc.cleanliness.atmosphere if fc.cleanliness is not None else "clear")
