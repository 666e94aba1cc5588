"""Each visit's camera exposure, and the corrected exposure of a retake (pure: numbers in, numbers out).

A camera that takes an exposure (PLANT_INTERFACE 1.1) is exposed per visit so that the spot's
brightest grey level in the after frame, board light included, lands near :data:`TARGET_GREY`, well
under saturation, whatever the heliostat's distance, the sun, DNI and its mirror's soiling:

    exposure_ms = TARGET_GREY / (ambient_rate + spot_gain · E_peak)

* ``E_peak`` [W/m²] is the spot's expected peak irradiance (:func:`expected_peak_wm2`): the power a
  mirror of this cleanliness sends (``DNI · A · ρ · cos θ · τ_atm · c``, the flux models of
  :mod:`helicalib.flux.cleanliness`) spread over its footprint blurred by the sun shape and the slope
  error over the slant distance (:data:`BEAM_SIGMA_MRAD`), stretched by the board's obliquity;
* ``spot_gain`` [grey per W/m² per ms] is what the camera's valid readings taught: the difference's
  peak over ``E_peak · exposure``, the median of the last :data:`GAIN_MEMORY` readings not touched by
  saturation (its prior: the camera's flux factor Fe at its reference exposure; without either, the
  camera's own exposure is kept until a reading teaches it);
* ``ambient_rate`` [grey per ms] is the white board's level in the last before frame over its exposure.

A reading refused as too bright or too faint is taken again (before and after frames, one exposure)
at the exposure :func:`retake_exposure_ms` gives, at most :data:`MAX_EXPOSURE_RETAKES` times:

* ``saturated`` (a saturated plateau), or ``clipped`` with more than :data:`CLIPPED_SATURATED_SHARE`
  of its spot at ≥ 250 grey levels: shorter, by the measured peak or ×:data:`SHORTER`. A
  clipped spot without such a plateau is a beam cut by the board's rim, which no exposure mends:
  it goes to the visit's search as it always did;
* ``low_contrast``: longer, so that the measured peak and the board reach :data:`TARGET_GREY` (at
  most ×:data:`LONGER_MAX`), or ×:data:`LONGER` when the peak is lost in the noise; never so long
  that the board itself would pass :data:`MAX_BOARD_GREY`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.special import erf

from helicalib.flux.cleanliness import atmospheric_attenuation, cos_incidence

TARGET_GREY = 170.0
"""The after frame's spot peak (board light plus spot) an exposure aims at [grey levels of 255]."""
MAX_BOARD_GREY = 200.0
"""A longer exposure never puts the white board above this [grey levels]: the spot must stay readable on it."""
BEAM_SIGMA_MRAD = 3.9
"""The beam's angular spread, one σ [mrad]: a Gaussian sun of 2.5 mrad and twice a 1.5 mrad slope
error in quadrature. A field whose mirrors differ is taken up by the learned gain (it enters the
spot's peak only as a scale for distant heliostats)."""
GAIN_MEMORY = 9
"""The spot gain is the median over this many of the camera's latest valid readings."""
MAX_EXPOSURE_RETAKES = 2
"""A reading refused as too bright or too faint is taken again at most this many times."""
SHORTER = 0.4
"""Factor of a retake after a saturated plateau whose true height the frame does not show."""
LONGER = 2.5
"""Factor of a retake after a faint reading whose peak is lost in the noise."""
LONGER_MAX = 8.0
"""The most a faint reading's measured peak may lengthen the exposure by, at one retake."""
CLIPPED_SATURATED_SHARE = 0.02
"""A ``clipped`` reading whose spot holds more than this share of saturated cells is too bright (its
plateau spread the threshold over the rim), not cut by it."""
MIN_PEAK_NOISE = 3.0
"""A faint reading's peak below this many noise σ says nothing of its height (×:data:`LONGER` then)."""


@dataclass(frozen=True)
class SpotFigures:
    """What a reading showed of the light: the difference's peak [grey], its noise σ [grey], the
    saturated share of the spot, the white board's level in the before frame [grey], all at
    ``exposure_ms``; None where the vision did not get that far."""

    exposure_ms: float
    peak: float | None = None
    noise: float | None = None
    saturated_fraction: float | None = None
    board_grey: float | None = None


def expected_peak_wm2(dni_wm2: float, mirror_size_m, pivot_enu_m, target_centre_enu_m, board_normal_enu,
                      sun_enu, cleanliness: float = 1.0, reflectivity: float = 0.93,
                      atmosphere: str | None = "clear") -> float:
    """The spot's expected peak irradiance on the board [W/m²] for a beam aimed at its centre.

    Power ``DNI · A · ρ · cos θ · τ_atm · c`` over the mirror's footprint (its sides × √cos θ)
    convolved with a Gaussian of :data:`BEAM_SIGMA_MRAD` × the slant distance, both stretched by
    1/√cos of the beam's angle to the board normal; 0 when the sun is behind the mirror."""
    pivot = np.asarray(pivot_enu_m, dtype=float)
    centre = np.asarray(target_centre_enu_m, dtype=float)
    slant = float(np.linalg.norm(centre - pivot))
    cos_inc = float(cos_incidence(np.asarray(sun_enu, dtype=float), pivot, centre))
    if not (slant > 0 and cos_inc > 0 and dni_wm2 > 0):
        return 0.0
    beam = (centre - pivot) / slant
    cos_b = abs(float(beam @ np.asarray(board_normal_enu, dtype=float)))
    stretch = 1.0 / math.sqrt(max(cos_b, 0.05))
    tau = 1.0 if atmosphere in (None, "none") else float(atmospheric_attenuation(slant, atmosphere))
    sides = np.asarray(mirror_size_m, dtype=float).reshape(2)
    power = dni_wm2 * float(np.prod(sides)) * reflectivity * cos_inc * tau * max(cleanliness, 0.0)
    sigma = 1e-3 * BEAM_SIGMA_MRAD * slant * stretch
    peak = power
    for side in sides:
        w = side * math.sqrt(cos_inc) * stretch
        peak *= erf(w / (2.0 * math.sqrt(2.0) * sigma)) / w  # the box ⊗ Gaussian at its centre, per axis
    return float(peak)


@dataclass
class ExposurePolicy:
    """One camera's exposure policy and what its frames taught (mutable, no I/O).

    ``range_ms``: the exposures asked for are kept within it (the camera clamps too).
    ``prior_gain``: grey per W/m² per ms before any reading taught one (None: unknown).
    """

    range_ms: tuple[float, float] = (0.01, 100.0)
    prior_gain: float | None = None
    gains: deque = field(default_factory=lambda: deque(maxlen=GAIN_MEMORY))
    ambient_rate: float | None = None
    """The white board's grey level per ms of exposure in the latest before frame."""

    def spot_gain(self) -> float | None:
        """Grey levels of the difference's peak per W/m² of expected peak per ms (None: not known)."""
        return float(np.median(self.gains)) if self.gains else self.prior_gain

    def clamp(self, exposure_ms: float) -> float:
        return float(min(max(exposure_ms, self.range_ms[0]), self.range_ms[1]))

    def choose(self, expected_peak: float | None) -> float | None:
        """The visit's exposure [ms] for a spot of ``expected_peak`` [W/m²]; None: no basis to
        choose one yet (keep the camera's)."""
        gain = self.spot_gain()
        if gain is None or expected_peak is None or not expected_peak > 0:
            return None
        rate = gain * expected_peak + (self.ambient_rate or 0.0)
        return self.clamp(TARGET_GREY / rate) if rate > 0 else None

    def saw_board(self, board_grey: float | None, exposure_ms: float) -> None:
        """A before frame: the white board at ``board_grey`` at ``exposure_ms``."""
        if board_grey is not None and math.isfinite(board_grey) and board_grey > 0 and exposure_ms > 0:
            self.ambient_rate = board_grey / exposure_ms

    def learn(self, figures: SpotFigures, expected_peak: float | None) -> None:
        """A valid reading: its peak per expected irradiance and ms joins the gain's median
        (unless saturation cut its peak, or nothing was expected)."""
        if (figures.peak is None or expected_peak is None or not expected_peak > 0 or not figures.peak > 0
                or (figures.saturated_fraction or 0.0) > 0.0):
            return
        self.gains.append(figures.peak / (expected_peak * figures.exposure_ms))

    def retake_exposure_ms(self, reason: str, figures: SpotFigures) -> float | None:
        """The exposure [ms] to take a reading refused for ``reason`` again at, or None when no
        exposure can mend it (a spot cut by the rim, an exposure at the end of the range)."""
        e = figures.exposure_ms
        sat = figures.saturated_fraction or 0.0
        if reason == "saturated" or (reason == "clipped" and sat > CLIPPED_SATURATED_SHARE):
            factor = SHORTER
            if figures.peak is not None and figures.peak > 0 and sat == 0.0:
                factor = min(SHORTER, TARGET_GREY / (figures.peak + (figures.board_grey or 0.0)))
            new = self.clamp(e * factor)
            return new if new < e else None
        if reason == "low_contrast":
            factor = LONGER
            if figures.peak is not None and figures.noise is not None and figures.peak > MIN_PEAK_NOISE * figures.noise:
                factor = min(LONGER_MAX, TARGET_GREY / (figures.peak + (figures.board_grey or 0.0)))
            if figures.board_grey is not None and figures.board_grey > 0:
                factor = min(factor, MAX_BOARD_GREY / figures.board_grey)
            new = self.clamp(e * factor)
            return new if new > e * 1.05 else None
        return None


def board_grey(image: np.ndarray, marks, target) -> float | None:
    """The white board's grey level in ``image``: the median over a 15 × 15 lattice of board points
    within 40 % of its half-sizes of the centre (marks and dots are a minority of them); None
    without marks."""
    from helicalib.vision.homography import board_to_image

    if marks is None or not getattr(marks, "found", False):
        return None
    hw, hh = 0.4 * target.size_m[0], 0.4 * target.size_m[1]
    uu, vv = np.meshgrid(np.linspace(-hw, hw, 15), np.linspace(-hh, hh, 15))
    px = np.rint(board_to_image(marks, np.column_stack([uu.ravel(), vv.ravel()]))).astype(int)
    h, w = image.shape[:2]
    ok = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    if not ok.any():
        return None
    return float(np.median(image[px[ok, 1], px[ok, 0]]))


class BeforeState(tuple):
    """A camera sensor's before reference, ``(image, marks)``, and the exposure it was taken at
    (``exposure_ms``, None: a camera without exposure control) with the spot's expected peak
    irradiance then (``expected_peak``, W/m²) and the white board's level in it (``board_grey``);
    None where not known. The after frames (and a before frame taken again) ask for the same
    exposure: a board's camera may serve several visits at once."""

    def __new__(cls, image, marks, exposure_ms: float | None = None, expected_peak: float | None = None,
                board_grey: float | None = None):
        self = super().__new__(cls, (image, marks))
        self.exposure_ms, self.expected_peak, self.board_grey = exposure_ms, expected_peak, board_grey
        return self


class AfterImages(list):
    """A reading's after images, and what they showed of the light (``figures``, a :class:`SpotFigures`
    or None: a camera without exposure control)."""

    figures: SpotFigures | None = None
