"""Spot centre on the target board, T/GRLM 02-2014 clause 7.2 and annex A.2, with validity checks.

Pipeline for one "before" frame (no beam) and one or more "after" frames (beam on the board):

1. marks on the before frame (or given) → homography → a metric grid of the board
   (:mod:`helicalib.vision.rectify`); both frames are sampled onto it, so everything below is
   in board metres, free of perspective;
2. ambient ratio ``k`` = after / before on the board free of the spot (the lowest well-populated
   mode of the ratio, then the median away from the spot); the difference ``D = after - k·before``
   removes the board, its marks and uneven light, and compensates a small change of daylight; on a
   dot board the spot's light on the dots is restored (:class:`~helicalib.vision.dots.DotFill`),
   with a smoother estimate of it for the peak and the threshold test of step 3. A spot that covers
   most of the board and leaves no free board for ``k`` is refused ("fills_board",
   :mod:`helicalib.vision.ambient`);
3. threshold ``T`` by Otsu's method on the histogram of ``D`` (A.1), raised to 4 noise sigmas;
   ``I = D`` where ``D ≥ T`` else 0; spot area ``S`` = count of ``D ≥ T`` (cells);
4. window side ``l = √S`` (A.2), the window sum ``f`` at every position from one integral image
   (A.3), its maximum (A.4);
5. centre by method:
   ``grlm``           the window's geometric centre, as the standard says (integer cells);
   ``grlm-centroid``  (default) the intensity centroid of ``I`` inside a window of side ``l`` that is
                      re-centred on that centroid until it stops moving (sub-cell; the fixed point is
                      the centre of a symmetric spot);
   ``centroid``       the intensity centroid of all of ``I``;
6. with several after frames the mean centre and its jitter (RMS distance to the mean, T/GRLM 3.3).

A spot whose region at ``T`` runs over the board's rim is "clipped", unless its core (30–60 % of the
peak, :func:`core_region`) keeps off the rim, then measured on the core, or else the symmetry of its
visible part pins its centre (:mod:`helicalib.vision.mirror`, :attr:`SpotLimits.max_mirror_slope`).

Every result says valid or not, with a reason code (:data:`REASONS`) and one sentence.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from helicalib.config import Camera, Target
from helicalib.errors import MeasurementError
from helicalib.vision.ambient import below_share, mad_sigma
from helicalib.vision.frames import as_gray_u8
from helicalib.vision.homography import MarksResult, board_to_image
from helicalib.vision.marks import find_marks
from helicalib.vision.rectify import BoardGrid, board_grid

METHODS = ("grlm", "grlm-centroid", "centroid")
REASONS = ("ok", "no_spot", "clipped", "saturated", "low_contrast", "marks_not_found", "reprojection",
           "ambient_change", "fills_board", "jitter", "bad_frame")
SATURATED_LEVEL = 250
CORE_SHARES = (0.3, 0.4, 0.5, 0.6)
"""Core thresholds [shares of the peak] tried, lowest first, on a spot whose region at ``T`` runs over
the board's rim: the first whose region keeps off the rim (the same rule) is measured instead. The
core of a centrally symmetric beam is centred on the beam, whatever of its skirt the rim cuts."""
CORE_RIM_MARGIN_CELLS = 3
"""A core must keep this many cells off the rim and off the dark marks: the rim's cells, sampled half
on the board and half beside it, and a mark's cells (its albedo a few % of the board's) read darker
than the spot there, so a core cut by either can look closed next to them."""
MIRROR_MAX_SLOPE = 0.75
"""Default :attr:`SpotLimits.max_mirror_slope`: a symmetric-region centre amplifies errors at most 4×."""
MIRROR_MAX_ASYMMETRY = 0.025
"""Default :attr:`SpotLimits.max_mirror_asymmetry`."""
DARK_MARK_SHARE = 0.5
"""Board cells darker than this share of the board's median in the before frame are marks (where the
spot's light is mostly lost, unless a dot board restores it)."""


@dataclass(frozen=True)
class SpotLimits:
    """Validity limits of a spot measurement."""

    max_reprojection_px: float = 1.5
    """Marks fit worse than this [px RMS] → "reprojection"."""
    min_snr: float = 8.0
    """Peak of the 3×3-smoothed difference below this many noise sigmas → "no_spot"."""
    min_contrast: float = 20.0
    """Peak of the difference below this [grey levels] → "low_contrast" (weak DNI, dirty mirror, cloud)."""
    max_saturated_fraction: float = 0.10
    """More of the spot area at ≥ 250 grey levels in the after frame than this → "saturated"."""
    max_ambient_change: float = 0.25
    """|after/before light ratio - 1| above this → "ambient_change"."""
    max_below_share: float = 0.04
    """A spot whose region at ``T`` covers at least ``fills_board_share`` of the board, with more than this
    share of the lit board darker than the ambient light ratio's fit allows
    (:func:`~helicalib.vision.ambient.below_share`) →
    "fills_board": the ratio was taken on the spot, as no free board was left to take it on, and the
    difference would lose part of the spot (a centre metres off)."""
    fills_board_share: float = 0.4
    """See ``max_below_share``: smaller spots leave the ratio its free board."""
    max_jitter_m: float = 0.10
    """RMS distance of the frame centres to their mean above this [m] → "jitter"."""
    min_area_cells: int = 9
    """Fewer thresholded cells than this → "no_spot"."""
    max_clipped_cells: int = 2
    """More thresholded cells than this on the board rim or the frame edge → "clipped"."""
    max_lost_light_share: float = 0.2
    """More cells than this share of the spot's (and at least ``min_area_cells``) at least the threshold
    *below* the before frame → "ambient_change": light on the board in the before frame that is gone
    in the after frame, another beam crossing the board while the before frame was taken."""
    core_shares: tuple[float, ...] = CORE_SHARES
    """Core thresholds tried on a spot that runs over the rim (:func:`core_region`); () keeps every such
    spot "clipped"."""
    max_mirror_slope: float | None = MIRROR_MAX_SLOPE
    """A spot over the rim whose every core reaches it is measured by the symmetry of its visible part
    (:func:`~helicalib.vision.mirror.mirror_centre`) when the centroid's slope over the symmetric
    region's centre is at most this on both axes (a centre error amplified at most 1 / (1 − slope)
    times); None keeps every such spot "clipped", and so does ``core_shares=()`` (no rim rule at all)."""
    max_mirror_asymmetry: float = MIRROR_MAX_ASYMMETRY
    """... and when the spot in the symmetric region is symmetric about the centre found: its
    :attr:`~helicalib.vision.mirror.MirrorCentre.asymmetry` at most this."""


@dataclass(frozen=True)
class FrameSpot:
    """The spot in one after frame (grid cell coordinates: column, row)."""

    center_cell: np.ndarray
    offset_m: np.ndarray
    threshold: float
    area_cells: int
    window_side_cells: float
    window_center_cell: np.ndarray
    ambient_ratio: float
    peak: float
    noise: float
    saturated_fraction: float
    clipped_cells: int
    core_share: float | None = None
    """The share of the peak ``threshold`` is at when the spot at ``T`` ran over the rim and its core
    was measured (:data:`CORE_SHARES`); None when measured at ``T``."""
    mirror_slope: float | None = None
    """The larger slope of the symmetric-region centre when the spot ran over the rim, no core kept off
    it, and the centre was found from the symmetry of its visible part; None otherwise."""
    mirror_asym: float | None = None
    """The spot's asymmetry about that centre (:attr:`~helicalib.vision.mirror.MirrorCentre.asymmetry`)."""


@dataclass(frozen=True)
class SpotResult:
    """A spot measurement. Pixel values are frame pixels; ``offset_m`` is (u, v) on the board from its centre.

    An invalid result has no ``offset_m``, except a "clipped" one: there it is the centroid of the
    visible part (biased toward the board centre), so a search can head for the beam.

    ``spot_area_px`` is the annex A spot area ``S`` counted on the board grid (cells of
    ``1/cells_per_m`` metres; ``spot_area_m2`` is the same in square metres). ``window_px`` holds the
    corners (4, 2) of the square A.2 window in the frame; ``window_side_m`` its side.
    """

    valid: bool
    reason: str
    message: str
    method: str = "grlm-centroid"
    marks: MarksResult | None = None
    spot_center_px: np.ndarray | None = None
    offset_m: np.ndarray | None = None
    target_center_px: np.ndarray | None = None
    spot_area_px: float | None = None
    spot_area_m2: float | None = None
    threshold: float | None = None
    jitter_m: float | None = None
    window_px: np.ndarray | None = None
    window_side_m: float | None = None
    cells_per_m: float | None = None
    frame_offsets_m: np.ndarray | None = None
    frames: tuple[FrameSpot, ...] = field(default_factory=tuple)
    failed_frame: int | None = None
    before_beam: bool = False
    """True for an "ambient_change" whose cause is light on the board in the before frame that is
    gone in the after frame (another beam lay on the board while the before frame was taken): a
    campaign takes the before frame again (``campaign.measure.retake_before``)."""

    def to_json(self) -> dict:
        """A JSON-ready dict (lists and floats; None where not measured)."""

        def arr(a, nd=4):
            return None if a is None else np.round(np.asarray(a, dtype=float), nd).tolist()

        def num(x, nd=4):
            return None if x is None or not np.isfinite(x) else round(float(x), nd)

        f0 = self.frames[0] if self.frames else None
        return {
            "valid": self.valid, "reason": self.reason, "message": self.message, "method": self.method,
            "spot_center_px": arr(self.spot_center_px, 3), "offset_m": arr(self.offset_m, 5),
            "target_center_px": arr(self.target_center_px, 3), "spot_area_px": num(self.spot_area_px, 1),
            "spot_area_m2": num(self.spot_area_m2), "threshold": num(self.threshold, 2),
            "jitter_m": num(self.jitter_m, 5), "window_px": arr(self.window_px, 2),
            "window_side_m": num(self.window_side_m), "cells_per_m": num(self.cells_per_m, 3),
            "frame_offsets_m": arr(self.frame_offsets_m, 5), "failed_frame": self.failed_frame,
            "ambient_ratio": None if f0 is None else num(f0.ambient_ratio),
            "peak": None if f0 is None else num(f0.peak, 2), "noise": None if f0 is None else num(f0.noise, 3),
            "saturated_fraction": None if f0 is None else num(f0.saturated_fraction),
            "marks": None if self.marks is None else self.marks.to_json(),
        }


class _Invalid(Exception):
    def __init__(self, reason: str, message: str, partial: FrameSpot | None = None, before_beam: bool = False):
        super().__init__(message)
        self.reason, self.message, self.partial, self.before_beam = reason, message, partial, before_beam


# ---------------------------------------------------------------------------- annex A core
def otsu_threshold(values_u8: np.ndarray) -> float:
    """Otsu's threshold of 8-bit values (any shape) [grey levels]."""
    import cv2

    v = np.ascontiguousarray(values_u8, dtype=np.uint8).reshape(-1, 1)
    t, _ = cv2.threshold(v, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return float(t)


def best_window(I: np.ndarray, side: int) -> tuple[np.ndarray, float]:
    """Annex A.3–A.4: the ``side``×``side`` window with the largest sum of ``I`` (rows, columns).

    Returns the window's geometric centre (column, row) in cell coordinates — the mean over all
    positions that reach the maximum — and that maximum.
    """
    import cv2

    rows, cols = I.shape
    side = int(max(1, min(side, rows, cols)))
    ii = cv2.integral(np.ascontiguousarray(I, dtype=np.float32), sdepth=cv2.CV_64F)
    f = ii[side:, side:] - ii[:-side, side:] - ii[side:, :-side] + ii[:-side, :-side]
    fmax = float(f.max())
    r, c = np.nonzero(f >= fmax - 1e-9 * max(1.0, abs(fmax)))
    half = (side - 1) / 2.0
    return np.array([c.mean() + half, r.mean() + half]), fmax


def _cover(lo: float, hi: float, n: int) -> tuple[int, np.ndarray, np.ndarray]:
    """Cells (index range) overlapping [lo, hi] and the covered fraction of each (cell k spans k±½)."""
    k0, k1 = max(0, int(math.floor(lo + 0.5))), min(n - 1, int(math.floor(hi + 0.5)))
    if k1 < k0:
        return k0, np.zeros(0, dtype=int), np.zeros(0)
    ks = np.arange(k0, k1 + 1)
    w = np.clip(np.minimum(ks + 0.5, hi) - np.maximum(ks - 0.5, lo), 0.0, 1.0)
    return k0, ks, w


def window_centroid(I: np.ndarray, start_cell: np.ndarray, side: float, iterations: int = 30) -> np.ndarray:
    """Intensity centroid of ``I`` inside a square window of ``side`` cells, re-centred until it stops moving.

    Partly covered cells count with their covered fraction, so the window slides continuously.
    Returns (column, row) in cell coordinates.
    """
    rows, cols = I.shape
    c = np.asarray(start_cell, dtype=float).copy()
    h = side / 2.0
    for _ in range(iterations):
        _, js, wx = _cover(c[0] - h, c[0] + h, cols)
        _, is_, wy = _cover(c[1] - h, c[1] + h, rows)
        if len(js) == 0 or len(is_) == 0:
            break
        patch = I[is_[0]: is_[-1] + 1, js[0]: js[-1] + 1] * wy[:, None] * wx[None, :]
        tot = float(patch.sum())
        if tot <= 0:
            break
        new = np.array([patch.sum(axis=0) @ js / tot, patch.sum(axis=1) @ is_ / tot])
        moved = float(np.max(np.abs(new - c)))
        c = new
        if moved < 1e-4:
            break
    return c


def core_region(Ddet: np.ndarray, inside: np.ndarray, T: float, peak: float, limits: SpotLimits,
                blind: np.ndarray | None = None) -> tuple[float, float, np.ndarray] | None:
    """The core of a spot whose region at ``T`` runs over the rim: (share, threshold, mask on the board).

    The lowest of ``limits.core_shares`` × ``peak`` (above ``T``) whose region, grown by
    :data:`CORE_RIM_MARGIN_CELLS`, has at most ``max_clipped_cells`` cells off ``inside`` or on
    ``blind`` (board cells that do not show the spot's light: dark marks), with at least
    ``min_area_cells`` cells and a side √S smaller than the grid; None when every core reaches the
    rim or a mark (the spot stays "clipped").
    """
    import cv2

    m = 2 * CORE_RIM_MARGIN_CELLS + 1
    kernel = np.ones((m, m), np.uint8)
    unseen = ~inside if blind is None else ~inside | blind
    for share in limits.core_shares:
        Tc = share * peak
        if Tc <= T:
            continue
        above = Ddet >= Tc
        S = int(np.count_nonzero(above & inside))
        if S < limits.min_area_cells:
            return None
        near = cv2.dilate(above.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        off = int(np.count_nonzero(near.astype(bool) & unseen))
        if off <= limits.max_clipped_cells and math.sqrt(S) < min(inside.shape):
            return share, Tc, above & inside
    return None


def _off_frame_cells(above: np.ndarray, inside: np.ndarray) -> int:
    """Cells of ``above`` off ``inside`` other than the board's rim (the grid's outer ring): where the
    frame's edge cuts the board. A spot cut there stays "clipped"; the core rule is for the rim."""
    off = above & ~inside
    return int(np.count_nonzero(off[1:-1, 1:-1]))


def intensity_centroid(I: np.ndarray) -> np.ndarray:
    """Intensity centroid (column, row) of all of ``I``."""
    tot = float(I.sum())
    return np.array([I.sum(axis=0) @ np.arange(I.shape[1]) / tot, I.sum(axis=1) @ np.arange(I.shape[0]) / tot])


def _mirror_spot(I: np.ndarray, inside: np.ndarray, blind: np.ndarray | None, limits: SpotLimits):
    """The centre of a rim-cut spot from the symmetry of its visible part (:mod:`.mirror`), or None when
    it is not well conditioned (a slope above ``limits.max_mirror_slope``), the spot there is not
    symmetric about it (``limits.max_mirror_asymmetry``), the region holds fewer than
    ``min_area_cells`` of the spot's cells, or the centre found is not on a cell that shows the spot."""
    import cv2

    from helicalib.vision.mirror import mirror_centre

    seen = inside if blind is None else inside & ~blind
    m = 2 * CORE_RIM_MARGIN_CELLS + 1
    seen = cv2.erode(seen.astype(np.uint8), np.ones((m, m), np.uint8), borderType=cv2.BORDER_CONSTANT,
                     borderValue=0).astype(bool)
    if not seen.any():
        return None
    peak_cell = np.array(np.unravel_index(int(np.argmax(np.where(seen, I, 0.0))), I.shape)[::-1], dtype=float)
    got = mirror_centre(I, seen, peak_cell)
    if got is None or got.area_cells < limits.min_area_cells or not np.all(got.slope <= limits.max_mirror_slope) \
            or got.asymmetry > limits.max_mirror_asymmetry:
        return None
    col, row = np.rint(got.center_cell).astype(int)
    if not (0 <= row < seen.shape[0] and 0 <= col < seen.shape[1] and seen[row, col]):
        return None
    return got


# ---------------------------------------------------------------------------- one frame
def _lowest_mode(r: np.ndarray, min_share: float = 0.1) -> float:
    """The lowest well-populated mode of after/before light ratios.

    A beam only ever adds light, so the spot-free board is the cluster of the LOWEST ratios; the
    spot's cells spread above it (and a flat-topped spot can form a larger cluster of its own, so
    the highest peak is not the answer). Histogram in 0.5 % bins, lightly smoothed; the first local
    maximum holding at least ``min_share`` of the cells within ±4 % of it.
    """
    lo, hi = np.percentile(r, [0.5, 99.5])
    if not hi > lo:
        return float(np.median(r))
    bins = int(np.clip((hi - lo) / 0.005, 20, 2000))
    hist, edges = np.histogram(r, bins=bins, range=(lo, hi))
    smooth = np.convolve(hist, np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 9.0, mode="same")
    centres = 0.5 * (edges[:-1] + edges[1:])
    peaks = [i for i in range(bins) if smooth[i] > 0 and smooth[i] >= smooth[max(i - 1, 0)]
             and smooth[i] >= smooth[min(i + 1, bins - 1)]]
    for i in peaks:
        c = centres[i]
        if np.count_nonzero(np.abs(r - c) <= 0.04 * c) >= min_share * r.size:
            near = r[np.abs(r - c) <= 0.04 * c]
            return float(np.median(near))
    return float(np.median(r))


def _ambient_ratio(a_s: np.ndarray, b_s: np.ndarray, lit: np.ndarray) -> tuple[float, np.ndarray]:
    """Light ratio after/before on the board, away from the spot, and a spot-free sample of the difference.

    Pass 1: the lowest well-populated mode of the after/before ratio over the lit board
    (:func:`_lowest_mode`: robust even when the spot covers most of the board). Pass 2: the cells
    clearly lit by the spot (more than 3 noise sigmas, the noise taken from the cells at the ambient
    level) are grown by their own extent (the faint tails of a real spot reach far) and left out;
    the median ratio of the rest is ``k``. Works on a sub-sampled grid (2-D arrays).
    """
    import cv2

    ratio = np.divide(a_s, b_s, out=np.zeros_like(a_s), where=b_s > 0)
    k = _lowest_mode(ratio[lit])
    d = a_s - k * b_s
    near = lit & (np.abs(ratio - k) <= 0.04 * k)
    ref = d[near] if np.count_nonzero(near) >= 16 else d[lit]
    noise = mad_sigma(ref)
    spot = ((d > 3.0 * noise) & lit).astype(np.uint8)
    n_spot = int(np.count_nonzero(spot))
    if n_spot:
        r = int(np.ceil(0.3 * np.sqrt(n_spot))) + 1  # about half the spot radius beyond its 3-sigma edge
        grown = cv2.dilate(spot, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))).astype(bool)
        rest = lit & ~grown
        if np.count_nonzero(rest) >= max(16, 0.05 * np.count_nonzero(lit)):
            k = float(np.median(ratio[rest]))
            return k, a_s[rest] - k * b_s[rest]
    return k, ref


def _frame_spot(B: np.ndarray, A: np.ndarray, grid: BoardGrid, method: str, limits: SpotLimits,
                fill=None) -> FrameSpot:
    """One after frame; ``B``, ``A`` are the before and after frames sampled on the grid (uint8);
    ``fill`` (a :class:`~helicalib.vision.dots.DotFill`) restores the spot's light on a dot board's dots:
    its values enter ``I`` and the centre, its smoother detection estimate the peak, the Otsu
    histogram and the threshold test (which cells form the spot)."""
    import cv2

    inside = grid.inside
    step = 4
    sub = (slice(None, None, step), slice(None, None, step))
    in_sub = inside[sub]
    b_s, a_s = B[sub].astype(np.float32), A[sub].astype(np.float32)
    if np.count_nonzero(in_sub) < 16:
        raise _Invalid("marks_not_found", "the board is not inside the frame.")
    b_med = float(np.median(b_s[in_sub]))
    lit = in_sub & (b_s > 0.25 * b_med) & (b_s < SATURATED_LEVEL) & (a_s < SATURATED_LEVEL)
    if np.count_nonzero(lit) < 16:
        raise _Invalid("low_contrast", "the board is too dark or saturated to compare before and after.")
    k, d0 = _ambient_ratio(a_s, b_s, lit)
    D = cv2.addWeighted(A, 1.0, B, -k, 0.0, dtype=cv2.CV_32F)  # after - k·before
    Ddet = D_raw = D  # D_raw: before any light restored on a dot board's dots (whose noise it amplifies)
    if fill is not None:
        D, Ddet = fill.correct(D, k)
    # noise sigma of the difference, from the board cells outside the spot (second pass above)
    noise = mad_sigma(d0)
    Dm = cv2.multiply(D, grid.inside_f32)  # zero off the board's inner part
    Dd = Dm if Ddet is D else cv2.multiply(Ddet, grid.inside_f32)
    peak = float(cv2.minMaxLoc(cv2.boxFilter(Dd, -1, (3, 3)))[1])
    partial = FrameSpot(np.full(2, np.nan), np.full(2, np.nan), float("nan"), 0, float("nan"), np.full(2, np.nan),
                        k, peak, noise, float("nan"), 0)
    if abs(k - 1.0) > limits.max_ambient_change:
        raise _Invalid("ambient_change", f"the light on the board changed by {100 * (k - 1):+.0f} % between the "
                       f"before and after frames (limit ±{100 * limits.max_ambient_change:.0f} %).", partial)
    if peak < limits.min_snr * noise:
        raise _Invalid("no_spot", f"no spot on the board: the brightest difference is {peak:.1f} grey levels, "
                       f"{peak / noise:.1f} noise sigmas (need {limits.min_snr:g}).", partial)
    if peak < limits.min_contrast:
        raise _Invalid("low_contrast", f"the spot is too faint: {peak:.1f} grey levels above the board "
                       f"(need {limits.min_contrast:g}; weak DNI, dirty mirror or cloud).", partial)
    # A.1: threshold from the grey-level histogram of the difference on the board (every 2nd cell)
    half = (slice(None, None, 2), slice(None, None, 2))
    d8 = np.clip(Dd[half][inside[half]], 0, 255).astype(np.uint8)
    T = max(otsu_threshold(d8), math.ceil(4.0 * noise), 1.0)
    above = Ddet >= T
    mask = above & inside
    S = int(np.count_nonzero(mask))
    clipped = int(np.count_nonzero(above)) - S
    sat = float(np.count_nonzero(A[mask] >= SATURATED_LEVEL)) / max(1, S)
    partial = FrameSpot(np.full(2, np.nan), np.full(2, np.nan), T, S, math.sqrt(S), np.full(2, np.nan),
                        k, peak, noise, sat, clipped)
    if S < limits.min_area_cells:
        raise _Invalid("no_spot", f"no spot: only {S} cells of the board lie above the threshold {T:.0f}.", partial)
    lost = int(np.count_nonzero((D_raw <= -T) & inside))
    if lost >= max(limits.min_area_cells, limits.max_lost_light_share * S):
        raise _Invalid("ambient_change", f"{lost} cells of the board were lit in the before frame and are "
                       f"{T:.0f} grey levels or more darker in the after frame (the spot has {S}): another beam "
                       "crossed the board while the before frame was taken.", partial, before_beam=True)
    if S >= limits.fills_board_share * np.count_nonzero(inside):
        below = below_share(a_s, b_s, lit, k)
        if below > limits.max_below_share:
            raise _Invalid("fills_board", f"the spot fills the board ({S} of its {np.count_nonzero(inside)} cells "
                           f"above the threshold {T:.0f}); {100 * below:.0f} % of the board is darker than the "
                           f"ambient light ratio {k:.2f} allows (limit {100 * limits.max_below_share:.0f} %): no "
                           "free board is left to judge the ambient light by.", partial)
    side = math.sqrt(S)
    core_share = None
    if clipped > limits.max_clipped_cells or side >= min(grid.shape):
        core = mirror = None
        if _off_frame_cells(above, inside) <= limits.max_clipped_cells:  # cut by the board's rim, not the frame
            dark = None
            if fill is None:  # L marks: the spot's light on them is lost (a dot board's fill restores it)
                dark = B < DARK_MARK_SHARE * float(np.median(B[inside]))
            core = core_region(Ddet, inside, T, peak, limits, dark)
            if core is None and limits.core_shares and limits.max_mirror_slope is not None:
                mirror = _mirror_spot(Dm * mask, inside, dark, limits)
        if mirror is not None:
            centre = mirror.center_cell
            side = math.sqrt(mirror.area_cells)
            if sat > limits.max_saturated_fraction:
                raise _Invalid("saturated", f"{100 * sat:.0f} % of the spot is saturated in the after frame "
                               f"(limit {100 * limits.max_saturated_fraction:.0f} %); close the aperture.", partial)
            return FrameSpot(centre, grid.cell_to_board(centre), T, S, side, centre, k, peak, noise, sat, clipped,
                             mirror_slope=float(mirror.slope.max()), mirror_asym=mirror.asymmetry)
        if core is None:
            # the visible part's centroid (biased toward the board): tells a search which way the beam lies
            seen = intensity_centroid(Dm * mask)
            partial = FrameSpot(seen, grid.cell_to_board(seen), T, S, side, np.full(2, np.nan), k, peak, noise, sat,
                                clipped)
            raise _Invalid("clipped", f"the spot runs over the edge of the board or the frame ({clipped} cells of "
                           "it on the rim); its centre would be biased.", partial)
        core_share, T, mask = core  # its core keeps off the rim: measured on the core alone
        S = int(np.count_nonzero(mask))
        side = math.sqrt(S)
    if sat > limits.max_saturated_fraction:
        raise _Invalid("saturated", f"{100 * sat:.0f} % of the spot is saturated in the after frame "
                       f"(limit {100 * limits.max_saturated_fraction:.0f} %); close the aperture.", partial)
    # I of A.1, on the part of the grid a window touching the spot can reach (windows elsewhere sum to 0)
    l_int = int(round(side))
    rows_any, cols_any = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(0, rows_any[0] - l_int), min(grid.shape[0], rows_any[-1] + l_int + 1)
    c0, c1 = max(0, cols_any[0] - l_int), min(grid.shape[1], cols_any[-1] + l_int + 1)
    I = Dm[r0:r1, c0:c1] * mask[r0:r1, c0:c1]
    origin = np.array([c0, r0], dtype=float)
    win_centre, _ = best_window(I, l_int)
    if method == "grlm":
        centre, win_side = win_centre, float(int(round(side)))
    elif method == "grlm-centroid":
        centre = window_centroid(I, win_centre, side)
        win_centre, win_side = centre, side
    elif method == "centroid":
        centre, win_side = intensity_centroid(I), side
    else:  # pragma: no cover - checked by measure_spot
        raise ValueError(method)
    centre, win_centre = centre + origin, win_centre + origin
    return FrameSpot(centre, grid.cell_to_board(centre), T, S, win_side, win_centre, k, peak, noise, sat, clipped,
                     core_share)


# ---------------------------------------------------------------------------- public
_GRIDS: dict = {}
_GRIDS_LOCK = threading.Lock()
_GRIDS_KEPT = 16
"""Board grids kept (a live run measures its boards' spots on the cameras' threads, each with its own marks)."""


def _grid_for(marks: MarksResult, target: Target, shape, cells_per_m) -> BoardGrid:
    """The board grid, memoised for the same marks object (a campaign reuses the marks of its before frame)."""
    key = (id(marks), target.id, tuple(shape), cells_per_m)
    with _GRIDS_LOCK:
        hit = _GRIDS.get(key)
    if hit is not None and hit[0] is marks:
        return hit[1]
    grid = board_grid(marks, target, shape, cells_per_m)
    with _GRIDS_LOCK:
        while len(_GRIDS) >= _GRIDS_KEPT:
            _GRIDS.pop(next(iter(_GRIDS)))
        _GRIDS[key] = (marks, grid)
    return grid


def measure_spot(before: np.ndarray, afters: Sequence[np.ndarray], target: Target, camera: Camera | None = None,
                 method: str = "grlm-centroid", marks: MarksResult | None = None,
                 limits: SpotLimits | None = None, cells_per_m: float | None = None) -> SpotResult:
    """Measure the spot centre on the board from a before frame and one or more after frames.

    Parameters
    ----------
    before : ndarray uint8 (H, W)
        Frame without the beam on the board.
    afters : sequence of ndarray uint8 (H, W)
        Frames with the beam on the board.
    target : config.Target
        The board (size and marks).
    camera : config.Camera, optional
        Its intrinsics/distortion undistort the marks and the grid.
    method : {"grlm", "grlm-centroid", "centroid"}
    marks : MarksResult, optional
        Marks found earlier (on the before frame); found here otherwise.
    limits : SpotLimits, optional
    cells_per_m : float, optional
        Board grid resolution [cells/m]; default: the board's pixel scale in the frame.

    Returns
    -------
    SpotResult
        ``valid`` False with a reason code when the measurement cannot be trusted; never raises for
        bad input frames (reason "bad_frame").
    """
    if method not in METHODS:
        raise MeasurementError(f"unknown spot method {method!r}; choose one of {', '.join(METHODS)}")
    limits = limits or SpotLimits()
    afters = list(afters) if not isinstance(afters, np.ndarray) or afters.ndim == 3 else [afters]
    try:
        before = as_gray_u8(before, "before frame")
        if not afters:
            raise MeasurementError("no after frame given")
        afters = [as_gray_u8(a, f"after frame {i + 1}") for i, a in enumerate(afters)]
        for i, a in enumerate(afters):
            if a.shape != before.shape:
                raise MeasurementError(f"after frame {i + 1} is {a.shape[1]}×{a.shape[0]} px but the before frame "
                                       f"is {before.shape[1]}×{before.shape[0]} px")
    except MeasurementError as exc:
        return SpotResult(False, "bad_frame", f"{exc}.", method)
    if marks is None:
        marks = find_marks(before, target, camera, max_reprojection_px=limits.max_reprojection_px)
    if not marks.found:
        return SpotResult(False, marks.reason, marks.message, method, marks)
    if marks.reprojection_px > limits.max_reprojection_px:
        return SpotResult(False, "reprojection", f"the marks fit only to {marks.reprojection_px:.2f} px RMS "
                          f"(limit {limits.max_reprojection_px:.2f} px).", method, marks)
    grid = _grid_for(marks, target, before.shape, cells_per_m)
    dots = target.marks is not None and target.marks.kind == "dots"
    B = _sample(grid, before, dots)
    fill = None
    if dots:
        from helicalib.vision.dots import DotFill

        fill = DotFill(grid, B, target.marks)
    base = dict(method=method, marks=marks, target_center_px=marks.center_px, cells_per_m=grid.cells_per_m)
    frames: list[FrameSpot] = []
    for i, a in enumerate(afters):
        try:
            frames.append(_frame_spot(B, _sample(grid, a, dots), grid, method, limits, fill))
        except _Invalid as bad:
            extra = dict(threshold=None, spot_area_px=None)
            if bad.partial is not None and bad.partial.area_cells:
                extra = dict(threshold=bad.partial.threshold, spot_area_px=float(bad.partial.area_cells),
                             spot_area_m2=bad.partial.area_cells / grid.cells_per_m**2)
            if bad.reason == "clipped" and bad.partial is not None and np.all(np.isfinite(bad.partial.offset_m)):
                # invalid, but where the visible part of the spot lies (a search is led by it)
                extra["offset_m"] = np.asarray(bad.partial.offset_m, dtype=float)
            where = f" (after frame {i + 1})" if len(afters) > 1 else ""
            return SpotResult(False, bad.reason, bad.message.rstrip(".") + where + ".", failed_frame=i,
                              frames=tuple(frames) + ((bad.partial,) if bad.partial else ()),
                              before_beam=bad.before_beam, **extra, **base)
    offsets = np.array([f.offset_m for f in frames])
    mean = offsets.mean(axis=0)
    jitter = float(np.sqrt(np.mean(np.sum((offsets - mean) ** 2, axis=1)))) if len(frames) > 1 else None
    f0 = frames[0]
    h = f0.window_side_cells / 2
    wc = f0.window_center_cell
    corners_cells = wc + np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    window_px = board_to_image(marks, grid.cell_to_board(corners_cells))
    result = dict(spot_center_px=board_to_image(marks, mean[None, :])[0], offset_m=mean,
                  spot_area_px=float(np.mean([f.area_cells for f in frames])),
                  spot_area_m2=float(np.mean([f.area_cells for f in frames])) / grid.cells_per_m**2,
                  threshold=float(np.mean([f.threshold for f in frames])), jitter_m=jitter, window_px=window_px,
                  window_side_m=f0.window_side_cells / grid.cells_per_m, frame_offsets_m=offsets, frames=tuple(frames))
    if jitter is not None and jitter > limits.max_jitter_m:
        return SpotResult(False, "jitter", f"the spot moved {jitter * 1000:.0f} mm RMS over {len(frames)} frames "
                          f"(limit {limits.max_jitter_m * 1000:.0f} mm; wind?).", **result, **base)
    cores = [f.core_share for f in frames if f.core_share is not None]
    mirrors = [f.mirror_slope for f in frames if f.mirror_slope is not None]
    msg = (f"spot centre at u = {mean[0]:+.3f} m, v = {mean[1]:+.3f} m from the board centre ({method}"
           + (f", {len(frames)} frames, jitter {jitter * 1000:.0f} mm RMS" if jitter is not None else "")
           + (f"; on its core above {100 * max(cores):.0f} % of the peak, the spot at the threshold running "
              "over the rim" if cores else "")
           + (f"; from the symmetry of its visible part, the spot running over the rim, slope "
              f"{max(mirrors):.2f}" if mirrors else "") + ").")
    return SpotResult(True, "ok", msg, **result, **base)


def _sample(grid: BoardGrid, frame: np.ndarray, exact: bool) -> np.ndarray:
    """The frame on the grid: uint8 (the interpolated values rounded) or, ``exact``, float32."""
    return grid.sample(frame.astype(np.float32) if exact else frame, dtype=None)
