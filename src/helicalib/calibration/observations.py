"""Calibration observations file: one row per observation, CSV with a fixed, documented header.

Any source writes it (``helicalib import-paint`` for PAINT records, the campaign for our own
measurements) and ``helicalib fit`` reads it. Columns, in this order:

=================  ==========================================================================
heliostat_id       the heliostat's id in the field config
utc_time           ISO 8601 UTC instant of the observation, empty when unknown
sun_e, sun_n,      unit vector from the heliostat to the sun, plant ENU (as measured or
sun_u              computed for the instant; PAINT: from the record's sun azimuth/elevation)
stroke1_mm,        actuator strokes [mm] of axis 1 and axis 2 as commanded/read back
stroke2_mm
target_id          the target (board) the spot was measured on
spot_e_m, spot_n_m, the observed spot centre in plant ENU [m]
spot_u_m
target_u_m,        the same spot in the target frame (u right as seen from the field, v up) [m]
target_v_m
spot_method        how the centre was found (``UTIS``, ``HeliOS``, ``grlm-centroid``, ...)
source             where the row comes from (``PAINT``, ``campaign``, ...)
record_id          the source's own id of the record (PAINT measurement id, campaign row id)
=================  ==========================================================================

Lines starting with ``#`` before the header are comments (provenance); they are kept on read.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from helicalib.errors import MeasurementError

COLUMNS: tuple[str, ...] = (
    "heliostat_id",
    "utc_time",
    "sun_e",
    "sun_n",
    "sun_u",
    "stroke1_mm",
    "stroke2_mm",
    "target_id",
    "spot_e_m",
    "spot_n_m",
    "spot_u_m",
    "target_u_m",
    "target_v_m",
    "spot_method",
    "source",
    "record_id",
)
_FLOATS = {"sun_e", "sun_n", "sun_u", "stroke1_mm", "stroke2_mm", "spot_e_m", "spot_n_m", "spot_u_m",
           "target_u_m", "target_v_m"}


@dataclass(frozen=True)
class Observation:
    heliostat_id: str
    utc_time: str
    sun_e: float
    sun_n: float
    sun_u: float
    stroke1_mm: float
    stroke2_mm: float
    target_id: str
    spot_e_m: float
    spot_n_m: float
    spot_u_m: float
    target_u_m: float
    target_v_m: float
    spot_method: str
    source: str
    record_id: str

    @property
    def sun_enu(self) -> np.ndarray:
        return np.array([self.sun_e, self.sun_n, self.sun_u])

    @property
    def strokes_mm(self) -> np.ndarray:
        return np.array([self.stroke1_mm, self.stroke2_mm])

    @property
    def spot_enu_m(self) -> np.ndarray:
        return np.array([self.spot_e_m, self.spot_n_m, self.spot_u_m])


assert tuple(f.name for f in fields(Observation)) == COLUMNS


def write_observations(path: str | Path, rows: Iterable[Observation], comments: Sequence[str] = ()) -> Path:
    """Write observations (and ``# comment`` lines before the header) to a CSV file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        for c in comments:
            f.write("# " + c.replace("\n", " ") + "\n")
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            d = asdict(r)
            w.writerow([repr(float(d[c])) if c in _FLOATS else d[c] for c in COLUMNS])
    return path


def read_observations(path: str | Path, heliostat_id: str | None = None) -> list[Observation]:
    """Read an observations CSV; optionally keep only one heliostat's rows.

    Raises :class:`MeasurementError` naming the file and line on a wrong header or value.
    """
    from helicalib.config import read_csv_rows

    path = Path(path)
    rows = read_csv_rows(path, MeasurementError, comments=True)
    if not rows:
        raise MeasurementError(f"{path}: empty file (expected the header {','.join(COLUMNS)})")
    header_line, header = rows[0]
    if tuple(h.strip() for h in header) != COLUMNS:
        raise MeasurementError(f"{path}: line {header_line}: expected the header {','.join(COLUMNS)}")
    out: list[Observation] = []
    for offset, row in rows[1:]:
        if len(row) != len(COLUMNS):
            raise MeasurementError(f"{path}: line {offset}: expected {len(COLUMNS)} fields, got {len(row)}")
        values = {}
        for name, raw in zip(COLUMNS, row):
            if name in _FLOATS:
                try:
                    v = float(raw)
                except ValueError:
                    raise MeasurementError(f"{path}: line {offset}: {name}: not a number: {raw[:40]!r}") from None
                if not math.isfinite(v):
                    raise MeasurementError(f"{path}: line {offset}: {name}: not finite")
                values[name] = v
            else:
                values[name] = raw.strip()
        if not values["heliostat_id"]:
            raise MeasurementError(f"{path}: line {offset}: heliostat_id: empty")
        if not values["target_id"]:
            raise MeasurementError(f"{path}: line {offset}: target_id: empty")
        if values["utc_time"]:
            _check_time(values["utc_time"], f"{path}: line {offset}: utc_time")
        if abs(math.hypot(values["sun_e"], values["sun_n"], values["sun_u"]) - 1.0) > 1e-3:
            raise MeasurementError(f"{path}: line {offset}: sun vector is not a unit vector")
        obs = Observation(**values)
        if heliostat_id is None or obs.heliostat_id == heliostat_id:
            out.append(obs)
    return out


def _check_time(value: str, where: str) -> None:
    from helicalib.errors import HelicalibError
    from helicalib.geometry.sun import parse_time

    try:
        parse_time(value)
    except HelicalibError as err:
        raise MeasurementError(f"{where}: {err}") from None


def observations_arrays(rows: Sequence[Observation]) -> dict[str, np.ndarray]:
    """Stacked arrays: ``strokes_mm`` (K,2), ``sun_enu`` (K,3), ``spot_enu`` (K,3), ``target_uv`` (K,2)."""
    return {
        "strokes_mm": np.array([r.strokes_mm for r in rows], dtype=float).reshape(-1, 2),
        "sun_enu": np.array([r.sun_enu for r in rows], dtype=float).reshape(-1, 3),
        "spot_enu": np.array([r.spot_enu_m for r in rows], dtype=float).reshape(-1, 3),
        "target_uv": np.array([[r.target_u_m, r.target_v_m] for r in rows], dtype=float).reshape(-1, 2),
    }
