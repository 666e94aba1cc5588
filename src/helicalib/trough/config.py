"""COLLECTOR.yaml and CAMERA.yaml for the trough overlay method → frozen, validated objects.

Every key is documented in ``docs/trough.md``. Problems raise :class:`ConfigError` with one line
per problem, ``FILE: key.path: what is wrong``. The loaders read files; the models and
:meth:`Collector.facets` are pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from helicalib.config import read_yaml, validation_error
from helicalib.errors import ConfigError
from helicalib.trough.camera import PinholeCamera

Finite = Field(allow_inf_nan=False)
MAX_SIZE_MM = 1e6
"""Largest length or coordinate a COLLECTOR.yaml or CAMERA.yaml may give [mm] (1 km)."""
MAX_IMAGE_SIDE_PX = 20000
"""Largest image side a CAMERA.yaml may give [px] (a 150-megapixel back is 14204 px wide)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


@dataclass(frozen=True)
class FacetLayout:
    """The N = rows × columns facets, row-major from the top-left (all arrays shape (N,), mm).

    Row 1 is the top row (largest Y), column 1 the leftmost in the photo (smallest X). Facet ids
    read ``R<row>C<column>``.
    """

    ids: tuple[str, ...]
    row: np.ndarray
    column: np.ndarray
    y_min_mm: np.ndarray
    y_max_mm: np.ndarray
    x_min_mm: np.ndarray
    x_max_mm: np.ndarray


class Collector(_Model):
    """One collector module (COLLECTOR.yaml)."""

    focal_length_mm: float = Field(gt=0, le=MAX_SIZE_MM, allow_inf_nan=False)
    aperture_mm: float = Field(gt=0, le=MAX_SIZE_MM, allow_inf_nan=False)
    length_mm: float = Field(gt=0, le=MAX_SIZE_MM, allow_inf_nan=False)
    tube_radius_mm: float = Field(gt=0, le=MAX_SIZE_MM, allow_inf_nan=False)
    tube_length_mm: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    rows: int = Field(ge=1, le=16)
    columns: int = Field(ge=1, le=64)
    row_edges_mm: tuple[tuple[float, float], ...] | None = None
    row_gap_mm: float = Field(default=0.0, ge=0, allow_inf_nan=False)
    column_gap_mm: float = Field(default=0.0, ge=0, allow_inf_nan=False)
    tilt_tolerance_mrad: float = Field(default=2.0, gt=0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _check(self):
        half = self.aperture_mm / 2.0
        if self.tube_radius_mm >= self.focal_length_mm:
            raise ValueError("tube_radius_mm must be smaller than focal_length_mm")
        if self.row_edges_mm is not None:
            edges = self.row_edges_mm
            if len(edges) != self.rows:
                raise ValueError(f"row_edges_mm: expected {self.rows} pairs (one per row), got {len(edges)}")
            for i, (lo, hi) in enumerate(edges):
                if not (math.isfinite(lo) and math.isfinite(hi) and -half - 1e-9 <= lo < hi <= half + 1e-9):
                    raise ValueError(f"row_edges_mm[{i}]: expected y_min < y_max inside ±aperture_mm/2 = ±{half:g}")
                if i and lo >= edges[i - 1][0]:
                    raise ValueError(f"row_edges_mm[{i}]: rows are listed from the top (largest Y) down")
                if i and hi > edges[i - 1][0]:
                    raise ValueError(f"row_edges_mm[{i}]: overlaps row {i}")
        else:
            if self.row_gap_mm * (self.rows + 1) >= self.aperture_mm:
                raise ValueError("row_gap_mm: gaps leave no mirror")
        if self.column_gap_mm * self.columns >= self.length_mm:
            raise ValueError("column_gap_mm: gaps leave no mirror")
        return self

    def row_bounds_mm(self) -> np.ndarray:
        """Y bounds of each row from the top, shape (rows, 2) [mm]."""
        if self.row_edges_mm is not None:
            return np.array(self.row_edges_mm, dtype=float)
        half = self.aperture_mm / 2.0
        cuts = np.linspace(half, -half, self.rows + 1)
        g = self.row_gap_mm / 2.0
        lo = cuts[1:] + np.where(np.arange(self.rows) < self.rows - 1, g, 0.0)
        hi = cuts[:-1] - np.where(np.arange(self.rows) > 0, g, 0.0)
        return np.stack([lo, hi], axis=1)

    def facets(self) -> FacetLayout:
        """All facets, row-major from the top-left."""
        rows = self.row_bounds_mm()
        cuts = np.linspace(-self.length_mm / 2.0, self.length_mm / 2.0, self.columns + 1)
        g = self.column_gap_mm / 2.0
        x_lo = cuts[:-1] + np.where(np.arange(self.columns) > 0, g, 0.0)
        x_hi = cuts[1:] - np.where(np.arange(self.columns) < self.columns - 1, g, 0.0)
        r_idx, c_idx = np.meshgrid(np.arange(self.rows), np.arange(self.columns), indexing="ij")
        r_idx, c_idx = r_idx.ravel(), c_idx.ravel()
        return FacetLayout(ids=tuple(f"R{r + 1}C{c + 1}" for r, c in zip(r_idx, c_idx)),
                           row=r_idx + 1, column=c_idx + 1,
                           y_min_mm=rows[r_idx, 0], y_max_mm=rows[r_idx, 1], x_min_mm=x_lo[c_idx], x_max_mm=x_hi[c_idx])

    def pivots_yz_mm(self, layout: FacetLayout) -> np.ndarray:
        """Tilt pivots: each strip's centre on the parabola, shape (N, 2) [mm]."""
        yc = 0.5 * (layout.y_min_mm + layout.y_max_mm)
        return np.stack([yc, yc * yc / (4.0 * self.focal_length_mm)], axis=-1)

    @property
    def tube_x_range_mm(self) -> tuple[float, float]:
        """Tube ends along X [mm] (centred on the module)."""
        half = (self.tube_length_mm or self.length_mm) / 2.0
        return -half, half


class Camera(_Model):
    """One camera of the overlay rig (CAMERA.yaml)."""

    position_mm: tuple[float, float, float]
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    image_size_px: tuple[int, int]
    focal_length_mm: float = Field(gt=0, le=MAX_SIZE_MM, allow_inf_nan=False)
    pixel_pitch_um: float = Field(gt=0, le=MAX_SIZE_MM, allow_inf_nan=False)
    principal_point_px: tuple[float, float] | None = None

    @field_validator("position_mm")
    @classmethod
    def _above(cls, value):
        if any(abs(v) > MAX_SIZE_MM for v in value):
            raise ValueError(f"expected coordinates within ±{MAX_SIZE_MM:g} mm")
        if not value[2] > 0:
            raise ValueError("the camera must stand above the vertex (z > 0) and look down along -Z")
        return value

    @field_validator("image_size_px")
    @classmethod
    def _image(cls, value):
        w, h = value
        if w < 16 or h < 16 or w > MAX_IMAGE_SIDE_PX or h > MAX_IMAGE_SIDE_PX:
            raise ValueError(f"expected width and height in 16..{MAX_IMAGE_SIDE_PX}")
        return value

    @field_validator("rotation_deg")
    @classmethod
    def _attitude(cls, value):
        if any(abs(a) > 10.0 for a in value):
            raise ValueError("residual attitude beyond ±10° — the camera must look along -Z")
        return value

    def pinhole(self) -> PinholeCamera:
        """The :class:`PinholeCamera` this file describes."""
        w, h = self.image_size_px
        pp = self.principal_point_px if self.principal_point_px is not None else ((w - 1) / 2.0, (h - 1) / 2.0)
        return PinholeCamera(position_mm=np.array(self.position_mm, dtype=float),
                             focal_length_px=self.focal_length_mm * 1000.0 / self.pixel_pitch_um,
                             principal_point_px=(float(pp[0]), float(pp[1])), image_size_px=(int(w), int(h)),
                             rotation_deg=tuple(float(a) for a in self.rotation_deg))




def parse(model: type[_Model], data: Any, source: str | Path | None = None):
    """Validate a parsed mapping as ``model``; ``source`` names the file in error lines."""
    where = f"{source}: " if source is not None else ""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}(top level): expected a mapping of keys, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise validation_error(exc, source) from None


def _load(model, path: str | Path):
    path = Path(path)
    return parse(model, read_yaml(path), path)


def load_collector(path: str | Path) -> Collector:
    """Read and validate COLLECTOR.yaml."""
    return _load(Collector, path)


def load_camera(path: str | Path) -> Camera:
    """Read and validate CAMERA.yaml."""
    return _load(Camera, path)
