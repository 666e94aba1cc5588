"""Nine-dot (田) target boards → homography image ↔ board (``marks: {kind: dots}``).

The 2019 calibration article's boards carry nine round dots of two sizes on a 3 × 3 grid (any paint
clearly darker than the board; light grey measures a spot on a dot best, docs/vision.md);
the reference dot (the centre one by default) is the board's measuring point, (u, v) = (0, 0).
:func:`find_dots` returns the same :class:`~helicalib.vision.homography.MarksResult` as the L marks, so
everything downstream (rectified grid, spot centre, reuse of the marks in a campaign) is shared.

Method
------
1. Dark blobs: adaptive mean threshold at three block sizes (a large dot needs a block wider than
   itself to come out filled), external contours. A candidate is convex (solidity ≥ 0.9), fits its
   ellipse (``cv2.fitEllipse``; the contour's area within 12 % of the ellipse's), lies wholly in the
   frame and is darker than a ring around it (by :data:`MIN_CONTRAST` grey levels, :data:`CONTRAST_NOISE`
   times the ring's noise and :data:`MIN_DARKNESS` of its white, whichever is most). Of one dot's
   blobs from the three block sizes the one with the flattest ring is kept. When fewer than nine
   dots come out, the blobs are proposed once more at a lower threshold constant
   (:data:`ADAPTIVE_C`: a small light-grey dot on a dimly lit board) and the pass using more dots wins.
2. Sub-pixel centre: the white level around the blob is a plane fitted to a ring outside it; the
   darkness ``1 - I / white`` (independent of the albedo contrast and of uneven light) inside the
   grown blob weighs the pixels, and its centroid (``cv2.moments``) is the ellipse's centre.
3. Identification: every candidate triple taken as a dot and its right and upper neighbours (the
   camera sees the board upright within ±50°, u to the image right and v up, as for the L marks)
   predicts the grid affinely; predicted dots with a candidate of the right size near them count,
   and the best hypothesis (most dots, then the closest) gives a homography (least squares), which
   predicts the nine dots again in perspective and matches them once more. The sizes tell large
   from small, so a grid shifted by one pitch does not fit.
4. Perspective: a circle's image is an ellipse whose centre is not the image of the circle's
   centre (up to about a pixel for a large dot seen obliquely). The homography maps each dot's
   circle to its image conic; the offset between the conic's centre and the mapped circle centre
   is taken off the measured centres and the homography refitted (three rounds).
5. Outliers: a dot whose residual stands out (a dot under the spot, half lit) is dropped while at
   least :data:`MIN_DOTS` remain. Four points fix a homography exactly and leave nothing to check
   it by, so at least five identified dots are needed; their RMS reprojection error is the quality
   figure, refused above the limit as for the marks ("reprojection").

The homography acts on ideal (undistorted) pixel coordinates, as for the marks.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from helicalib.config import Camera, Target
from helicalib.vision.homography import (MarksResult, apply_homography, camera_model, distort_px, finish_homography,
                                        undistort_px)

MIN_DOTS = 5
"""Fewest identified dots that give a checked homography (four fit exactly; the fifth checks them)."""
UPRIGHT_DEG = 50.0
"""The board's u axis may turn this far from the image's x axis (and v from image up)."""
MAX_CANDIDATES = 24
MIN_CONTRAST = 4.0
"""Fewest grey levels a dot candidate lies below the white around it (and :data:`CONTRAST_NOISE` times
the noise of that white ring): a frame exposed for the spot shows the ambient-lit board at some 20-30
grey levels, so a light-grey dot there is only about 9 levels darker."""
CONTRAST_NOISE = 4.0
ADAPTIVE_C = (4.0, 2.0)
"""Fewest grey levels below its block's mean that a pixel must lie to be a dot candidate's (the
adaptive threshold's constant, at least 8 % of the frame's median), for the first pass and for a
second one when the first identifies fewer than nine dots. A candidate is then held to
:data:`MIN_CONTRAST` against its own white ring; a block's mean takes in the dot itself, so a small
light-grey dot on a board at 12-16 grey levels lies only about 3 levels below it: with 4 the small
dots of such a frame were lost and only the five large ones found, with 2 all nine (docs/vision.md)."""
MIN_DARKNESS = 0.25
"""A dot candidate is at least this much darker than the white around it (``1 - dot / white``; black
dots 0.94, mid-grey ones 0.5)."""


@dataclass(frozen=True)
class _Dot:
    centre: np.ndarray  # (2,) frame pixels, sub-pixel
    diameter_px: float  # equivalent diameter sqrt(4·area/π)
    ring_rms: float  # plane-fit residual of the white ring around it [grey levels]
    contrast: float  # white - dark [grey levels]


def _dot_candidate(gray: np.ndarray, contour: np.ndarray, fine: np.ndarray | None = None) -> _Dot | None:
    """A dot candidate from a blob's ``contour`` in the 8-bit ``gray``; its white ring, contrast and
    centre are measured on ``fine`` when given (the same image in floating point, e.g. a mean of
    frames, whose fractions of a grey level rounding would lose)."""
    import cv2

    area = cv2.contourArea(contour)
    H, W = gray.shape
    if area < 20 or len(contour) < 8 or area > 0.05 * H * W:
        return None
    hull_area = cv2.contourArea(cv2.convexHull(contour))
    if hull_area <= 0 or area / hull_area < 0.9:
        return None
    (_, _), (a, b), _ = cv2.fitEllipse(contour)
    ell_area = np.pi * a * b / 4
    if ell_area <= 0 or abs(area / ell_area - 1.0) > 0.12 or max(a, b) > 4 * min(a, b):
        return None
    x, y, w, h = cv2.boundingRect(contour)
    r_eq = float(np.sqrt(area / np.pi))
    m = int(max(3, round(0.3 * r_eq) + 2))  # beyond the blurred edge
    x0, y0, x1, y1 = x - 2 * m - 1, y - 2 * m - 1, x + w + 2 * m + 1, y + h + 2 * m + 1
    if x0 < 0 or y0 < 0 or x1 > W or y1 > H:
        return None  # cut by the frame edge: its centre would be biased
    roi = (gray if fine is None else fine)[y0:y1, x0:x1].astype(np.float32)
    mask = np.zeros(roi.shape, np.uint8)
    cv2.drawContours(mask, [contour - np.array([x0, y0])], -1, 1, thickness=cv2.FILLED)
    disc = lambda k: cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))  # noqa: E731
    inner = cv2.dilate(mask, disc(m))
    ring = cv2.dilate(mask, disc(2 * m)).astype(bool) & ~inner.astype(bool)
    core = cv2.erode(mask, disc(max(1, m // 2))).astype(bool)
    if np.count_nonzero(ring) < 12 or np.count_nonzero(core) < 4:
        return None
    ys, xs = np.nonzero(ring)
    A = np.column_stack([np.ones(len(xs)), xs, ys])
    coef, *_ = np.linalg.lstsq(A, roi[ring], rcond=None)
    ring_rms = float(np.sqrt(np.mean((A @ coef - roi[ring]) ** 2)))
    yy, xx = np.mgrid[0:roi.shape[0], 0:roi.shape[1]]
    white = (coef[0] + coef[1] * xx + coef[2] * yy).astype(np.float32)
    dark = float(np.median(roi[core]))
    contrast = float(np.median(white[core])) - dark
    floor = max(MIN_CONTRAST, CONTRAST_NOISE * ring_rms, MIN_DARKNESS * float(np.median(white[core])))
    if contrast < floor:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        darkness = np.where((white > 1.0) & inner.astype(bool), 1.0 - roi / white, 0.0).astype(np.float32)
    M = cv2.moments(darkness)
    if M["m00"] <= 0:
        return None
    centre = np.array([M["m10"] / M["m00"] + x0, M["m01"] / M["m00"] + y0])
    return _Dot(centre, 2.0 * r_eq, ring_rms, contrast)


def _candidates(gray: np.ndarray, c_floor: float, fine: np.ndarray | None = None) -> list[_Dot]:
    import cv2

    h, w = gray.shape
    blur = cv2.GaussianBlur(gray, (3, 3), 0)
    c = max(c_floor, 0.08 * float(np.median(gray)))
    out: list[_Dot] = []
    for frac in (4, 8, 16):
        block = max(15, (min(h, w) // frac) | 1)
        binary = cv2.adaptiveThreshold(blur, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block, c)
        binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        # outer boundaries only (a dot lies inside the board, itself a hole in the darker surroundings)
        contours, hierarchy = cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        for ct, (_, _, _, parent) in zip(contours, hierarchy[0] if hierarchy is not None else ()):
            if parent != -1:
                continue
            d = _dot_candidate(gray, ct, fine)
            if d is None:
                continue
            same = [i for i, o in enumerate(out)
                    if np.linalg.norm(d.centre - o.centre) <= 0.25 * min(d.diameter_px, o.diameter_px)]
            if not same:
                out.append(d)
            elif len(same) == 1 and d.ring_rms < out[same[0]].ring_rms:
                # the same dot from another block size: keep the blob whose white ring is the flattest (a
                # light dot near the board's dark rim comes out whole only in a block clear of the rim)
                out[same[0]] = d
    out.sort(key=lambda d: -d.diameter_px)
    return out[:MAX_CANDIDATES]


# ---------------------------------------------------------------------------- identification
def _grid_cells() -> np.ndarray:
    """(column, row) of the nine dots in pitches, row +1 at the top, in the order of ``DotMarks.dots_m``."""
    cols, rows = np.meshgrid([-1.0, 0.0, 1.0], [1.0, 0.0, -1.0])
    return np.column_stack([cols.ravel(), rows.ravel()])


def _match(pred: np.ndarray, want_d: np.ndarray, pts: np.ndarray, diam: np.ndarray, tol: np.ndarray):
    """For each predicted dot (9, 2), the candidate index within ``tol`` px with a diameter within
    0.65–1.5 of ``want_d``, else -1; and the distances."""
    d = np.linalg.norm(pred[:, None, :] - pts[None, :, :], axis=-1)
    ratio = diam[None, :] / want_d[:, None]
    d = np.where((ratio > 0.65) & (ratio < 1.5), d, np.inf)
    j = np.argmin(d, axis=1)
    dist = d[np.arange(len(pred)), j]
    return np.where(dist <= tol, j, -1), dist


def _identify(dots: list[_Dot], marks, pitch_m: float) -> np.ndarray | None:
    """Candidate index for each of the nine dots (-1 where not seen), or None."""
    pts = np.array([d.centre for d in dots])
    diam = np.array([d.diameter_px for d in dots])
    size = marks.diameters_m()
    cells = _grid_cells()
    n = len(dots)
    cos_up = np.cos(np.deg2rad(UPRIGHT_DEG))
    best = None
    for i, j in itertools.permutations(range(n), 2):
        ex = pts[j] - pts[i]
        lx = float(np.linalg.norm(ex))
        if lx <= 0 or ex[0] / lx < cos_up:
            continue
        for k in range(n):
            if k == i or k == j:
                continue
            ey = pts[k] - pts[i]
            ly = float(np.linalg.norm(ey))
            if ly <= 0 or -ey[1] / ly < cos_up or not 0.25 < lx / ly < 4.0:
                continue
            px_per_m = 0.5 * (lx + ly) / pitch_m
            for g0 in ((-1, -1), (0, -1), (-1, 0), (0, 0)):
                g = np.array(g0, dtype=float)
                idx = [int(np.argmin(np.linalg.norm(cells - c, axis=1))) for c in (g, g + (1, 0), g + (0, 1))]
                want = size[idx] * px_per_m
                if np.any(diam[[i, j, k]] / want < 0.65) or np.any(diam[[i, j, k]] / want > 1.5):
                    continue
                pred = pts[i] + (cells[:, :1] - g[0]) * ex + (cells[:, 1:] - g[1]) * ey
                tol = np.full(9, 0.25 * min(lx, ly))
                hit, dist = _match(pred, size * px_per_m, pts, diam, tol)
                count = int(np.count_nonzero(hit >= 0))
                if len(set(hit[hit >= 0].tolist())) != count:
                    continue  # one blob taken for two dots
                score = (count, -float(np.sum(dist[hit >= 0]) / min(lx, ly)))
                if best is None or score > best[0]:
                    best = (score, hit)
    if best is None or best[0][0] < 4:
        return None
    return best[1]


# ---------------------------------------------------------------------------- perspective
def conic_centres(H_bi: np.ndarray, centres_m: np.ndarray, radii_m: np.ndarray) -> np.ndarray:
    """Image centres (N, 2) of the ellipses that circles (centre, radius) [m] on the board map to.

    ``H_bi`` maps board (u, v, 1) to image pixels. A circle is the conic ``Q``; its image is
    ``H⁻ᵀ Q H⁻¹``, whose centre solves the conic's 2 × 2 part against its linear terms.
    """
    Hinv = np.linalg.inv(H_bi)
    out = np.empty((len(centres_m), 2))
    for k, ((cu, cv), r) in enumerate(zip(centres_m, radii_m)):
        Q = np.array([[1.0, 0.0, -cu], [0.0, 1.0, -cv], [-cu, -cv, cu * cu + cv * cv - r * r]])
        C = Hinv.T @ Q @ Hinv
        out[k] = -np.linalg.solve(C[:2, :2], C[:2, 2])
    return out


# ---------------------------------------------------------------------------- main
def find_dots(gray: np.ndarray, target: Target, camera: Camera | None = None, *,
              max_reprojection_px: float = 1.5) -> MarksResult:
    """Find the nine dots of ``target`` (``marks.kind == "dots"``) in a frame (H, W): uint8, or
    floating point (a mean of frames: blobs are proposed on it rounded, dots measured on its fractions).

    Returns a :class:`MarksResult` (``kind`` "dots", ``dots_px`` the nine centres, NaN where not
    used); ``found`` is False with reason "marks_not_found" when fewer than :data:`MIN_DOTS` dots
    are identified, or "reprojection" when they fit the layout worse than ``max_reprojection_px``.
    When the first pass uses fewer than nine dots, a second one proposes candidates at the lower
    threshold constant of :data:`ADAPTIVE_C` (a dimly lit board), and the result using more dots wins.
    """
    fine = None
    if np.asarray(gray).dtype != np.uint8:  # e.g. the mean of several frames: centres on its fractions
        fine = np.ascontiguousarray(gray, dtype=np.float32)
        gray = np.clip(np.rint(fine), 0, 255).astype(np.uint8)
    gray = np.ascontiguousarray(gray, dtype=np.uint8)
    first = _find_dots(gray, target, camera, max_reprojection_px, ADAPTIVE_C[0], fine)
    if first.found and np.count_nonzero(np.isfinite(first.dots_px[:, 0])) == 9:
        return first
    second = _find_dots(gray, target, camera, max_reprojection_px, ADAPTIVE_C[1], fine)
    used = lambda r: np.count_nonzero(np.isfinite(r.dots_px[:, 0])) if r.found else -1  # noqa: E731
    return second if used(second) > used(first) else first


def _find_dots(gray: np.ndarray, target: Target, camera: Camera | None, max_reprojection_px: float,
               c_floor: float, fine: np.ndarray | None = None) -> MarksResult:
    """:func:`find_dots` with candidates proposed at threshold constant ``c_floor``."""
    import cv2

    marks = target.marks
    K, dist = camera_model(camera)
    dots = _candidates(gray, c_floor, fine)
    not_found = dict(kind="dots", dots_px=np.full((9, 2), np.nan))
    if len(dots) < MIN_DOTS:
        return MarksResult(False, "marks_not_found", f"only {len(dots)} round dark dots of target {target.id} "
                           f"were seen in the frame (need {MIN_DOTS} of its 9).", **not_found)
    hit = _identify(dots, marks, marks.pitch_m)
    if hit is None:
        return MarksResult(False, "marks_not_found",
                           f"no dots in the frame fit the 3 x 3 dot layout of target {target.id}.", **not_found)
    model = marks.dots_m()
    radii = marks.diameters_m() / 2
    pts = np.array([d.centre for d in dots])
    diam = np.array([d.diameter_px for d in dots])
    ideal_all = undistort_px(pts, K, dist)
    # perspective: fit on what the affine hypothesis found, predict all nine, match again
    for _ in range(2):
        sel = hit >= 0
        if np.count_nonzero(sel) < 4:
            break
        Hbi, _ = cv2.findHomography(model[sel], ideal_all[hit[sel]], 0)
        if Hbi is None or not np.all(np.isfinite(Hbi)):
            break
        pred = apply_homography(Hbi, model)
        scale = np.linalg.norm(apply_homography(Hbi, model + [marks.pitch_m, 0.0]) - pred, axis=1) / marks.pitch_m
        pred_px = distort_px(pred, K, dist)
        new, _ = _match(pred_px, 2 * radii * scale, pts, diam, 0.15 * marks.pitch_m * scale)
        if len(set(new[new >= 0].tolist())) != np.count_nonzero(new >= 0):
            break
        hit = new
    sel = hit >= 0
    if np.count_nonzero(sel) < MIN_DOTS:
        return MarksResult(False, "marks_not_found", f"only {np.count_nonzero(sel)} of the 9 dots of target "
                           f"{target.id} were identified (need {MIN_DOTS}).", **not_found)
    measured = np.full((9, 2), np.nan)
    measured[sel] = ideal_all[hit[sel]]
    ring = np.full(9, np.nan)
    ring[sel] = [dots[i].ring_rms for i in hit[sel]]
    use = sel.copy()
    # a dot whose white ring is far from a plane (the spot beside it) is not trusted while enough remain
    med_ring = float(np.median(ring[use]))
    for k in np.argsort(-np.nan_to_num(ring, nan=-1.0)):
        if use[k] and np.count_nonzero(use) > MIN_DOTS and ring[k] > max(4.0 * med_ring, med_ring + 6.0):
            use[k] = False
    corrected = measured.copy()
    Hbi = None
    while True:
        for _ in range(3):
            Hbi, _ = cv2.findHomography(model[use], corrected[use], 0)
            if Hbi is None or not np.all(np.isfinite(Hbi)):
                return MarksResult(False, "marks_not_found", "the dots do not define a homography.", **not_found)
            corrected = measured - (conic_centres(Hbi, model, radii) - apply_homography(Hbi, model))
        res = np.linalg.norm(apply_homography(Hbi, model) - corrected, axis=1)
        worst = int(np.nanargmax(np.where(use, res, -1.0)))
        if np.count_nonzero(use) > MIN_DOTS and res[worst] > max(0.75, 5.0 * float(np.median(res[use]))):
            use[worst] = False
            continue
        break
    Hib = np.linalg.inv(Hbi)
    dots_px = np.full((9, 2), np.nan)
    dots_px[use] = pts[hit[use]]
    n_used = int(np.count_nonzero(use))
    corners = distort_px(apply_homography(Hbi, model[[0, 2, 8, 6]]), K, dist)  # the outer dots TL, TR, BR, BL
    return finish_homography(Hib, model[use], corrected[use], K, dist, max_reprojection_px,
                             f"{n_used} of 9 dots found", kind="dots", dots_px=dots_px, vertices_px=corners)


# ---------------------------------------------------------------------------- the spot on a dot
class DotFill:
    """The spot's light on the dark dots of a board, restored on the rectified grid.

    A spot that falls on a dot is seen dimmed by the dot's albedo (a black dot returns a few per
    cent), which would pull the spot centre away from the dot; the aim point of a dot board is its
    reference dot, so that is the usual case. On the grid the dots lie where the layout says. Each
    cell's albedo relative to the white board is ``a = before / white``, the white level a plane
    fitted to a ring of board around the dot in the before frame, taken as a function of the
    distance from the dot's centre. The difference ``D = a · E`` (spot irradiance ``E`` in
    white-board grey levels) is turned back into ``E``:

    * on the dot's flat interior the before frame's own noise (which ``D = after - k·before``
      carries, divided by ``a`` once restored) is replaced by its model ``a₀ · white`` (``a₀`` the
      mean albedo there), leaving the after frame's noise alone;
    * on the dark part (``a < 0.5``) a normalised convolution over the dark cells,
      ``E = G∗(a·D) / G∗(a²)`` (the least-squares estimate of a smooth ``E`` under a Gaussian window
      ``G``), with σ :data:`FILL_SIGMA_M` for the values and the wider :data:`DETECT_SIGMA_M` for the
      detection estimate that decides which cells pass the annex A threshold (thresholding the
      noisier values would keep the noise peaks and drop the troughs, a bias);
    * on the dot's bright edge ``D / a`` cell by cell (its noise grows by 1/a ≤ 2).

    Elsewhere ``D`` is left as it is. The restored values carry the after frame's noise times
    ``1/a`` (17 on a 6 % dot), which is what limits a spot on a dot.

    Parameters
    ----------
    grid : BoardGrid
        The board grid (cells of ``1/grid.cells_per_m`` metres, board frame u right, v up).
    before : ndarray (rows, columns)
        The before frame sampled on the grid [grey levels].
    marks : DotMarks
        The board's dots (centres and diameters [m], board frame).
    """

    def __init__(self, grid, before: np.ndarray, marks):
        import cv2

        s = grid.cells_per_m
        B = np.asarray(before, dtype=np.float32)
        self.parts = []
        sigma = max(1.0, FILL_SIGMA_M * s)
        sigma_det = max(sigma, DETECT_SIGMA_M * s)
        pad = int(np.ceil(3 * sigma_det))
        rows, cols = grid.shape
        for (cu, cv), d in zip(marks.dots_m(), marks.diameters_m()):
            r_m = d / 2
            reach = r_m + 0.3  # the ring's outer edge
            c0, r0 = np.floor(grid.board_to_cell(np.array([cu - reach, cv + reach]))).astype(int) - pad
            c1, r1 = np.ceil(grid.board_to_cell(np.array([cu + reach, cv - reach]))).astype(int) + pad + 1
            c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, cols), min(r1, rows)
            if c1 - c0 < 4 or r1 - r0 < 4:
                continue
            cc, rr = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
            uv = grid.cell_to_board(np.stack([cc, rr], axis=-1))
            dist = np.hypot(uv[..., 0] - cu, uv[..., 1] - cv)
            inside = grid.inside[r0:r1, c0:c1]
            ring = inside & (dist >= r_m + 4.0 / s + 0.02) & (dist <= reach)
            region = inside & (dist <= r_m + 3.0 / s + 0.02)
            if np.count_nonzero(ring) < 12 or not region.any():
                continue
            b = B[r0:r1, c0:c1]
            A = np.column_stack([np.ones(np.count_nonzero(ring)), uv[..., 0][ring] - cu, uv[..., 1][ring] - cv])
            coef, *_ = np.linalg.lstsq(A, b[ring], rcond=None)
            white = coef[0] + coef[1] * (uv[..., 0] - cu) + coef[2] * (uv[..., 1] - cv)
            if not np.all(white[region] > 1.0):
                continue
            # the albedo as a function of the distance from the dot's centre (medians in half-cell
            # rings): a per-cell ratio would share the before frame's noise with D = after - before
            # and bias E low (by σ²/(a·white) per cell: 10 % on a 6 % dot)
            ratio = b / np.maximum(white, 1.0)
            edges = np.arange(0.0, r_m + 3.0 / s + 0.02 + 0.5 / s, 0.5 / s)
            edges[0] = -1.0
            edges = np.concatenate([[-1.0, max(0.0, r_m - 2.0 / s - 0.02)], edges[edges > r_m - 2.0 / s - 0.02]])
            which = np.digitize(dist, edges) - 1
            prof_d, prof_a = [], []
            for j in range(len(edges) - 1):
                sel = region & (which == j)
                if np.count_nonzero(sel) >= 3:
                    prof_d.append(float(np.median(dist[sel])))
                    prof_a.append(float(np.median(ratio[sel])))
            if len(prof_d) < 2:
                continue
            a = np.clip(np.interp(dist, prof_d, prof_a), 0.02, 1.0).astype(np.float32)
            # the dark side (a < 0.5) by a normalised convolution over dark cells only (a window that took
            # in white cells would be carried by them: a spot's edge near the dot's would leak inward);
            # the bright rest of the edge cell by cell (its noise grows by 1/a ≤ 2)
            core = (region & (a < 0.5)).astype(np.float32)
            den = cv2.GaussianBlur(a * a * core, (0, 0), sigma)
            den_det = cv2.GaussianBlur(a * a * core, (0, 0), sigma_det)
            band = region & (core == 0)
            # the before frame's noise on the dot's flat interior, replaced by its model
            deep = region & (dist <= r_m - 3.0 / s - 0.02)
            bfix = np.zeros_like(a)
            if np.count_nonzero(deep) >= 12:
                a0 = float(np.mean(ratio[deep]))
                bfix[deep] = (b[deep] - a0 * white[deep]).astype(np.float32)
            self.parts.append((slice(r0, r1), slice(c0, c1), a, core, den, core > 0, band, sigma, bfix, den_det,
                               sigma_det))

    def correct(self, D: np.ndarray, k: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Restore the spot's light on the dots.

        Parameters
        ----------
        D : ndarray float32 (rows, columns)
            The difference ``after - k·before`` on the grid [grey levels].
        k : float
            The ambient ratio after/before that ``D`` was formed with.

        Returns
        -------
        values, detection : ndarray float32 (rows, columns)
            Copies of ``D`` with the irradiance ``E`` [white-board grey levels] on and around the
            dots: ``values`` for the centre, ``detection`` (smoother on the dots' dark part) for the
            threshold test and the peak.
        """
        import cv2

        out, det = D.copy(), D.copy()
        for rs, cs, a, core, den, in_core, band, sigma, bfix, den_det, sigma_det in self.parts:
            d = D[rs, cs] + np.float32(k) * bfix
            ad = a * d * core
            num = cv2.GaussianBlur(ad, (0, 0), sigma)
            block = out[rs, cs]
            block[in_core] = num[in_core] / np.maximum(den[in_core], 1e-9)
            block[band] = d[band] / a[band]
            num = cv2.GaussianBlur(ad, (0, 0), sigma_det)
            block = det[rs, cs]
            block[in_core] = num[in_core] / np.maximum(den_det[in_core], 1e-9)
            block[band] = d[band] / a[band]
        return out, det


FILL_SIGMA_M = 0.03
"""σ [m] of the window over which the spot's light on a dot is estimated (a spot is far wider; a
wider window biases the estimate near the dot's edge and does not lower the centre's noise)."""
DETECT_SIGMA_M = 0.06
"""σ [m] of the wider window of the detection estimate, which decides which dot cells lie above the
annex A threshold (the values there come from the :data:`FILL_SIGMA_M` estimate)."""
