"""Rectify frames onto a metric grid of the target board through the marks' homography.

The grid covers the whole board, row 0 at the top (v = +H/2), column 0 at the left (u = -W/2);
cell (row i, column j) has its centre at ``u = -W/2 + (j + ½)/s``, ``v = H/2 - (i + ½)/s`` with
``s`` cells per metre. Chosen near the board's largest pixel scale in the frame, the grid keeps
the frame's resolution without inventing detail, and a perspective-free grid lets the annex A
window and centroids work in metres (an image-space centroid of a large spot in a steep view is
biased by perspective).

Frames without lens distortion go through one ``cv2.warpPerspective``; with distortion a
``cv2.remap`` table (built once per grid) combines undistortion and homography.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helicalib.config import Target
from helicalib.vision.homography import MarksResult, distort_px

MAX_GRID_CELLS_PER_SIDE = 2048


@dataclass(frozen=True)
class BoardGrid:
    """A metric grid of the board and how to sample a frame onto it.

    Attributes
    ----------
    cells_per_m : float
        Grid resolution s [cells/m].
    shape : (int, int)
        (rows, columns) of the grid.
    size_m : (float, float)
        Board width, height [m].
    grid_to_image : ndarray (3, 3)
        Grid (column, row, 1) → ideal frame pixels (for ``warpPerspective`` with ``WARP_INVERSE_MAP``).
    maps : tuple or None
        ``cv2.remap`` maps when the camera has lens distortion.
    frame_shape : (int, int)
        (H, W) of the frames this grid samples.
    inside : ndarray bool (rows, columns)
        Cells whose board point lies inside the frame (one cell margin).
    """

    cells_per_m: float
    shape: tuple[int, int]
    size_m: tuple[float, float]
    grid_to_image: np.ndarray
    maps: tuple | None
    frame_shape: tuple[int, int]
    inside: np.ndarray

    @property
    def inside_f32(self) -> np.ndarray:
        """``inside`` as float32 0/1 (rows, columns), for masking by multiplication."""
        cached = self.__dict__.get("_inside_f32")
        if cached is None:
            cached = self.inside.astype(np.float32)
            object.__setattr__(self, "_inside_f32", cached)
        return cached

    # -- coordinates ----------------------------------------------------------------
    def cell_to_board(self, col_row: np.ndarray) -> np.ndarray:
        """Grid (column, row) (..., 2), fractional allowed → board (u, v) (..., 2) [m]."""
        cr = np.asarray(col_row, dtype=float)
        u = -self.size_m[0] / 2 + (cr[..., 0] + 0.5) / self.cells_per_m
        v = self.size_m[1] / 2 - (cr[..., 1] + 0.5) / self.cells_per_m
        return np.stack([u, v], axis=-1)

    def board_to_cell(self, uv_m: np.ndarray) -> np.ndarray:
        """Board (u, v) (..., 2) [m] → grid (column, row) (..., 2)."""
        uv = np.asarray(uv_m, dtype=float)
        col = (uv[..., 0] + self.size_m[0] / 2) * self.cells_per_m - 0.5
        row = (self.size_m[1] / 2 - uv[..., 1]) * self.cells_per_m - 0.5
        return np.stack([col, row], axis=-1)

    # -- sampling -------------------------------------------------------------------
    def sample(self, gray: np.ndarray, dtype=np.float32) -> np.ndarray:
        """A frame (H, W) sampled onto the grid (rows, columns), bilinear; outside the frame 0."""
        import cv2

        img = gray
        rows, cols = self.shape
        if self.maps is not None:
            out = cv2.remap(img, self.maps[0], self.maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                            borderValue=0)
        else:
            out = cv2.warpPerspective(img, self.grid_to_image, (cols, rows),
                                      flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return out if dtype is None else out.astype(dtype, copy=False)


def choose_cells_per_m(marks: MarksResult, target: Target, cells_per_m: float | None = None) -> float:
    """Grid resolution [cells/m]: ``cells_per_m`` or the board's largest pixel scale, capped."""
    s = float(cells_per_m) if cells_per_m else float(marks.px_per_m)
    if not np.isfinite(s) or s <= 0:
        s = 50.0
    cap = MAX_GRID_CELLS_PER_SIDE / max(target.size_m)
    return min(s, cap)


def board_grid(marks: MarksResult, target: Target, frame_shape: tuple[int, int],
               cells_per_m: float | None = None) -> BoardGrid:
    """The board grid for frames of ``frame_shape`` (H, W), from marks found in one of them."""
    import cv2

    s = choose_cells_per_m(marks, target, cells_per_m)
    width_m, height_m = target.size_m
    cols, rows = max(8, int(round(width_m * s))), max(8, int(round(height_m * s)))
    s = cols / width_m  # exact cells per metre along u; rows use the same scale
    rows = max(8, int(round(height_m * s)))
    size_m = (width_m, rows / s)
    # grid (col, row, 1) → board (u, v, 1)
    G = np.array([[1.0 / s, 0.0, -size_m[0] / 2 + 0.5 / s],
                  [0.0, -1.0 / s, size_m[1] / 2 - 0.5 / s],
                  [0.0, 0.0, 1.0]])
    M = np.linalg.inv(marks.homography) @ G
    M = M / M[2, 2]
    h, w = frame_shape
    maps = None
    if marks.camera_matrix is not None:
        cc, rr = np.meshgrid(np.arange(cols, dtype=np.float64), np.arange(rows, dtype=np.float64))
        p = np.stack([cc.ravel(), rr.ravel(), np.ones(cc.size)], axis=-1) @ M.T
        ideal = p[:, :2] / p[:, 2:3]
        dist = distort_px(ideal, marks.camera_matrix, marks.distortion)
        mx = dist[:, 0].reshape(rows, cols).astype(np.float32)
        my = dist[:, 1].reshape(rows, cols).astype(np.float32)
        maps = cv2.convertMaps(mx, my, cv2.CV_16SC2)
    probe = np.full((h, w), 255, np.uint8)
    grid = BoardGrid(s, (rows, cols), size_m, M, maps, (h, w), np.zeros((rows, cols), bool))
    inside = grid.sample(probe, dtype=None) == 255
    inside = cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                       borderValue=0).astype(bool)
    return BoardGrid(s, (rows, cols), size_m, M, maps, (h, w), inside)
