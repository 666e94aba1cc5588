"""A board's homography image ↔ board, shared by both kinds of marks (L marks and dots).

:class:`MarksResult` is what either finder returns: the homography from ideal (undistorted)
image pixels to board metres, its RMS reprojection error, the board centre and scale in the frame.
The camera model (intrinsics and lens distortion) maps frame pixels to ideal pixels and back;
:func:`image_to_board` / :func:`board_to_image` go either way with distortion handled.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from helicalib.config import Camera


@dataclass(frozen=True)
class MarksResult:
    """Marks found in a frame.

    Attributes
    ----------
    found : bool
    reason : str
        "ok" or why not ("marks_not_found", "reprojection").
    message : str
        One sentence.
    vertices_px : ndarray (4, 2)
        Outer vertices TL, TR, BR, BL [px, frame pixels, sub-pixel]; NaN when not found.
    homography : ndarray (3, 3)
        Ideal image pixels (x, y, 1) → board (u, v, 1) [m]; NaN when not found.
    reprojection_px : float
        RMS distance between the 24 refined corners and the model corners mapped by the homography [px].
    center_px : ndarray (2,)
        The board centre (u, v) = (0, 0) in the frame [px] (T/GRLM annex A.1 (x0, y0)).
    corners_px : ndarray (24, 2)
        All six corners of each L (TL first), frame pixels.
    px_per_m : float
        Largest board scale at the centre [px/m].
    """

    found: bool
    reason: str
    message: str
    vertices_px: np.ndarray = field(default_factory=lambda: np.full((4, 2), np.nan))
    homography: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    reprojection_px: float = float("nan")
    center_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    corners_px: np.ndarray = field(default_factory=lambda: np.full((24, 2), np.nan))
    px_per_m: float = float("nan")
    camera_matrix: np.ndarray | None = None
    distortion: np.ndarray | None = None
    kind: str = "right-angles"
    """The board's marks kind (``marks.kind`` of the target): "right-angles" or "dots"."""
    dots_px: np.ndarray | None = None
    """Dot boards: the nine dot centres (9, 2) [frame px], rows top to bottom, NaN for a dot not used."""

    def to_json(self) -> dict:
        def lst(a):
            return None if a is None or not np.all(np.isfinite(a)) else np.round(np.asarray(a, float), 4).tolist()

        extra = {} if self.dots_px is None else {
            "dots_px": [None if not np.all(np.isfinite(p)) else np.round(p, 4).tolist() for p in self.dots_px]}
        return {"found": self.found, "reason": self.reason, "message": self.message, "kind": self.kind, **extra,
                "vertices_px": lst(self.vertices_px), "center_px": lst(self.center_px),
                "reprojection_px": None if not np.isfinite(self.reprojection_px) else round(self.reprojection_px, 4),
                "px_per_m": None if not np.isfinite(self.px_per_m) else round(self.px_per_m, 3)}


def camera_model(camera: Camera | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(K, distortion) when the camera has intrinsics and a non-zero distortion, else (None, None)."""
    if camera is None or camera.intrinsics is None or camera.distortion is None:
        return None, None
    d = np.asarray(camera.distortion, dtype=float)
    if not np.any(d != 0):
        return None, None
    return camera.camera_matrix, d


def undistort_px(points_px: np.ndarray, K, dist) -> np.ndarray:
    """Frame pixels (N, 2) → ideal pixels (N, 2) (identity without distortion)."""
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    if K is None:
        return pts
    import cv2

    return cv2.undistortPoints(pts.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)


def distort_px(points_px: np.ndarray, K, dist) -> np.ndarray:
    """Ideal pixels (N, 2) → frame pixels (N, 2) (identity without distortion)."""
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    if K is None:
        return pts
    import cv2

    norm = np.column_stack([(pts[:, 0] - K[0, 2]) / K[0, 0], (pts[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(pts))])
    px, _ = cv2.projectPoints(norm.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    return px.reshape(-1, 2)


def apply_homography(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (N, 2) through the homography H; a point H sends to infinity (a degenerate fit of
    bad marks) comes out non-finite: candidate layouts with such points are not matched, and a
    non-finite reprojection error is refused."""
    p = np.column_stack([pts, np.ones(len(pts))]) @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[:, :2] / p[:, 2:3]


def board_to_image(marks: MarksResult, uv_m: np.ndarray) -> np.ndarray:
    """Board points (N, 2) [m] → frame pixels (N, 2)."""
    ideal = apply_homography(np.linalg.inv(marks.homography), np.atleast_2d(np.asarray(uv_m, dtype=float)))
    return distort_px(ideal, marks.camera_matrix, marks.distortion)


def image_to_board(marks: MarksResult, points_px: np.ndarray) -> np.ndarray:
    """Frame pixels (N, 2) → board points (N, 2) [m]."""
    ideal = undistort_px(np.atleast_2d(np.asarray(points_px, dtype=float)), marks.camera_matrix, marks.distortion)
    return apply_homography(marks.homography, ideal)


def finish_homography(Hib: np.ndarray, model_m: np.ndarray, ideal_px: np.ndarray, K, dist,
                      max_reprojection_px: float, found_text: str, **extra) -> MarksResult:
    """The result of a fitted homography ``Hib`` (ideal image → board) of the points ``ideal_px``
    (N, 2) whose board positions are ``model_m`` (N, 2): RMS reprojection error, the board centre
    and scale in the frame, and the reprojection limit. ``extra`` fills the kind's own fields
    (``vertices_px`` at least)."""
    Hbi = np.linalg.inv(Hib)
    reproj = float(np.sqrt(np.mean(np.sum((apply_homography(Hbi, model_m) - ideal_px) ** 2, axis=1))))
    centre_ideal = apply_homography(Hbi, np.zeros((1, 2)))
    # board scale at the centre: image length of 1 m along u and along v
    J = apply_homography(Hbi, np.array([[0.5, 0.0], [-0.5, 0.0], [0.0, 0.5], [0.0, -0.5]]))
    px_per_m = float(max(np.linalg.norm(J[0] - J[1]), np.linalg.norm(J[2] - J[3])))
    kw = dict(homography=Hib / Hib[2, 2], reprojection_px=reproj, center_px=distort_px(centre_ideal, K, dist)[0],
              px_per_m=px_per_m, camera_matrix=K, distortion=dist, **extra)
    if not np.isfinite(reproj) or reproj > max_reprojection_px:  # NaN compares False: refuse it explicitly
        return MarksResult(False, "reprojection",
                           f"the marks fit the board layout only to {reproj:.2f} px RMS "
                           f"(limit {max_reprojection_px:.2f} px).", **kw)
    return MarksResult(True, "ok", f"{found_text}, reprojection {reproj:.3f} px RMS.", **kw)
