"""The named geometric error model of a heliostat and how it alters the nominal drive.

A parameter row ``params`` (shape (P,), or (N, P) for N heliostats) holds one value per entry of
:data:`PARAMETERS`, in that order, in the parameter's own unit. All zero = the nominal heliostat.
:func:`apply` turns nominal :class:`~helicalib.geometry.drives.DriveArrays` and pivots into the
effective ones, so every other function (forward beam, inverse aim, fit) uses one exact model.

How each parameter acts (a1, a2, n0 = nominal axis 1, axis 2 in the zero pose, zero-pose normal):

* ``stroke_offset_i_mm``: the actuator's true length is ``ℓ0 + (s + offset)/1000``: the commanded
  stroke is short of the real one by ``offset`` (folded into ``length_at_zero_m``).
* ``arm_scale_i``: the moving arm is ``rb · (1 + arm_scale_i)`` (relative deviation, 0 = nominal).
* ``canting_1_mrad``: n0 rotated about ``unit(a2 × n0)``: the mirror is not square to axis 2.
* ``canting_2_mrad``: n0 rotated about a2. This is exactly an angle offset of axis 2; it differs
  from ``stroke_offset_2_mm`` only through the linkage's non-linearity, so the data rarely
  separate the two (the fit's identifiability report says so).
* ``axis_nonorthogonality_mrad``: axis 2 and n0 rotated together about ``unit(a1 × a2)``: axis 2
  tilts away from perpendicular to axis 1.
* ``pedestal_tilt_e_mrad`` / ``pedestal_tilt_n_mrad`` / ``pedestal_yaw_mrad``: the whole drive
  (a1, a2, n0) rotated about east, north and up (R_e · R_n · R_u). For a tilt-roll drive (a1 = east)
  the east tilt equals an axis-1 angle offset and the yaw is the real mounting error; for an
  azimuth-elevation drive (a1 = down) the yaw equals an azimuth offset. ``pedestal_yaw_mrad`` is the
  thirteenth parameter, added because a tilt-roll pedestal's orientation error is a yaw.
* ``pivot_de_m`` / ``pivot_dn_m`` / ``pivot_du_m``: the true pivot is the nominal one plus this.
* ``backlash_1_mm`` / ``backlash_2_mm``: each actuator's dead band. The mirror sits where the
  strokes ``s − backlash/2 · approach`` would put it, ``approach`` = ±1 the direction of the
  actuator's last motion. These two act on the strokes, not on the drive, so :func:`apply` leaves
  them out: :class:`~helicalib.geometry.heliostat.HeliostatModel` applies them to commanded strokes
  when it is told the approach (:data:`BACKLASH`, :func:`backlash_shift_mm`). Without an approach
  (``None`` or 0) they act as the middle of the dead band, i.e. not at all.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from helicalib.geometry.drives import DriveArrays, cross3, rotate


@dataclass(frozen=True)
class Parameter:
    """One error-model parameter: ``name``, ``unit``, ``description``, ``prior_sigma`` (in ``unit``)."""

    name: str
    unit: str
    description: str
    prior_sigma: float


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("stroke_offset_1_mm", "mm", "zero offset of actuator 1 (main push rod)", 2.0),
    Parameter("stroke_offset_2_mm", "mm", "zero offset of actuator 2 (secondary push rod)", 2.0),
    Parameter("pedestal_tilt_e_mrad", "mrad", "pedestal tilt about east", 2.0),
    Parameter("pedestal_tilt_n_mrad", "mrad", "pedestal tilt about north", 2.0),
    Parameter("axis_nonorthogonality_mrad", "mrad", "axis 2 out of square with axis 1", 1.0),
    Parameter("canting_1_mrad", "mrad", "mirror normal rotated about a2 × n0 (not square to axis 2)", 1.5),
    Parameter("canting_2_mrad", "mrad", "mirror normal rotated about axis 2", 1.5),
    Parameter("pivot_de_m", "m", "pivot position error, east", 0.05),
    Parameter("pivot_dn_m", "m", "pivot position error, north", 0.05),
    Parameter("pivot_du_m", "m", "pivot position error, up", 0.05),
    Parameter("arm_scale_1", "1", "relative error of actuator 1's moving arm", 0.001),
    Parameter("arm_scale_2", "1", "relative error of actuator 2's moving arm", 0.001),
    Parameter("pedestal_yaw_mrad", "mrad", "pedestal rotation about up", 2.0),
    Parameter("backlash_1_mm", "mm", "dead band of actuator 1 (the mirror lags the encoder by half of it)", 0.5),
    Parameter("backlash_2_mm", "mm", "dead band of actuator 2", 0.5),
)
NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS)
P = len(PARAMETERS)
_INDEX = {name: i for i, name in enumerate(NAMES)}
PRIOR_SIGMA = np.array([p.prior_sigma for p in PARAMETERS], dtype=float)
BACKLASH: tuple[str, str] = ("backlash_1_mm", "backlash_2_mm")
"""The parameters that act on the strokes through the approach direction, not on the drive."""
GEOMETRIC: tuple[str, ...] = tuple(n for n in NAMES if n not in BACKLASH)
"""The parameters :func:`apply` uses: every one but :data:`BACKLASH`."""

EAST = np.array([1.0, 0.0, 0.0])
NORTH = np.array([0.0, 1.0, 0.0])
UP = np.array([0.0, 0.0, 1.0])


def zeros(n: int) -> np.ndarray:
    """Nominal (all-zero) parameters of ``n`` heliostats, shape (n, P)."""
    return np.zeros((int(n), P), dtype=float)


def index(name: str) -> int:
    """Column of parameter ``name``; KeyError naming the known parameters otherwise."""
    try:
        return _INDEX[name]
    except KeyError:
        raise KeyError(f"unknown error-model parameter {name!r}; known: {', '.join(NAMES)}") from None


def as_dict(row: np.ndarray) -> dict[str, float]:
    """One parameter row (P,) → ``{name: value}``."""
    row = np.asarray(row, dtype=float).reshape(-1)
    if row.size != P:
        raise ValueError(f"expected {P} error-model parameters, got {row.size}")
    return {name: float(v) for name, v in zip(NAMES, row)}


def from_dict(values: Mapping[str, float]) -> np.ndarray:
    """``{name: value}`` (missing names = 0) → one parameter row (P,). Unknown names raise KeyError."""
    row = np.zeros(P, dtype=float)
    for name, v in values.items():
        row[index(name)] = float(v)
    return row


def prior_sigma(overrides: Mapping[str, float] | None = None) -> np.ndarray:
    """Prior standard deviations (P,), the defaults of :data:`PARAMETERS` with ``overrides``."""
    sig = PRIOR_SIGMA.copy()
    for name, v in (overrides or {}).items():
        sig[index(name)] = float(v)
    return sig


def backlash_shift_mm(params: np.ndarray, approach: np.ndarray | None) -> np.ndarray | float:
    """Stroke shift (N, 2) [mm] from commanded to effective strokes for ``approach`` (N, 2) or (2,)
    of ±1 (0 = unknown, no shift): ``−backlash/2 · approach``; 0.0 when ``approach`` is None."""
    if approach is None:
        return 0.0
    params = np.asarray(params, dtype=float).reshape(-1, P)
    b = params[:, [_INDEX[BACKLASH[0]], _INDEX[BACKLASH[1]]]]
    return -0.5 * b * np.sign(np.asarray(approach, dtype=float))


def _col(params: np.ndarray, name: str) -> np.ndarray:
    return params[:, _INDEX[name]]


def _unit_or(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, v / np.where(norm > 1e-12, norm, 1.0), fallback)


def apply(drives: DriveArrays, pivots_enu: np.ndarray, params: np.ndarray) -> tuple[DriveArrays, np.ndarray]:
    """Effective drives and pivots of N heliostats with error parameters ``params`` (N, P).

    Returns ``(drives_eff, pivots_eff (N, 3))``; stroke ranges are those of the commanded strokes
    and stay unchanged.
    """
    params = np.asarray(params, dtype=float).reshape(len(drives), P)
    mrad = 1e-3
    a1, a2, n0 = drives.axis1_enu, drives.axis2_enu, drives.normal0_enu
    # mirror canting (relative to axis 2)
    u = _unit_or(cross3(a2, n0), np.broadcast_to(EAST, a2.shape))
    n0 = rotate(u, _col(params, "canting_1_mrad") * mrad, n0)
    n0 = rotate(a2, _col(params, "canting_2_mrad") * mrad, n0)
    # axis non-orthogonality: axis 2 with the mirror rotated about a1 × a2
    w = _unit_or(cross3(a1, a2), np.broadcast_to(UP, a2.shape))
    delta = _col(params, "axis_nonorthogonality_mrad") * mrad
    a2 = rotate(w, delta, a2)
    n0 = rotate(w, delta, n0)
    # pedestal: R_e · R_n · R_u applied to the whole drive
    shape = a1.shape
    for axis, name in ((UP, "pedestal_yaw_mrad"), (NORTH, "pedestal_tilt_n_mrad"), (EAST, "pedestal_tilt_e_mrad")):
        ang = _col(params, name) * mrad
        ax = np.broadcast_to(axis, shape)
        a1, a2, n0 = rotate(ax, ang, a1), rotate(ax, ang, a2), rotate(ax, ang, n0)
    offsets_mm = params[:, [_INDEX["stroke_offset_1_mm"], _INDEX["stroke_offset_2_mm"]]]
    scales = params[:, [_INDEX["arm_scale_1"], _INDEX["arm_scale_2"]]]
    eff = drives.replace(
        axis1_enu=a1, axis2_enu=a2, normal0_enu=n0,
        arm_moving_m=drives.arm_moving_m * (1.0 + scales),
        length_at_zero_m=drives.length_at_zero_m + offsets_mm / 1000.0,
    )
    dp = params[:, [_INDEX["pivot_de_m"], _INDEX["pivot_dn_m"], _INDEX["pivot_du_m"]]]
    return eff, np.asarray(pivots_enu, dtype=float) + dp
