"""``HeliostatModel``: N heliostats (pivots, drives, error parameters) as one immutable, vectorised model.

Forward: strokes → axis angles → normal → beam from the mirror centre → spot on a target.
Inverse: sun + aim point → the normal (with the mirror offset) → axis angles → strokes, solved
exactly with the error model, so a model whose parameters equal a heliostat's true errors puts that
heliostat's beam on the aim point.

Each method runs as one compiled kernel of :mod:`helicalib.geometry.kernels` (below
``kernels.MAX_ROWS`` heliostats, inputs of 1 or N rows); ``reference=True`` runs the numpy code,
the reference those kernels are tested against, which also takes any other broadcasting.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.drives import (
    DriveArrays,
    angles_to_normal,
    angles_to_strokes,
    kernel_rows,
    kernels,
    normal_to_angles,
    strokes_in_range,
    strokes_to_angles,
    use_kernels,
)

_BACKLASH_COLS = [em.index(n) for n in em.BACKLASH]


@dataclass(frozen=True)
class AimSolution:
    """Strokes that put each heliostat's beam on its aim point.

    Attributes
    ----------
    strokes_mm : (N, 2) commanded strokes [mm]; NaN where unreachable
    angles_rad : (N, 2) axis angles of the effective drive [rad]
    normal_enu : (N, 3) the mirror normal wanted
    in_range : (N,) bool, both strokes inside their ranges (implies reachable)
    reachable : (N,) bool, the drive can point the normal there (triangle angles inside (0, π))
    """

    strokes_mm: np.ndarray
    angles_rad: np.ndarray
    normal_enu: np.ndarray
    in_range: np.ndarray
    reachable: np.ndarray


def _rows(v, n: int, width: int) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return np.broadcast_to(a, (n, width)) if a.ndim == 1 else a


class HeliostatModel:
    """N heliostats with a geometric error model; immutable (methods return new models).

    Attributes
    ----------
    ids : tuple[str, ...]
    pivots_enu : (N, 3) nominal pivot positions [m, ENU]
    drives : DriveArrays, nominal drives
    params : (N, P) error-model parameters (order of ``errors.PARAMETERS``)
    drives_eff : DriveArrays with the errors applied; ``pivots_eff_enu`` (N, 3) likewise
    """

    __slots__ = ("ids", "pivots_enu", "drives", "params", "drives_eff", "pivots_eff_enu", "_backlash_mm", "_packed")

    def __init__(self, ids: Sequence[str], pivots_enu: np.ndarray, drives: DriveArrays, params: np.ndarray | None = None):
        n = len(drives)
        pivots = np.asarray(pivots_enu, dtype=float).reshape(n, 3)
        p = em.zeros(n) if params is None else np.array(params, dtype=float).reshape(n, em.P)
        if len(ids) != n:
            raise ValueError(f"{len(ids)} ids for {n} drives")
        eff, piv = em.apply(drives, pivots, p)
        for name, value in (("ids", tuple(ids)), ("pivots_enu", pivots), ("drives", drives), ("params", p),
                            ("drives_eff", eff), ("pivots_eff_enu", piv),
                            ("_backlash_mm", p[:, _BACKLASH_COLS])):
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "_packed", None)

    def __setattr__(self, name, value):
        raise AttributeError("HeliostatModel is immutable; use with_params() or subset()")

    def __len__(self) -> int:
        return len(self.ids)

    def __repr__(self) -> str:
        return f"HeliostatModel({len(self)} heliostats, errors {'set' if np.any(self.params) else 'zero'})"

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_config(cls, cfg, heliostat_ids: Sequence[str] | None = None, params: np.ndarray | None = None) -> HeliostatModel:
        """Model of the heliostats ``heliostat_ids`` (default: all, in config order) of a ``FieldConfig``."""
        ids = [h.id for h in cfg.heliostats] if heliostat_ids is None else list(heliostat_ids)
        pivots = np.array([cfg.heliostat(i).position_enu_m for i in ids], dtype=float).reshape(-1, 3)
        drives = DriveArrays.from_drives([cfg.drive_of(i) for i in ids])
        return cls(ids, pivots, drives, params)

    def with_params(self, params: np.ndarray) -> HeliostatModel:
        """The same heliostats with other error parameters (N, P) (or (P,) for all)."""
        p = np.broadcast_to(np.asarray(params, dtype=float), (len(self), em.P))
        return HeliostatModel(self.ids, self.pivots_enu, self.drives, p)

    def subset(self, indices) -> HeliostatModel:
        """Heliostats ``indices`` (integer array or slice) as a new model.

        The effective drives and pivots are this model's rows (the errors act heliostat by
        heliostat, so they are the values a new model of those rows would compute), not computed
        again: a model of one heliostat out of 10⁴ costs one row."""
        idx = np.arange(len(self))[indices] if isinstance(indices, slice) else np.asarray(indices, dtype=int).reshape(-1)
        out = object.__new__(HeliostatModel)
        for name, value in (("ids", tuple(map(self.ids.__getitem__, idx.tolist()))), ("pivots_enu", self.pivots_enu[idx]),
                            ("drives", self.drives.take(idx)), ("params", self.params[idx]),
                            ("drives_eff", self.drives_eff.take(idx)), ("pivots_eff_enu", self.pivots_eff_enu[idx]),
                            ("_backlash_mm", self._backlash_mm[idx])):
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(out, name, value)
        object.__setattr__(out, "_packed", None if self._packed is None else self._packed[idx])
        return out

    def repeat(self, counts) -> HeliostatModel:
        """Each heliostat repeated ``counts`` times (for evaluating many observations in one call)."""
        idx = np.repeat(np.arange(len(self)), counts)
        return self.subset(idx)

    # -- forward ------------------------------------------------------------------------
    @property
    def has_dead_bands(self) -> bool:
        """Whether any heliostat has a non-zero backlash parameter (then ``approach`` matters)."""
        return bool(np.any(self._backlash_mm))

    @property
    def mirror_offset_m(self) -> np.ndarray:
        return self.drives.mirror_offset_m

    def effective_strokes(self, strokes_mm: np.ndarray, approach: np.ndarray | None = None) -> np.ndarray:
        """Strokes (N, 2) [mm] at which the mirror sits for commanded strokes (N, 2) after each
        actuator last moved in ``approach`` (N, 2) or (2,) of ±1: the backlash parameters shift
        them by half the dead band against the approach. ``approach`` None: no shift."""
        return np.asarray(strokes_mm, dtype=float) + em.backlash_shift_mm(self.params, approach)

    def _kernel_args(self, approach, *rows: tuple[np.ndarray, int]) -> list | None:
        """The packed model, the row arguments ``(value, width)`` and ``approach`` as kernel inputs
        (1 or N rows), or None: too many heliostats for the kernels, or shapes that need numpy's
        broadcasting."""
        n = len(self)
        if not use_kernels(n):
            return None
        out = [kernel_rows(v, w, n) for v, w in rows]
        out.append(kernels().NO_APPROACH if approach is None else kernel_rows(approach, 2, n))
        if any(o is None for o in out):
            return None
        if self._packed is None:  # once per model: a one-heliostat model is asked many times
            object.__setattr__(self, "_packed", kernels().pack_model(self.drives_eff.packed, self.pivots_eff_enu,
                                                                     self._backlash_mm))
        return [self._packed, *out]

    def angles(self, strokes_mm: np.ndarray, approach: np.ndarray | None = None, reference: bool = False
               ) -> np.ndarray:
        """Effective axis angles (N, 2) [rad] for commanded strokes (N, 2) [mm]; NaN if impossible.
        ``approach``: the last motion of each actuator (±1), for the backlash parameters."""
        k = None if reference else self._kernel_args(approach, (strokes_mm, 2))
        if k is not None:
            return kernels().linkage(*k, True)
        return strokes_to_angles(self.drives_eff, self.effective_strokes(strokes_mm, approach), reference=True)

    def normal(self, strokes_mm: np.ndarray, approach: np.ndarray | None = None, reference: bool = False
               ) -> np.ndarray:
        """Mirror normal (N, 3), ENU, for commanded strokes (N, 2) [mm], errors applied."""
        k = None if reference else self._kernel_args(approach, (strokes_mm, 2))
        if k is not None:
            return kernels().model_normal(*k)
        return angles_to_normal(self.drives_eff, self.angles(strokes_mm, approach, reference=True), reference=True)

    def beam(self, strokes_mm: np.ndarray, sun_enu: np.ndarray, approach: np.ndarray | None = None,
             reference: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Reflected beam for strokes (N, 2) [mm] and sun (3,) or (N, 3).

        Returns ``(origin_enu (N, 3), direction_enu (N, 3))``: the mirror centre and unit direction.
        """
        k = None if reference else self._kernel_args(approach, (strokes_mm, 2), (sun_enu, 3))
        if k is not None:
            return kernels().model_beam(*k)
        n = self.normal(strokes_mm, approach, reference=True)
        s = optics.unit(_rows(sun_enu, len(self), 3))
        return optics.mirror_centre(self.pivots_eff_enu, n, self.mirror_offset_m), optics.reflect(s, n)

    def spot_on_target(self, strokes_mm: np.ndarray, sun_enu: np.ndarray, target,
                       approach: np.ndarray | None = None, reference: bool = False) -> np.ndarray:
        """Beam centre on the target plane(s), target frame (u, v), shape (N, 2) [m]; NaN if missed.

        ``target`` is one ``config.Target`` or a sequence of N of them (one per heliostat).
        """
        k = None if reference else self._kernel_args(approach, (strokes_mm, 2), (sun_enu, 3))
        planes = None if k is None else _planes(target, len(self))
        if planes is not None:
            return kernels().model_spot(*k, *planes)
        origin, direction = self.beam(strokes_mm, sun_enu, approach, reference=True)
        if isinstance(target, Sequence) and not isinstance(target, str):
            uv = np.full((len(self), 2), np.nan)
            for t in {id(t): t for t in target}.values():
                sel = np.array([tt is t for tt in target])
                uv[sel] = optics.intersect_target(origin[sel], direction[sel], t)[0]
            return uv
        return optics.intersect_target(origin, direction, target)[0]

    # -- inverse ------------------------------------------------------------------------
    def normal_to_strokes(self, normal_enu: np.ndarray, approach: np.ndarray | None = None, reference: bool = False
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Normal (N, 3) → (strokes_mm (N, 2), angles_rad (N, 2), reachable (N,)), errors applied:
        the strokes to command, arriving in ``approach`` (±1 per actuator; None: no backlash)."""
        k = None if reference else self._kernel_args(approach, (normal_enu, 3))
        if k is not None:
            return kernels().model_normal_to_strokes(*k)
        angles, reachable = normal_to_angles(self.drives_eff, normal_enu, reference=True)
        strokes = (angles_to_strokes(self.drives_eff, angles, reference=True)
                   - em.backlash_shift_mm(self.params, approach))
        reachable = reachable & np.all(np.isfinite(strokes), axis=-1)
        return strokes, angles, reachable

    def strokes_for_aim(self, sun_enu: np.ndarray, aim_enu: np.ndarray, approach: np.ndarray | None = None,
                        reference: bool = False) -> AimSolution:
        """Strokes that put the beam on ``aim_enu`` ((3,) or (N, 3) [m]) for the sun (3,) or (N, 3),
        with each actuator arriving in ``approach`` ((N, 2) or (2,) of ±1; None: the backlash
        parameters are left out, as for the middle of the dead band)."""
        k = None if reference else self._kernel_args(approach, (sun_enu, 3), (aim_enu, 3))
        if k is not None:
            strokes, angles, normal, in_range, reachable = kernels().model_strokes_for_aim(
                *k, optics.AIM_ITERATIONS)
            return AimSolution(strokes_mm=strokes, angles_rad=angles, normal_enu=normal, in_range=in_range,
                               reachable=reachable)
        n_rows = len(self)
        s = optics.unit(_rows(sun_enu, n_rows, 3))
        t = _rows(aim_enu, n_rows, 3)
        normal = optics.aim_normal(self.pivots_eff_enu, s, t, self.mirror_offset_m, reference=True)
        strokes, angles, reachable = self.normal_to_strokes(normal, approach, reference=True)
        in_range = reachable & np.all(strokes_in_range(self.drives, strokes), axis=-1)
        return AimSolution(strokes_mm=strokes, angles_rad=angles, normal_enu=normal, in_range=in_range,
                           reachable=reachable)


def _planes(target, n_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(centres (T, 3), frames (T, 3, 3), which (N,)) of one target or a sequence of ``n_rows``
    targets (one per heliostat), for ``kernels.model_spot``; None for a sequence of another length."""
    if isinstance(target, Sequence) and not isinstance(target, str):
        if len(target) != n_rows:
            return None
        unique = list({id(t): t for t in target}.values())
        pos = {id(t): i for i, t in enumerate(unique)}
        which = np.array([pos[id(t)] for t in target], dtype=np.int64)
    else:
        unique = [target]
        which = np.zeros(n_rows, dtype=np.int64)
    centres = np.array([t.center_enu_m for t in unique], dtype=float).reshape(-1, 3)
    frames = np.ascontiguousarray(np.array([t.frame_enu for t in unique], dtype=float).reshape(-1, 3, 3))
    return centres, frames, which


def tracking_approach(strokes_now_mm: np.ndarray, strokes_later_mm: np.ndarray) -> np.ndarray:
    """Direction (±1) in which each actuator moves between two stroke sets of a tracking heliostat
    (the approach its backlash sits in while tracking); +1 where it stands still or is unknown."""
    d = np.sign(np.asarray(strokes_later_mm, dtype=float) - np.asarray(strokes_now_mm, dtype=float))
    return np.where(np.isfinite(d) & (d != 0), d, 1.0)


def stroke_sweep(model: HeliostatModel, sun_enu: np.ndarray, aim_enu: np.ndarray) -> dict[str, np.ndarray]:
    """Strokes each heliostat needs for its aim at many sun positions, and their margins.

    Parameters
    ----------
    model : N heliostats
    sun_enu : (T, 3) sun vectors
    aim_enu : (3,) or (N, 3) aim points [m]

    Returns
    -------
    dict with ``strokes_mm`` (T, N, 2), ``margin_mm`` (T, N, 2) (distance inside the stroke range,
    negative outside, −inf where unreachable) and ``in_range`` (T, N).
    """
    from helicalib.geometry.drives import stroke_margin_mm

    sun = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    t, n = len(sun), len(model)
    aims = np.broadcast_to(np.asarray(aim_enu, dtype=float), (n, 3))
    big = model.subset(np.tile(np.arange(n), t))
    sol = big.strokes_for_aim(np.repeat(sun, n, axis=0), np.tile(aims, (t, 1)))
    margin = stroke_margin_mm(big.drives, sol.strokes_mm)
    margin = np.where(np.isfinite(margin), margin, -np.inf)
    return {"strokes_mm": sol.strokes_mm.reshape(t, n, 2), "margin_mm": margin.reshape(t, n, 2),
            "in_range": sol.in_range.reshape(t, n)}
