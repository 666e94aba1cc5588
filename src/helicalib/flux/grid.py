"""The metric grid on a target board on which flux maps live.

A :class:`BoardGrid` covers the white board (``Target.size_m``) with square cells of side
``cell_m``. Arrays on the grid have shape ``(nv, nu)`` and are stored the way the camera sees the
board: row 0 is the top of the board (largest v), column 0 its left edge (smallest u), so an
``imshow`` of a flux map looks like the camera frame. Coordinates are the target frame of
``FIELD_CONFIG.md``: u to the right as seen from the field, v up the board, metres from the
board centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BoardGrid:
    """Cell centres of a metric grid on the board.

    Attributes
    ----------
    u_m : np.ndarray, shape (nu,)
        Cell-centre u coordinates, increasing [m, target frame].
    v_m : np.ndarray, shape (nv,)
        Cell-centre v coordinates, *decreasing* (row 0 = top of the board) [m, target frame].
    cell_m : float
        Side of one square cell [m].
    """

    u_m: np.ndarray
    v_m: np.ndarray
    cell_m: float

    @property
    def shape(self) -> tuple[int, int]:
        """``(nv, nu)``, the shape of every array on this grid."""
        return (self.v_m.size, self.u_m.size)

    @property
    def cell_area_m2(self) -> float:
        """Area of one cell [m²]."""
        return self.cell_m * self.cell_m

    def mesh_m(self) -> tuple[np.ndarray, np.ndarray]:
        """``(U, V)``, each of shape (nv, nu): the cell-centre coordinates [m]."""
        return np.meshgrid(self.u_m, self.v_m)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """``(u_left, u_right, v_bottom, v_top)`` of the covered area [m], for ``imshow(extent=...)``."""
        h = self.cell_m / 2
        return (float(self.u_m[0] - h), float(self.u_m[-1] + h), float(self.v_m[-1] - h), float(self.v_m[0] + h))


def board_grid(size_m: tuple[float, float], cell_m: float) -> BoardGrid:
    """The grid of cells of side ``cell_m`` that covers a board of ``size_m`` = (width, height).

    The number of cells along each side is ``round(side / cell_m)`` (at least 1); the cell side is
    then adjusted so that the cells tile the board exactly.

    Parameters
    ----------
    size_m : (float, float)
        Board width (along u) and height (along v) [m].
    cell_m : float
        Wanted cell side [m], > 0.

    Returns
    -------
    BoardGrid
    """
    width, height = float(size_m[0]), float(size_m[1])
    if cell_m <= 0 or width <= 0 or height <= 0:
        raise ValueError(f"board size {size_m} and cell {cell_m} must be positive")
    nu = max(1, int(round(width / cell_m)))
    cell = width / nu
    nv = max(1, int(round(height / cell)))
    # keep square cells: the v extent may differ from the board height by under half a cell
    u = (np.arange(nu) + 0.5) * cell - width / 2
    v = nv * cell / 2 - (np.arange(nv) + 0.5) * cell
    return BoardGrid(u_m=u, v_m=v, cell_m=cell)
