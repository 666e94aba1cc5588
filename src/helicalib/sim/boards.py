"""The dark pattern of a target board in its own plane, for the renderers: what is black where.

``marks`` of a target is either T/GRLM's four right-angle marks (``sim.camera.mark_mask``) or the
nine round dots of a 田 board (``kind: dots``, :func:`dot_mask`).
"""

from __future__ import annotations

import numpy as np


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
    from helicalib.sim.camera import mark_mask

    return mark_mask(target, u, v)
