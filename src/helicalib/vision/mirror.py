"""The centre of a spot cut by the board's rim, from the symmetry of its visible part.

A beam's spot (the mirror's footprint blurred by the sun shape and slope errors) is centrally
symmetric. Where the rim cuts it, the part of the board that mirrors onto the board about a point
``c`` is itself symmetric about ``c``; the intensity centroid of the spot inside it is ``c`` exactly
when ``c`` is the spot's centre. :func:`mirror_centre` finds that fixed point: the region is
rebuilt about the centroid (on half cells) until it stops moving, then one Newton step per axis
with the slope of the centroid over the region's centre.

That slope is the estimate's conditioning: a region that holds the spot's fall-off pins the centre
(slope near 0); a region inside a flat top, or one that sees only the spot's peak, barely moves the
centroid when moved (slope near 1), and a centre error is amplified 1 / (1 − slope) times. A
centre is accepted only with the slope at most ``max_slope`` on both axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ITERATIONS = 30
"""Most rebuilds of the region before the Newton step."""


@dataclass(frozen=True)
class MirrorCentre:
    """The symmetric-region estimate: ``center_cell`` (column, row), the centroid's ``slope`` per
    axis, the spot's cells inside the region (``area_cells``) and the ``asymmetry`` of the spot there
    about the centre: Σ|I − I mirrored| / Σ(I + I mirrored) (0 for a symmetric spot, noise aside)."""

    center_cell: np.ndarray
    slope: np.ndarray
    area_cells: int
    asymmetry: float


def mirrored(mask: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """``mask`` reflected about the cell point ``m2 / 2`` (``m2`` = doubled (column, row), integers):
    ``out[r, j] = mask[m2_row − r, m2_col − j]``, False where that lies off the grid."""
    rows, cols = mask.shape
    out = np.zeros_like(mask)  # False / 0 off the grid
    mc, mr = int(m2[0]), int(m2[1])
    j0, j1 = max(0, mc - cols + 1), min(cols - 1, mc)
    r0, r1 = max(0, mr - rows + 1), min(rows - 1, mr)
    if j1 < j0 or r1 < r0:
        return out
    out[r0:r1 + 1, j0:j1 + 1] = mask[mr - r1: mr - r0 + 1, mc - j1: mc - j0 + 1][::-1, ::-1]
    return out


def _centroid(I: np.ndarray, seen: np.ndarray, m2: np.ndarray) -> tuple[np.ndarray, int] | None:
    """Intensity centroid of ``I`` over the cells of ``seen`` whose mirror about ``m2 / 2`` is seen too."""
    region = seen & mirrored(seen, m2)
    W = np.where(region, I, 0.0)
    tot = float(W.sum())
    if tot <= 0:
        return None
    c = np.array([W.sum(axis=0) @ np.arange(I.shape[1]), W.sum(axis=1) @ np.arange(I.shape[0])]) / tot
    return c, int(np.count_nonzero(W > 0))


def mirror_centre(I: np.ndarray, seen: np.ndarray, start_cell: np.ndarray) -> MirrorCentre | None:
    """The spot's centre from the symmetry of what of it is seen.

    ``I`` the spot's intensity on the grid (0 off the spot), ``seen`` the cells that show it (the
    board less its rim and dark marks), ``start_cell`` a first guess (column, row). None when the
    region holds none of the spot.
    """
    m2 = np.rint(2.0 * np.asarray(start_cell, dtype=float)).astype(int)
    for _ in range(ITERATIONS):
        got = _centroid(I, seen, m2)
        if got is None:
            return None
        new = np.rint(2.0 * got[0]).astype(int)
        if np.array_equal(new, m2):
            break
        m2 = new
    got = _centroid(I, seen, m2)
    if got is None:
        return None
    g, area = got
    base = m2 / 2.0
    slope = np.ones(2)
    for ax in (0, 1):
        step = np.zeros(2, dtype=int)
        step[ax] = 1
        hi, lo = _centroid(I, seen, m2 + step), _centroid(I, seen, m2 - step)
        if hi is None or lo is None:
            return None
        slope[ax] = hi[0][ax] - lo[0][ax]  # the region's centre moved by one cell in all
    centre = base + (g - base) / np.maximum(1.0 - slope, 1e-6)
    return MirrorCentre(centre, slope, area, asymmetry(I, seen, np.rint(2.0 * centre).astype(int)))


def asymmetry(I: np.ndarray, seen: np.ndarray, m2: np.ndarray) -> float:
    """Σ|I − I'| / Σ(I + I') over the cells seen together with their mirror about ``m2 / 2``, I' the
    mirrored intensity; 1 when nothing is seen so."""
    region = seen & mirrored(seen, m2)
    a = np.where(region, I, 0.0)
    b = np.where(region, mirrored(I, m2), 0.0)
    tot = float(a.sum() + b.sum())
    return float(np.abs(a - b).sum()) / tot if tot > 0 else 1.0
