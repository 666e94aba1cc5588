"""The dark pattern of a target board in its own plane, for the renderers: what is black where.

``marks`` of a target is either T/GRLM's four right-angle marks (:func:`mark_mask`) or the
nine round dots of a 田 board (``kind: dots``, :func:`dot_mask`); :func:`dark_mask` is either. Both
renderers (``sim.camera`` for the simulated plant, ``sim.render`` for tests and benchmarks) draw
the board's dark pattern from here.
"""

from __future__ import annotations

import numpy as np


def mark_mask(target, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """True where board points (u, v) [m] lie on one of the four L marks (vertex inward, two arms)."""
    out = np.zeros(np.broadcast(u, v).shape, dtype=bool)
    if target.marks is None:
        return out
    arm, thick = target.marks.arm_m, target.marks.thickness_m
    for vu, vv in target.marks.vertices_m:
        su, sv = -np.sign(vu) or 1.0, -np.sign(vv) or 1.0   # inward directions
        a = (u - vu) * su                                   # distance inward along u
        b = (v - vv) * sv
        arm_u = (a >= 0) & (a <= arm) & (b >= 0) & (b <= thick)
        arm_v = (b >= 0) & (b <= arm) & (a >= 0) & (a <= thick)
        out |= arm_u | arm_v
    return out


def dot_mask(marks, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """True where board points (u, v) [m] lie on one of the nine dots of ``marks`` (``kind: dots``)."""
    out = np.zeros(np.broadcast(u, v).shape, dtype=bool)
    for (cu, cv), d in zip(marks.dots_m(), marks.diameters_m()):
        out |= (u - cu) ** 2 + (v - cv) ** 2 <= (d / 2) ** 2
    return out


def dark_mask(target, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """True where board points (u, v) [m] lie on the board's marks, whichever their kind."""
    if target.marks is not None and target.marks.kind == "dots":
        return dot_mask(target.marks, u, v)
    return mark_mask(target, u, v)
