"""The four black right-angle marks of a target board → homography image ↔ board (T/GRLM annex A.1).

Method
------
1. Dark blobs: adaptive mean threshold (robust to uneven light and to a bright spot nearby),
   external contours.
2. L-shape test: the contour simplifies to a hexagon with exactly one reflex (inner) corner and a
   solidity (area / hull area) of an L; its outer vertex is the corner opposite the reflex one.
3. Layout: every choice of four candidates (ordered TL, TR, BR, BL by their angle about their
   centroid, image y down) must have each L opening toward the centroid; the homography of the
   four outer vertices must then predict the other 20 L corners onto detected corners. The best
   fitting choice wins; none fitting means ``found=False`` — never a wrong homography.
4. Sub-pixel: all 24 corners are refined with ``cv2.cornerSubPix`` (window below half the mark
   thickness), undistorted when the camera has intrinsics and distortion, and the final homography
   is the least-squares fit of the 24 model corners (board metres); its RMS reprojection error in
   pixels is a quality figure.

The homography acts on *ideal* (undistorted) pixel coordinates; with no distortion those are the
frame's pixels. Use :func:`~helicalib.vision.homography.image_to_board` /
:func:`~helicalib.vision.homography.board_to_image` to go either way with distortion handled.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from helicalib.config import Camera, Target
from helicalib.vision.homography import (MarksResult, apply_homography, board_to_image, camera_model, distort_px,
                                        finish_homography, image_to_board, undistort_px)

__all__ = ["MarksResult", "board_to_image", "find_marks", "image_to_board", "mark_model_m"]


def mark_model_m(target: Target) -> np.ndarray:
    """The six corners of each L in board metres, shape (4, 6, 2).

    Order per mark: outer vertex, end of the horizontal arm (outer, inner), reflex corner,
    end of the vertical arm (inner, outer).
    """
    m = target.marks
    out = np.zeros((4, 6, 2))
    for k, (pu, pv) in enumerate(m.vertices_m):
        du = np.array([-np.sign(pu), 0.0])
        dv = np.array([0.0, -np.sign(pv)])
        p = np.array([pu, pv])
        a, t = m.arm_m, m.thickness_m
        out[k] = [p, p + a * du, p + a * du + t * dv, p + t * du + t * dv, p + t * du + a * dv, p + a * dv]
    return out


# ---------------------------------------------------------------------------- candidates
@dataclass(frozen=True)
class _LCandidate:
    corners: np.ndarray  # (6, 2) starting at the outer vertex, in contour order
    outer: np.ndarray  # (2,)
    inward: np.ndarray  # unit vector from outer vertex toward the reflex corner
    thickness_px: float
    area_px: float


def _l_candidate(contour: np.ndarray) -> _LCandidate | None:
    import cv2

    area = cv2.contourArea(contour)
    hull_area = cv2.contourArea(cv2.convexHull(contour))
    if area < 12 or hull_area <= 0:
        return None
    solidity = area / hull_area
    if not 0.35 <= solidity <= 0.85:
        return None
    perimeter = cv2.arcLength(contour, True)
    for eps in (0.02, 0.03, 0.015, 0.04, 0.05):
        poly = cv2.approxPolyDP(contour, eps * perimeter, True).reshape(-1, 2).astype(float)
        if len(poly) == 6:
            break
    else:
        return None
    e1 = poly - np.roll(poly, 1, axis=0)
    e2 = np.roll(poly, -1, axis=0) - poly
    cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    sign = np.sign(np.sum(cross))
    reflex = np.flatnonzero(np.sign(cross) != sign)
    if len(reflex) != 1:
        return None
    r = int(reflex[0])
    o = (r + 3) % 6
    corners = np.roll(poly, -o, axis=0)
    inward = corners[3] - corners[0]
    diag = float(np.linalg.norm(inward))
    if diag <= 0:
        return None
    arm1, arm2 = np.linalg.norm(corners[1] - corners[0]), np.linalg.norm(corners[5] - corners[0])
    if min(arm1, arm2) < 1.5 * diag / np.sqrt(2) * 0.8 or max(arm1, arm2) > 8 * min(arm1, arm2):
        return None
    thick = min(np.linalg.norm(corners[2] - corners[1]), np.linalg.norm(corners[5] - corners[4]))
    return _LCandidate(corners, corners[0], inward / diag, float(thick), float(area))


def _candidates(gray: np.ndarray) -> list[_LCandidate]:
    import cv2

    h, w = gray.shape
    out: list[_LCandidate] = []
    for frac in (16, 8, 32):
        block = max(15, (min(h, w) // frac) | 1)
        blur = cv2.GaussianBlur(gray, (3, 3), 0)
        c = max(4.0, 0.08 * float(np.median(gray)))
        binary = cv2.adaptiveThreshold(blur, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block, c)
        binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))
        contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
        found = [c for c in (_l_candidate(ct) for ct in contours if len(ct) >= 12) if c is not None]
        out.extend(found)
        if len(found) >= 4:
            break
    # drop duplicates (the same mark from two passes)
    unique: list[_LCandidate] = []
    for c in sorted(out, key=lambda c: -c.area_px):
        if all(np.linalg.norm(c.outer - u.outer) > max(2.0, c.thickness_px) for u in unique):
            unique.append(c)
    return unique[:14]


def _order(cands: tuple[_LCandidate, ...]) -> tuple[_LCandidate, ...] | None:
    pts = np.array([c.outer for c in cands])
    centroid = pts.mean(axis=0)
    ang = np.arctan2(pts[:, 1] - centroid[1], pts[:, 0] - centroid[0])  # image y down: TL ≈ -135°
    start = int(np.argmin(np.abs(np.angle(np.exp(1j * (ang + 3 * np.pi / 4))))))
    order = [(start + k) % 4 for k in range(4)]
    by_angle = list(np.argsort(ang))
    i0 = by_angle.index(start)
    order = [by_angle[(i0 + k) % 4] for k in range(4)]
    ordered = tuple(cands[i] for i in order)
    for c in ordered:
        to_c = centroid - c.outer
        if np.dot(c.inward, to_c / (np.linalg.norm(to_c) + 1e-12)) < 0.6:
            return None
    return ordered


# ---------------------------------------------------------------------------- main
def find_marks(gray: np.ndarray, target: Target, camera: Camera | None = None, *,
               max_reprojection_px: float = 1.5) -> MarksResult:
    """Find the four L marks of ``target`` in a frame (H, W): uint8, or floating point (a mean of
    frames, rounded here); a dot board is handed to :func:`~helicalib.vision.dots.find_dots`.

    Returns a :class:`MarksResult`; ``found`` is False with reason "marks_not_found" when no
    layout fits, or "reprojection" when the fit is worse than ``max_reprojection_px``.
    """
    import cv2

    if target.marks is None:
        return MarksResult(False, "marks_not_found", f"target {target.id} has no marks in the field config.")
    if target.marks.kind == "dots":
        from helicalib.vision.dots import find_dots

        return find_dots(gray, target, camera, max_reprojection_px=max_reprojection_px)
    K, dist = camera_model(camera)
    if np.asarray(gray).dtype != np.uint8:  # a mean of frames: rounded, not truncated
        gray = np.clip(np.rint(np.asarray(gray, dtype=np.float32)), 0, 255)
    gray = np.ascontiguousarray(gray, dtype=np.uint8)
    cands = _candidates(gray)
    if len(cands) < 4:
        return MarksResult(False, "marks_not_found",
                           f"only {len(cands)} of the 4 L marks of target {target.id} were seen in the frame.")
    model = mark_model_m(target)
    best = None
    for combo in itertools.combinations(cands, 4):
        ordered = _order(combo)
        if ordered is None:
            continue
        src = undistort_px(np.array([c.outer for c in ordered]), K, dist)
        Hbi, _ = cv2.findHomography(model[:, 0, :], src, 0)  # board → ideal image
        if Hbi is None or not np.all(np.isfinite(Hbi)):
            continue
        pred = distort_px(apply_homography(Hbi, model.reshape(-1, 2)), K, dist).reshape(4, 6, 2)
        errs = []
        matched = np.zeros((4, 6, 2))
        for k, c in enumerate(ordered):
            d = np.linalg.norm(pred[k][:, None, :] - c.corners[None, :, :], axis=-1)
            j = np.argmin(d, axis=1)
            errs.append(d[np.arange(6), j])
            matched[k] = c.corners[j]
        errs = np.concatenate(errs)
        tol = max(3.0, 0.6 * min(c.thickness_px for c in ordered))
        score = float(np.median(errs))
        if np.max(errs) <= 2 * tol and (best is None or score < best[0]):
            best = (score, ordered, matched)
    if best is None:
        return MarksResult(False, "marks_not_found",
                           f"no four dark L shapes in the frame fit the mark layout of target {target.id}.")
    _, ordered, matched = best
    thick = min(c.thickness_px for c in ordered)
    win = max(2, int(0.4 * thick))
    pts = matched.reshape(-1, 1, 2).astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 0.001)
    refined = cv2.cornerSubPix(gray, pts.copy(), (win, win), (-1, -1), crit).reshape(-1, 2).astype(np.float64)
    moved = np.linalg.norm(refined - matched.reshape(-1, 2), axis=1)
    refined[moved > win + 1.5] = matched.reshape(-1, 2)[moved > win + 1.5]  # a runaway corner keeps its estimate
    ideal = undistort_px(refined, K, dist)
    Hib, _ = cv2.findHomography(ideal, model.reshape(-1, 2), 0)  # ideal image → board
    if Hib is None or not np.all(np.isfinite(Hib)):
        return MarksResult(False, "marks_not_found", "the mark corners do not define a homography.")
    return finish_homography(Hib, model.reshape(-1, 2), ideal, K, dist, max_reprojection_px, "4 marks found",
                             vertices_px=refined.reshape(4, 6, 2)[:, 0, :].copy(), corners_px=refined)
