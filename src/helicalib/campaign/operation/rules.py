"""Year-round operation: which calibrated heliostat to check next, and what a drift does.

After commissioning (or instead of it) the runner in *operation* (``helicalib operate``,
``simulate --operate``) keeps every calibrated heliostat's tracking corrections current, as a
campaign does, and spends the board time no acceptance gap needs on **checks**: a visit of an
accepted heliostat whose first placement, made with its newest model, tests that model where the
sun is now and adds a point there. This module holds the rules; the runner applies them.

The ranking rule (``docs/operation.md``)
-----------------------------------------
A check of heliostat *h* now is worth the expected reduction of the field's year-round squared
error it brings, per check (a check takes about the same board time for every heliostat):

``gain(h) = spread(h)² + D² · λ · Δt(h)``  [mrad²]

* ``spread(h)``: the model's predicted 1-σ beam error at the present sun
  (:func:`helicalib.calibration.fit.beam_spread_mrad`, from the fit's covariance). A point here
  removes most of that variance; new seasons open sun positions the model has never seen, where the
  spread is large, so the checks follow the sun into them;
* ``D² · λ · Δt``: the expected squared error from a drift not yet seen: ``λ`` drifts per
  heliostat-day (:data:`DRIFT_RATE_PER_YEAR` / 365), ``D`` their typical size
  (:data:`DRIFT_MRAD`), ``Δt`` the days since the heliostat's last visit.

A heliostat is checked only when its gain reaches :func:`min_gain_mrad2`, the drift term of a
heliostat left :data:`MAX_DAYS_UNCHECKED` days (so a sure model is still checked that often, and
drift is seen within days), at most once per :data:`MIN_CHECK_INTERVAL_S` (a solar day), and not
before its *preferred time* of the day: the time the day's sun is where its model is least sure
(evaluated every :data:`PREFERRED_STEP_S` once a day), so the checks cover the sky the points do
not, instead of crowding at sunrise; a heliostat a day overdue goes whatever the time. Each board's
checks are paced to :data:`CHECK_BOARD_SHARE` of the day's sunlit time so far. Highest gain first;
ties by the longest unchecked. A heliostat suspected of drift goes first, before the planner's own
choice; the crew's requests (console) go before everything.

Drift
-----
A check whose first placement lies outside the fit's predicted band
(:func:`helicalib.campaign.operation.drift.drift_evidence`, p below 0.001) makes the heliostat *suspected*:
it is checked again first, and that check, tested against the fit from before the first suspicious
check (a suspicious point must not widen the band it is judged by), confirms the drift when its p is
below :data:`CONFIRM_ALPHA` (one check alone could be a bad frame or a gust the vision did not
catch; the Gaussian band also flags an unchanged heliostat somewhat more often than its p says); a
check inside that band clears the suspicion. A slow creep moves each check only a little, and
the refits after each check follow it part of the way, so each check may stay inside its band: the
last :data:`TREND_CHECKS` checks whose whitened residuals lean the same way (their mean, p below
:data:`TREND_ALPHA`) make the heliostat suspected as well, and the confirming check is then tested
against the fit from before the first of them. A confirmed drift
**reopens** the heliostat's calibration: its points before the first suspicious check are left out
of every later fit and verdict (they stay in the database), because a step change makes them
wrong, not merely old: down-weighting them would leave a bias in proportion to their weight. The
fit after the drift is centred on the model from before it (its prior, instead of the nominal
heliostat's), so the two checks' points already move the parameters a settling or an actuator
swap changes, and the plant's tracking is right again at once; the paper's acceptance (the
verdict of record) must then be earned again on points after the drift, which the gaps planner
goes after as for any unaccepted heliostat.
"""

from __future__ import annotations

import math

import numpy as np

DRIFT_RATE_PER_YEAR = 0.05
"""Prior share of heliostats that drift in a year (settling, an actuator swapped, a storm)."""
DRIFT_MRAD = 3.0
"""Typical size of a drift [mrad] (steps of 2–5 mrad)."""
MAX_DAYS_UNCHECKED = 3.0
"""A heliostat with a sure model is still checked about this often [days]: the threshold of the gain."""
MIN_CHECK_INTERVAL_S = 20 * 3600.0
"""No second check of an unsuspected heliostat within this [plant s]: at most one a solar day."""
CONFIRM_CHECKS = 2
"""Consecutive checks outside the fit's band that confirm a drift."""
CONFIRM_ALPHA = 0.01
"""p-value below which a suspect's next check confirms the drift; it is tested against the fit from
before the first suspicious check (the suspicious point must not widen the band it is judged by),
and after a first check below p 0.001 a second below 0.01 is strong evidence together."""
TREND_CHECKS = 3
"""A slow creep: the last this many checks, each inside its band, whose whitened residuals lean the
same way (:func:`helicalib.campaign.operation.drift.trend_p_value`) ..."""
TREND_ALPHA = 1e-3
"""... below this p-value make the heliostat suspected, as one check outside its band does."""
TILT_RATE_IN_FITS = True
"""Operation's fits (either rule) have a steady pedestal tilt rate (``tilt_rate`` of
:func:`helicalib.campaign.verdict.refit`), and every point counts alike. Every heliostat drifts slowly
(foundations settle); a fit that weighs months of points alike without the rate lags it, and one
that weighs old points down (σ × exp(age / 20 d), the rule until 2026-11-26) follows it but forgets
the sun positions of past seasons: measured over 210 days, the models' error over the year's sky
fell from 1.50 to 0.79 mrad with the rate and all points alike (docs/benchmarks.md). A step change
(a drift confirmed by checks) opens a new epoch of the fits (:data:`helicalib.campaign.book.EPOCHS_AFTER_DRIFT`)."""
STILL_DAYS_AFTER_DRIFT = 14.0
"""With :data:`helicalib.campaign.book.EPOCHS_AFTER_DRIFT` off (the fits drop the points before a drift; the rule
until version 2026-11-27): after a confirmed drift a heliostat's fits have no steady tilt rate until its book holds a point
this many days after the newest confirmation. A creeping pedestal tilts by 0.1-0.3 mrad a day, and a
rate fitted to the few points since a confirmation follows it, so the checks stay inside their band
while it creeps on and its last days stay in the book (measured over 210 days, docs/benchmarks.md).
Without the rate the model stands still, the checks leave the band every few days while the creep
goes on (every 4-7 days on the measured creeps), and each confirmation drops the moving points
before it. Once none has come for this long the heliostat is taken to be still, and the rate comes
back for the slow settling of the months ahead (without it a settled heliostat's model drifted to
2.3 mrad over the sky in 145 days)."""


def fits_tilt_rate(operated: bool, drifted: bool, newest_point_s: float = math.inf,
                   confirmed_s: float = -math.inf, epochs: bool = False) -> bool:
    """Whether a heliostat's fits have the steady pedestal tilt rate: in operation
    (:data:`TILT_RATE_IN_FITS`), but not since a confirmed drift (confirmed at ``confirmed_s``)
    until the newest point of the fit (``newest_point_s``) lies :data:`STILL_DAYS_AFTER_DRIFT`
    after it, unless the fit carries the points from before the drift in epochs of their own
    (``epochs``, :data:`helicalib.campaign.book.EPOCHS_AFTER_DRIFT`): their months then pin the rate, and the few
    points since the drift cannot bend it to follow a creep."""
    if not (operated and TILT_RATE_IN_FITS):
        return False
    return not drifted or epochs or newest_point_s - confirmed_s >= STILL_DAYS_AFTER_DRIFT * 86400.0


PREFERRED_STEP_S = 1800.0
"""Each solar day the runner evaluates every fitted model's predicted error on the day's sun every
this many seconds; a heliostat's check waits for the time its model is least sure (its preferred
time), unless it is a day overdue."""
CHECK_BOARD_SHARE = 0.10
"""A board's checks take at most this share of the day's sunlit time so far (plus
:data:`CHECK_ALLOWANCE_S`): paced through the day, half the 20 % a plant grants calibration after
commissioning. Calibrations still open (acceptance gaps, a drift reopened) are not counted."""
CHECK_ALLOWANCE_S = 600.0
"""Board seconds of checks allowed ahead of the pace (a check or two at sunrise)."""
CHECK_AFTER_FRAMES = 10
"""A check's measurement is the mean of at least this many after frames (1 s apart; more when
``calibration.after_frames`` asks for more). Past commissioning the points of checks are what the
year's models stand on, and a single frame carries the wind's jitter whole: on the simulated
plant the jitter was 0.33 of the 0.43 mrad RMS by which a point missed the heliostat's
noise-free spot (90 days of operation, demo field); with ten frames a check's jitter is 0.10 of
0.28. Over 210 days the plant's tracking improved in six months of seven and the false drift
confirmation went (docs/benchmarks.md, "Checks of ten frames"). The frames cost a few seconds of
board time per check, which operation has to spare (checks took 2.1 % of it). The stroke
repeatability (the rest of that noise) is not averaged by frames."""
OPERATION_MODES = ("ranked", "rota")
"""``ranked``: the gain rule above; ``rota``: every heliostat every ``rota_days`` (the baseline)."""


def drift_term_mrad2(days_since: np.ndarray) -> np.ndarray:
    """Expected squared error from a drift not yet seen after ``days_since`` days [mrad²]."""
    lam = DRIFT_RATE_PER_YEAR / 365.0
    return DRIFT_MRAD**2 * lam * np.maximum(np.asarray(days_since, dtype=float), 0.0)


def min_gain_mrad2() -> float:
    """The gain a check must reach: the drift term of :data:`MAX_DAYS_UNCHECKED` days."""
    return float(drift_term_mrad2(np.array(MAX_DAYS_UNCHECKED)))


def check_gains(spread_mrad: np.ndarray, days_since: np.ndarray) -> np.ndarray:
    """``gain = spread² + D² λ Δt`` [mrad²] for each candidate; an unknown spread (NaN: no fit, or
    the aim out of reach) counts as 0."""
    spread = np.nan_to_num(np.asarray(spread_mrad, dtype=float), nan=0.0)
    return spread**2 + drift_term_mrad2(days_since)


def choose_check(ids: list[str], spread_mrad, last_visit_s, now_s: float, *, mode: str = "ranked",
                 rota_days: float = 14.0) -> str | None:
    """The heliostat of ``ids`` (accepted, free, off cool-down, mirror clean enough) to check now, or None.

    ``spread_mrad`` and ``last_visit_s`` are per id (NaN spread: unknown; -inf last visit: never).
    ``ranked``: the highest gain at or above :func:`min_gain_mrad2`, checked at most once per
    :data:`MIN_CHECK_INTERVAL_S`; ``rota``: the longest unchecked of those unchecked for
    ``rota_days``.
    """
    if not ids:
        return None
    last = np.asarray(last_visit_s, dtype=float)
    since_days = np.where(np.isfinite(last), (now_s - last) / 86400.0, 3650.0)
    if mode == "rota":
        due = np.flatnonzero(since_days >= rota_days)
        return ids[int(due[np.argmax(since_days[due])])] if due.size else None
    if mode != "ranked":
        raise ValueError(f"unknown operation mode {mode!r}; choose one of {', '.join(OPERATION_MODES)}")
    gain = check_gains(spread_mrad, since_days)
    ok = (since_days * 86400.0 >= MIN_CHECK_INTERVAL_S) & (gain >= min_gain_mrad2())
    sel = np.flatnonzero(ok)
    if not sel.size:
        return None
    best = sel[np.lexsort((-since_days[sel], -gain[sel]))[0]]
    return ids[int(best)]


def check_budget_s(day_grid: np.ndarray, now_s: float) -> float:
    """Board seconds of checks allowed by ``now_s``: :data:`CHECK_BOARD_SHARE` of the day's sunlit
    seconds so far (``day_grid``: the day's times with the sun up, every :data:`PREFERRED_STEP_S`)
    plus :data:`CHECK_ALLOWANCE_S`."""
    sunlit = float(np.count_nonzero(np.asarray(day_grid) <= now_s)) * PREFERRED_STEP_S
    return CHECK_BOARD_SHARE * sunlit + CHECK_ALLOWANCE_S


def days_to_fix(drift_start_s: float, fixed_s: float | None) -> float:
    """Days from a drift's start to the heliostat's acceptance after it (inf when not yet)."""
    return math.inf if fixed_s is None else max(0.0, (fixed_s - drift_start_s) / 86400.0)

