"""The sun's daily course at a site: when it crosses the acceptance elevations (paper 2.4).

:func:`sun_days` samples the SPA sun once a minute and interpolates the crossings of the
acceptance band edges (``low_band_deg``) and of ``high_elevation_deg``; :class:`SunDay` holds
them for one solar day (centred on the sun's transit). Acceptance, gap finding and the planner
all take these days, so they stay pure functions of arrays: the sun is computed once, here.

A crossing interpolated between one-minute samples is within a few seconds of the SPA crossing;
rules that need exactness (the band membership of a point) use the point's own sun elevation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

SECONDS_PER_DAY = 86400.0


@dataclass(frozen=True)
class SunDay:
    """One solar day's crossings, plant time [UTC s]; None when the sun does not reach that elevation.

    Attributes
    ----------
    noon_s : float
        Transit (highest elevation) of the day.
    noon_elevation_deg : float
        Elevation at transit [deg].
    rise_band_start_s, rise_band_end_s : float or None
        The sun rises through ``low_band_deg[0]`` and ``low_band_deg[1]``; if it never reaches the
        upper edge the band ends at noon.
    set_band_start_s, set_band_end_s : float or None
        The sun sets through ``low_band_deg[1]`` (or noon) and ``low_band_deg[0]``.
    high_start_s, high_end_s : float or None
        The sun is above ``high_elevation_deg`` between these.
    """

    noon_s: float
    noon_elevation_deg: float
    rise_band_start_s: float | None
    rise_band_end_s: float | None
    set_band_start_s: float | None
    set_band_end_s: float | None
    high_start_s: float | None
    high_end_s: float | None

    @property
    def high_span_s(self) -> float:
        """Length of the time above ``high_elevation_deg`` [s] (0 when the sun stays below)."""
        if self.high_start_s is None or self.high_end_s is None:
            return 0.0
        return self.high_end_s - self.high_start_s

    @property
    def daylight(self) -> tuple[float, float] | None:
        """(start, end) [UTC s] of the time the sun is above ``low_band_deg[0]``: when any point can be taken."""
        if self.rise_band_start_s is None or self.set_band_end_s is None:
            return None
        return (self.rise_band_start_s, self.set_band_end_s)

    def high_window(self, k: int, n_windows: int) -> tuple[float, float] | None:
        """(start, end) [UTC s] of high-elevation window ``k`` of ``n_windows`` equal windows, or None."""
        if self.high_start_s is None or self.high_end_s is None or n_windows <= 0:
            return None
        length = self.high_span_s / n_windows
        return (self.high_start_s + k * length, self.high_start_s + (k + 1) * length)


def n_high_windows(span_s: float, window_h: float) -> int:
    """How many equal windows, each at most ``window_h`` long, cut a high-elevation span.

    ``ceil(span / window)``: a 9.5 h span with 2 h windows gives 5 windows of 1.9 h.
    """
    if span_s <= 0:
        return 0
    return max(1, math.ceil(span_s / (window_h * 3600.0) - 1e-9))


def _crossings(t: np.ndarray, elev: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Times [s] where ``elev`` crosses ``level`` upward and downward (linear interpolation)."""
    d = elev - level
    up = np.nonzero((d[:-1] < 0) & (d[1:] >= 0))[0]
    down = np.nonzero((d[:-1] >= 0) & (d[1:] < 0))[0]

    def interp(i: np.ndarray) -> np.ndarray:
        return t[i] + (t[i + 1] - t[i]) * (-d[i]) / (d[i + 1] - d[i])

    return interp(up), interp(down)


def days_from_elevations(times_s: np.ndarray, elevation_deg: np.ndarray, low_band_deg: Sequence[float],
                         high_elevation_deg: float) -> tuple[SunDay, ...]:
    """The :class:`SunDay` list from sampled elevations (pure; :func:`sun_days` feeds it the SPA sun).

    Parameters
    ----------
    times_s : ndarray, shape (N,)
        Increasing sample times [UTC s], covering whole days.
    elevation_deg : ndarray, shape (N,)
        Sun elevation at those times [deg].
    low_band_deg : (float, float)
        Acceptance band edges [deg].
    high_elevation_deg : float
        Elevation above which the 2 h windows apply [deg].
    """
    t = np.asarray(times_s, dtype=float)
    e = np.asarray(elevation_deg, dtype=float)
    # transits: local maxima of the elevation, one per solar day
    peaks = np.nonzero((e[1:-1] >= e[:-2]) & (e[1:-1] > e[2:]))[0] + 1
    lo, hi = float(low_band_deg[0]), float(low_band_deg[1])
    cross = {level: _crossings(t, e, level) for level in {lo, hi, float(high_elevation_deg)}}
    days = []
    for p in peaks:
        noon = float(t[p])
        start, end = noon - SECONDS_PER_DAY / 2, noon + SECONDS_PER_DAY / 2

        def rise(level: float) -> float | None:
            ups = cross[level][0]
            ups = ups[(ups > start) & (ups <= noon)]
            return float(ups[-1]) if ups.size else None

        def set_(level: float) -> float | None:
            downs = cross[level][1]
            downs = downs[(downs >= noon) & (downs < end)]
            return float(downs[0]) if downs.size else None

        r_lo, s_lo = rise(lo), set_(lo)
        r_hi = rise(hi) if r_lo is not None else None
        s_hi = set_(hi) if s_lo is not None else None
        days.append(SunDay(
            noon_s=noon, noon_elevation_deg=float(e[p]),
            rise_band_start_s=r_lo, rise_band_end_s=(r_hi if r_hi is not None else (noon if r_lo is not None else None)),
            set_band_start_s=(s_hi if s_hi is not None else (noon if s_lo is not None else None)), set_band_end_s=s_lo,
            high_start_s=rise(float(high_elevation_deg)), high_end_s=set_(float(high_elevation_deg)),
        ))
    return tuple(days)


def sun_days(site, start_s: float, end_s: float, low_band_deg: Sequence[float], high_elevation_deg: float,
             step_s: float = 60.0) -> tuple[SunDay, ...]:
    """Solar days whose transit lies in ``[start_s - 12 h, end_s + 12 h]``, from the SPA sun at ``site``.

    Parameters
    ----------
    site : helicalib.config.Site
        The plant site (latitude, longitude, altitude, pressure, temperature).
    start_s, end_s : float
        Interval of interest [UTC s]; every day overlapping it is returned, in order.
    low_band_deg, high_elevation_deg :
        As ``FieldConfig.acceptance``.
    step_s : float
        Sampling step [s].
    """
    from helicalib.geometry.sun import sun_at_site

    t = np.arange(start_s - SECONDS_PER_DAY, end_s + SECONDS_PER_DAY + step_s, step_s)
    elev = np.asarray(sun_at_site(site, t).elevation_deg, dtype=float)
    days = days_from_elevations(t, elev, low_band_deg, high_elevation_deg)
    half = SECONDS_PER_DAY / 2
    return tuple(d for d in days if start_s - half <= d.noon_s <= end_s + half)


def day_of(times_s: np.ndarray, days: Sequence[SunDay]) -> np.ndarray:
    """Index into ``days`` of the solar day (transit ± 12 h) each time falls in; -1 outside all days."""
    t = np.atleast_1d(np.asarray(times_s, dtype=float))
    if not days:
        return np.full(t.shape, -1, dtype=int)
    noons = np.array([d.noon_s for d in days])
    idx = np.clip(np.searchsorted(noons, t), 0, len(days) - 1)
    prev = np.clip(idx - 1, 0, len(days) - 1)
    nearer = np.where(np.abs(t - noons[prev]) < np.abs(t - noons[idx]), prev, idx)
    inside = np.abs(t - noons[nearer]) <= SECONDS_PER_DAY / 2
    return np.where(inside, nearer, -1)


def is_rising(times_s: np.ndarray, days: Sequence[SunDay]) -> np.ndarray:
    """True where a time lies before its day's transit (the sun is rising)."""
    t = np.atleast_1d(np.asarray(times_s, dtype=float))
    idx = day_of(t, days)
    noons = np.array([d.noon_s for d in days] or [np.nan])
    return np.where(idx >= 0, t < noons[np.maximum(idx, 0)], False)
