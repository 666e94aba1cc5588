"""Spot centre from a single rectified frame of the board (no "before" frame).

The frame shows the board exactly, W × H metres, image right = target u, image up = target v.
Without a frame of the empty board, the board's own appearance has to be estimated from the frame:

1. **Grid and marks out.** The board's dark grid lines and corner marks are thin dark features: a
   grey-level closing (dilate, then erode) with a square a little wider than a line fills them with
   the surrounding brightness.
2. **Background from the frame.** The empty board's brightness varies smoothly (sky light, soiling,
   camera vignetting, and on real boards sky-lit bands with sharp shadow edges); it is fitted by a
   2-D polynomial of degree ``degree`` (4), robustly: pixels brighter than the fit by more than
   ``clip_sigma`` robust sigmas (the spot and its halo) are left out and the fit is repeated until the
   set is stable. Degree 4 rather than 2: a quadratic cannot follow a band across the board, so the
   band's bright part is clipped as if it were spot and the spot's part in the darker zone is
   under-counted (PAINT crop 240796: 0.42 m → 0.05 m from HeliOS). The degree was chosen on the 10
   real AA23 crops (there is no held-out set): mean distance to HeliOS 0.18 / 0.12 / 0.13 / 0.12 /
   0.11 m at degrees 2 / 3 / 4 / 5 / 6; 4 because it stays below 0.15 m for ``clip_sigma`` 0.75–1.5
   where 3 does not. Soft shadows and seams that the polynomial still cannot follow remain in the
   residual as broad, weak structures.
3. **The spot, not the glint.** The excess over the background is smoothed and cut at a fraction of
   its peak; among the connected regions the spot is the one with the largest *integrated* excess
   (a second beam or a glint in a corner is bright but small). Regions are scored by
   integrated excess, and those that touch the frame's border lose the part of their score outside
   a border band (a glint in a corner is usually cut by the frame edge).
4. **Centre.** The centroid of the excess inside the chosen region, grown by ``grow_px`` pixels so the
   spot's flanks count, with the excess clipped at zero.

The result is in pixels and in target metres (about the board centre); :func:`pixel_to_uv_m`
documents the pixel convention (pixel centres at integer + 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from helicalib.errors import MeasurementError


@dataclass(frozen=True)
class SingleFrameSpot:
    centre_px: tuple[float, float]  # (x, y), pixel units, origin at the image's top-left corner
    fraction_xy: tuple[float, float]  # (x / width, y / height) in [0, 1]
    centre_uv_m: tuple[float, float]  # target frame about the board centre: u right, v up [m]
    area_px: int  # pixels of the chosen region
    peak_excess: float  # brightness above the background at the spot (grey levels)
    background_sigma: float  # robust scatter of the background residual (grey levels)
    regions: int  # candidate regions found
    score_ratio: float  # chosen region's score over the runner-up's (inf if alone)

    def as_dict(self) -> dict:
        return {
            "centre_px": list(self.centre_px),
            "fraction_xy": list(self.fraction_xy),
            "centre_uv_m": list(self.centre_uv_m),
            "area_px": self.area_px,
            "peak_excess": self.peak_excess,
            "background_sigma": self.background_sigma,
            "regions": self.regions,
            "score_ratio": self.score_ratio if np.isfinite(self.score_ratio) else None,  # null: one region
        }


def pixel_to_uv_m(x_px: float, y_px: float, shape_hw: tuple[int, int], board_size_m: tuple[float, float]):
    """Continuous pixel position (x right, y down, the image's top-left corner at (0, 0), so pixel
    (i, j) has its centre at (i + 0.5, j + 0.5)) → target (u, v) [m] about the board centre."""
    h, w = shape_hw
    bw, bh = board_size_m
    return (x_px / w - 0.5) * bw, (0.5 - y_px / h) * bh


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3].astype(np.uint8) if img.dtype != np.uint8 else img[..., :3], cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or min(img.shape) < 16:
        raise MeasurementError(f"expected a grey or colour image of at least 16×16 pixels, got shape {np.shape(image)}")
    return img.astype(np.float32)


def _poly_design(xx: np.ndarray, yy: np.ndarray, degree: int) -> np.ndarray:
    cols = [xx**i * yy**j for i in range(degree + 1) for j in range(degree + 1 - i)]
    return np.stack(cols, axis=-1)


def robust_background(img: np.ndarray, degree: int = 2, clip_sigma: float = 1.0, iterations: int = 15,
                      grid: int = 64) -> tuple[np.ndarray, float]:
    """Smooth background of a frame (same shape) and the robust sigma of its residual.

    Fitted on a ``grid`` × ``grid`` block-mean image; pixels more than ``clip_sigma`` robust sigmas
    above the fit, or 4 below, are excluded and the fit repeated.
    """
    h, w = img.shape
    small = cv2.resize(img, (grid, grid), interpolation=cv2.INTER_AREA).astype(np.float64)
    yy, xx = np.mgrid[0:grid, 0:grid]
    xs, ys = (xx + 0.5) / grid * 2 - 1, (yy + 0.5) / grid * 2 - 1
    a = _poly_design(xs.ravel(), ys.ravel(), degree)
    z = small.ravel()
    keep = np.ones(z.size, bool)
    # start from the darker part: the spot is bright, so the lower half of the values is board
    keep &= z <= np.percentile(z, 60)
    sigma = 1.0
    for _ in range(iterations):
        coef, *_ = np.linalg.lstsq(a[keep], z[keep], rcond=None)
        r = z - a @ coef
        sigma = max(1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep])))), 0.5)
        new = (r < clip_sigma * sigma) & (r > -4 * sigma)
        if np.array_equal(new, keep):
            break
        keep = new
    yy, xx = np.mgrid[0:h, 0:w]
    xf, yf = (xx + 0.5) / w * 2 - 1, (yy + 0.5) / h * 2 - 1
    bg = (_poly_design(xf.ravel(), yf.ravel(), degree) @ coef).reshape(h, w)
    return bg.astype(np.float32), sigma


def spot_centre_single_frame(image: np.ndarray, board_size_m: tuple[float, float], *, close_px: int = 7,
                             degree: int = 4, clip_sigma: float = 1.0, level: float = 0.35, grow_px: int = 6,
                             border_px: int = 12, weight_cut: float = 0.35) -> SingleFrameSpot:
    """Centre of the beam's spot in one rectified board frame (see the module docstring)."""
    img = _gray(image)
    h, w = img.shape
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (close_px, close_px))
    closed = cv2.morphologyEx(img, cv2.MORPH_CLOSE, k)
    bg, sigma = robust_background(closed, degree=degree, clip_sigma=clip_sigma)
    excess = closed - bg
    smooth = cv2.GaussianBlur(excess, (0, 0), sigmaX=max(2.0, w / 64))
    peak = float(smooth.max())
    if peak < 3 * sigma:
        raise MeasurementError(f"no spot: the brightest excess ({peak:.1f}) is within 3 sigma ({sigma:.1f}) of the board")
    mask = (smooth > max(level * peak, 3 * sigma)).astype(np.uint8)
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    pos = np.clip(excess, 0, None)
    inner = np.zeros((h, w), bool)
    inner[border_px:h - border_px, border_px:w - border_px] = True
    scores = []
    for lab in range(1, n):
        region = labels == lab
        scores.append(float(pos[region & inner].sum()))
    order = np.argsort(scores)[::-1]
    best = int(order[0]) + 1
    ratio = float(scores[order[0]] / scores[order[1]]) if len(order) > 1 and scores[order[1]] > 0 else float("inf")
    region = (labels == best).astype(np.uint8)
    if grow_px > 0:
        region = cv2.dilate(region, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow_px + 1, 2 * grow_px + 1)))
    wgt = np.clip(excess - weight_cut * peak, 0, None) * region
    total = float(wgt.sum())
    if total <= 0:
        raise MeasurementError("no spot: the chosen region has no excess brightness")
    yy, xx = np.mgrid[0:h, 0:w]
    cx = float((wgt * (xx + 0.5)).sum() / total)
    cy = float((wgt * (yy + 0.5)).sum() / total)
    u, v = pixel_to_uv_m(cx, cy, (h, w), board_size_m)
    return SingleFrameSpot(centre_px=(cx, cy), fraction_xy=(cx / w, cy / h), centre_uv_m=(u, v),
                           area_px=int(region.sum()), peak_excess=peak, background_sigma=sigma, regions=n - 1,
                           score_ratio=ratio)
