"""What an error-model fit is given: the observations (:class:`FitPoints`), how to fit them
(:class:`FitOptions`), and the fit's unknowns in the solver's whitened units (:class:`Unknowns`).

A fit has three modes beyond the plain one, each switched on by a column of :class:`FitPoints`:
weights per observation (``sigma_scale``), a steady pedestal tilt rate (``age_days``), and the
epochs between confirmed drifts (``epoch``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from helicalib.geometry import error_model as em

FIT_METHODS = ("fast", "reference")
"""Solvers of :func:`helicalib.calibration.fit.fit_error_model`: ``"fast"`` (analytic Jacobian,
damped Gauss-Newton: compiled in :mod:`helicalib.calibration.fit_kernels` by default, numpy in
:mod:`helicalib.calibration.fit_solver` with ``solver="numpy"``) and ``"reference"``
(``scipy.optimize.least_squares``, TRF, with a central-difference Jacobian). Both minimise the same cost."""
SIGMA_MRAD = 0.3
"""Default measurement noise of one beam-angle component [mrad] (``sigma_mrad`` of the fit)."""
TILT_RATE_SIGMA_MRAD_PER_DAY = 0.02
"""Prior σ of a pedestal's tilt rate per axis [mrad/day] in a fit with ``age_days``: 0.14 mrad
a week, 7 mrad a year (foundations settle by a few mrad in their first years; the data of a few
weeks determine the rate far more tightly)."""
TILT = np.array([em.index("pedestal_tilt_e_mrad"), em.index("pedestal_tilt_n_mrad")])
"""The columns of the pedestal's tilts in ``error_model.PARAMETERS``."""
EPOCH_PARAMS = ("stroke_offset_1_mm", "stroke_offset_2_mm", "pedestal_tilt_e_mrad", "pedestal_tilt_n_mrad")
"""The parameters a drift changes, which a fit with ``epoch`` gives each earlier epoch its own
offset of: the pedestal's tilts (a foundation settles or creeps) and the actuators' zero offsets (an
actuator or its encoder is swapped). The others (canting, axes, pivot, arms) are the heliostat's
build and stay one for all epochs."""
EPOCH_SIGMA = {"stroke_offset_1_mm": 5.0, "stroke_offset_2_mm": 5.0, "pedestal_tilt_e_mrad": 5.0,
               "pedestal_tilt_n_mrad": 5.0}
"""Prior σ of an earlier epoch's offset from the next, per :data:`EPOCH_PARAMS` (mean 0): wider than
the drifts helicalib is built to find (steps of 2-5 mrad, creeps of a few mrad, zero offsets of
1-3 mm), so the data, not the prior, size them."""
EPOCH = np.array([em.index(n) for n in EPOCH_PARAMS])
"""The columns of :data:`EPOCH_PARAMS` in ``error_model.PARAMETERS``."""


@dataclass(frozen=True)
class FitPoints:
    """One heliostat's K observations for a fit.

    Attributes
    ----------
    strokes_mm : (K, 2) strokes held [mm]
    sun_enu : (K, 3) unit sun vectors at the captures
    spot_enu : (K, 3) observed spot centres [m, ENU]
    approach : (K, 2), optional
        Direction of each actuator's last motion before each observation (±1; 0 = unknown): lets
        the fit see the backlash parameters. A dead band is determined only where the data hold
        both directions of an actuator; otherwise its prior keeps it near 0 and the stroke offset
        takes the one-sided shift.
    sigma_scale : (K,), optional
        Each observation's noise σ is ``sigma_mrad`` times this (≥ 1 weighs it less; default all 1).
    age_days : (K,), optional
        Each observation's age [days] (≥ 0; the newest 0). Given, the fit adds a **pedestal tilt
        rate** (east, north) [mrad/day], with a prior of mean 0 and σ
        ``FitOptions.tilt_rate_sigma_mrad_per_day``: an observation of age ``a`` is fitted with the
        pedestal tilts ``tilt − a · rate``, so points of other seasons stay consistent with a
        foundation that settles at a steady rate, and ``params`` are the parameters now (age 0).
        The fast solver takes the tilt change to first order; the reference solver evaluates each
        observation with its own tilts (on a heliostat tilting 2.6 mrad over 120 days their beams
        agree to 0.002 mrad).
    epoch : (K,) int, optional
        Each observation's epoch: 0 for the newest (the heliostat as it is now), 1, 2, ... for the
        ones before each confirmed drift, counting back. Given, every earlier epoch gets its own
        offset of the :data:`EPOCH_PARAMS` (the tilts and zero offsets a drift changes; prior σ
        :data:`EPOCH_SIGMA`), and the other parameters stay one for all epochs: the points from
        before a drift keep determining the heliostat's build, and ``params`` are the newest
        epoch's. Both solvers evaluate each epoch with its own parameters exactly.
    """

    strokes_mm: np.ndarray
    sun_enu: np.ndarray
    spot_enu: np.ndarray
    approach: np.ndarray | None = None
    sigma_scale: np.ndarray | None = None
    age_days: np.ndarray | None = None
    epoch: np.ndarray | None = None


@dataclass(frozen=True)
class FitOptions:
    """How a fit is made.

    Attributes
    ----------
    prior_sigma : overrides of the default prior σ by name (units of each parameter)
    free : names to fit (default all; without ``approach`` all but the backlash parameters, which
        the data then cannot see); the others stay at the model's parameters
    loss, f_scale_mrad : robust loss of ``least_squares`` and its scale [mrad]
    sigma_mrad : measurement noise of one beam-angle component [mrad]
    residual_kind : "beam" or "normal"
    method : "fast" (default) or "reference" (:data:`FIT_METHODS`)
        ``"fast"``: analytic Jacobian and a damped Gauss-Newton run to a step of 1e-9 prior σ; if
        it does not converge, the reference solver takes over. ``"reference"``:
        ``scipy.optimize.least_squares`` (TRF) with a central-difference Jacobian, whose covariance
        also uses that Jacobian. Both minimise the same cost; on recorded campaign observations
        their predicted beams agree to well under 0.001 mrad (docs/model.md).
    tilt_rate_sigma_mrad_per_day : the tilt rate's prior σ (:data:`TILT_RATE_SIGMA_MRAD_PER_DAY`;
        with ``FitPoints.age_days``)
    n_suggestions : how many sun positions the identifiability report suggests (0: none, the
        campaign's refits)
    candidate_sun_enu : (C, 3) sun positions to rank in that report (default: a sky grid,
        elevation 10–80°); ``aim_enu`` (3,) the aim point for them (default: mean observed spot)
    """

    prior_sigma: Mapping[str, float] | None = None
    free: Sequence[str] | None = None
    loss: str = "soft_l1"
    f_scale_mrad: float = 1.0
    sigma_mrad: float = SIGMA_MRAD
    residual_kind: str = "beam"
    method: str = "fast"
    tilt_rate_sigma_mrad_per_day: float = TILT_RATE_SIGMA_MRAD_PER_DAY
    n_suggestions: int = 3
    candidate_sun_enu: np.ndarray | None = None
    aim_enu: np.ndarray | None = None


@dataclass(frozen=True)
class Unknowns:
    """A fit's unknowns ``x`` in whitened units, and the parameters they stand for.

    ``x`` holds the F free parameters (each ``(p − centre) / prior σ``), then with ``age`` the
    tilt rate (two, whitened by ``rate_scale``), then with ``epoch`` the ``n_ep`` older epochs'
    offsets of :data:`EPOCH_PARAMS`, epoch by epoch (whitened by ``ep_scale``).
    """

    free_names: tuple[str, ...]
    free_idx: np.ndarray
    sig_prior: np.ndarray
    base: np.ndarray
    """(P,) the model's parameters: the values of the fixed ones."""
    centre: np.ndarray
    """(P,) the priors' centre."""
    k: int
    age: np.ndarray | None = None
    rate_scale: float = 0.0
    epoch: np.ndarray | None = None
    n_ep: int = 0
    ep_scale: np.ndarray | None = None

    @property
    def f(self) -> int:
        return len(self.free_idx)

    @property
    def nr(self) -> int:
        return 2 if self.age is not None else 0

    def x0(self, start: np.ndarray | None) -> np.ndarray:
        """Where the solver starts: ``start`` (P,) (default the model's parameters), no tilt rate,
        no epoch offsets."""
        first = self.base if start is None else np.asarray(start, dtype=float).reshape(em.P)
        x0 = (first[self.free_idx] - self.centre[self.free_idx]) / self.sig_prior
        if self.age is not None:
            x0 = np.concatenate([x0, np.zeros(2)])
        if self.epoch is not None:
            x0 = np.concatenate([x0, np.zeros(self.n_ep * len(EPOCH))])
        return x0

    def params_of(self, xs: np.ndarray) -> np.ndarray:
        """(M, P) parameter sets of the unknowns (M, len(x)) (the newest epoch's, at age 0)."""
        out = np.repeat(self.base[None, :], len(xs), axis=0)
        out[:, self.free_idx] = self.centre[self.free_idx] + xs[:, :self.f] * self.sig_prior
        return out

    def offsets_of(self, xs: np.ndarray) -> np.ndarray:
        """(M, E + 1, m): each epoch's offsets of the EPOCH_PARAMS (row 0 zero)."""
        d = xs[:, self.f + self.nr:].reshape(len(xs), self.n_ep, len(EPOCH)) * self.ep_scale
        return np.concatenate([np.zeros((len(xs), 1, len(EPOCH))), d], axis=1)

    def rows_of(self, xs: np.ndarray) -> np.ndarray:
        """(M, K, P): each observation's parameters (the tilts of its age, the offsets of its epoch)."""
        out = np.repeat(self.params_of(xs)[:, None, :], self.k, axis=1)
        if self.age is not None:
            out[:, :, TILT] -= self.age[None, :, None] * (xs[:, None, self.f:self.f + self.nr] * self.rate_scale)
        if self.epoch is not None:
            out[:, :, EPOCH] += self.offsets_of(xs)[:, self.epoch, :]
        return out


def unknowns(model, k: int, points: FitPoints, options: FitOptions, approach, prior_mean) -> Unknowns:
    """The :class:`Unknowns` of a fit of ``model`` (N = 1) to K observations; ``approach``: the
    points' approach, None when not recorded; ``prior_mean`` (P,), optional, the priors' centre
    (default 0: the nominal heliostat)."""
    if options.free is None:
        free_names = tuple(em.NAMES) if approach is not None else em.GEOMETRIC
    else:
        free_names = tuple(options.free)
    free_idx = np.array([em.index(n) for n in free_names], dtype=int)
    sig_prior = em.prior_sigma(options.prior_sigma)[free_idx]
    centre = np.zeros(em.P) if prior_mean is None else np.asarray(prior_mean, dtype=float).reshape(em.P)
    age = None
    if points.age_days is not None:
        if not np.all(np.isin(TILT, free_idx)):
            raise ValueError("a tilt rate (age_days) needs both pedestal tilts free")
        age = np.asarray(points.age_days, dtype=float).reshape(k)
    rate_scale = float(options.tilt_rate_sigma_mrad_per_day) if age is not None else 0.0
    epoch, n_ep, ep_scale = None, 0, None
    if points.epoch is not None:
        epoch = np.asarray(points.epoch, dtype=int).reshape(k)
        if np.any(epoch < 0):
            raise ValueError("epoch must be 0 (the newest epoch) or more")
        if not np.all(np.isin(EPOCH, free_idx)):
            raise ValueError(f"epochs need {', '.join(EPOCH_PARAMS)} free")
        n_ep = int(epoch.max()) if k else 0
        ep_scale = np.array([EPOCH_SIGMA[n] for n in EPOCH_PARAMS])
    return Unknowns(free_names=free_names, free_idx=free_idx, sig_prior=sig_prior, base=model.params[0].copy(),
                    centre=centre, k=k, age=age, rate_scale=rate_scale, epoch=epoch, n_ep=n_ep, ep_scale=ep_scale)
