"""Apparent topocentric sun position by NREL SPA (pvlib's implementation), vectorised.

The sun vector ``s`` points from the observer to the sun in the local ENU frame
(x east, y north, z up); azimuth is from north, clockwise; elevation includes refraction for the
site's pressure and temperature. This is the only way helicalib computes the sun: the simple
textbook formulas are off by several mrad, more than the 3.5 mrad loop threshold.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from pvlib import spa
from pvlib.atmosphere import alt2pres

from helicalib.errors import ConfigError

ATMOS_REFRACT_DEG = 0.5667
"""Apparent sun elevation at sunrise/sunset used by SPA (refraction plus the solar radius) [deg]."""


@dataclass(frozen=True)
class SunPosition:
    """Sun position arrays, all of the broadcast shape of times and sites.

    Attributes
    ----------
    azimuth_deg : ndarray
        From north, clockwise [deg].
    elevation_deg : ndarray
        Apparent (refracted) elevation above the horizon [deg].
    zenith_deg : ndarray
        Apparent zenith angle, ``90 - elevation_deg`` [deg].
    vector_enu : ndarray, shape (..., 3)
        Unit vector from the site to the sun, ENU.
    """

    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray
    zenith_deg: np.ndarray
    vector_enu: np.ndarray


def parse_time(value: Any) -> pd.Timestamp:
    """One timezone-aware instant (ISO string, datetime or Timestamp) → UTC Timestamp.

    A time without a zone is refused: guessing local time misplaces the sun by hours.
    """
    try:
        ts = pd.Timestamp(value)
    except (ValueError, TypeError):
        raise ConfigError(f"time {value!r}: not an ISO 8601 time (e.g. 2026-06-21T12:00:00+08:00)") from None
    if ts.tzinfo is None:
        raise ConfigError(
            f"time {value!r}: no timezone offset; write it as e.g. {ts.isoformat()}Z or {ts.isoformat()}+08:00"
        )
    return ts.tz_convert("UTC")


def to_unix_seconds(times: Any) -> np.ndarray:
    """Times → float UTC seconds since the epoch, as an array.

    Accepts numbers (already UTC seconds), timezone-aware datetimes, Timestamps, ISO strings
    with an offset, a ``DatetimeIndex`` with a zone, or sequences of these. Naive times are refused.
    """
    if isinstance(times, pd.DatetimeIndex):
        if times.tz is None:
            raise ConfigError("times: DatetimeIndex without a timezone; localise it first")
        epoch = pd.Timestamp(0, tz="UTC")
        return np.asarray((times.tz_convert("UTC") - epoch) / pd.Timedelta("1s"), dtype=float)
    arr = np.asarray(times, dtype=object) if not isinstance(times, np.ndarray) else times
    if arr.dtype.kind in "iuf":
        return arr.astype(float)
    flat = [
        float(x) if isinstance(x, (int, float, np.number)) else _ts_seconds(parse_time(x))
        for x in np.ravel(arr)
    ]
    return np.asarray(flat, dtype=float).reshape(np.shape(arr))


def _ts_seconds(ts: pd.Timestamp) -> float:
    return (ts - pd.Timestamp(0, tz="UTC")) / pd.Timedelta("1s")


def delta_t_seconds(unix_s: np.ndarray) -> np.ndarray:
    """TT − UT1 [s] for the given instants (pvlib's polynomial of Espenak & Meeus)."""
    unix_s = np.asarray(unix_s, dtype=float)
    dt = pd.to_datetime(np.ravel(unix_s), unit="s", utc=True)
    years = np.asarray(dt.year, dtype=float)
    months = np.asarray(dt.month, dtype=float)
    return np.asarray(spa.calculate_deltat(years, months), dtype=float).reshape(unix_s.shape)


def sun_vector_from_angles(azimuth_deg: Any, elevation_deg: Any) -> np.ndarray:
    """Azimuth (from north, clockwise) and elevation [deg] → unit vector (..., 3), ENU."""
    az = np.radians(np.asarray(azimuth_deg, dtype=float))
    el = np.radians(np.asarray(elevation_deg, dtype=float))
    return np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=-1)


def angles_from_sun_vector(vector_enu: Any) -> tuple[np.ndarray, np.ndarray]:
    """Unit vector (..., 3), ENU → (azimuth_deg from north clockwise in [0, 360), elevation_deg)."""
    v = np.asarray(vector_enu, dtype=float)
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    az = np.degrees(np.arctan2(v[..., 0], v[..., 1])) % 360.0
    el = np.degrees(np.arcsin(np.clip(v[..., 2], -1.0, 1.0)))
    return az, el


def sun_position(
    times: Any,
    latitude_deg: Any,
    longitude_deg: Any,
    altitude_m: Any = 0.0,
    pressure_hpa: Any = None,
    temperature_c: Any = 12.0,
    delta_t_s: Any = None,
) -> SunPosition:
    """Apparent topocentric sun position by NREL SPA.

    Parameters
    ----------
    times : see :func:`to_unix_seconds`
        Instants, shape T (or scalar).
    latitude_deg, longitude_deg, altitude_m : array_like
        Site(s) [deg, deg, m]; broadcast against ``times``.
    pressure_hpa : array_like, optional
        Air pressure [hPa] for refraction; default the standard atmosphere at ``altitude_m``.
    temperature_c : array_like
        Air temperature [°C] for refraction.
    delta_t_s : array_like, optional
        TT − UT1 [s]; default from pvlib's polynomial for each instant's year and month.

    Returns
    -------
    SunPosition
        Arrays of the broadcast shape of all inputs.
    """
    unix_s = to_unix_seconds(times)
    if pressure_hpa is None:
        pressure_hpa = alt2pres(np.asarray(altitude_m, dtype=float)) / 100.0
    if delta_t_s is None:
        delta_t_s = delta_t_seconds(unix_s)
    args = np.broadcast_arrays(
        unix_s,
        np.asarray(latitude_deg, dtype=float),
        np.asarray(longitude_deg, dtype=float),
        np.asarray(altitude_m, dtype=float),
        np.asarray(pressure_hpa, dtype=float),
        np.asarray(temperature_c, dtype=float),
        np.asarray(delta_t_s, dtype=float),
    )
    shape = args[0].shape
    flat = [np.ravel(a).astype(float) for a in args]
    # spa.solar_position works element-wise in numpy mode: every argument may be an array
    result = spa.solar_position(
        flat[0], flat[1], flat[2], flat[3], flat[4], flat[5], flat[6], ATMOS_REFRACT_DEG, numthreads=1
    )
    apparent_zenith, _zenith, apparent_elevation, _elevation, azimuth = (np.asarray(r) for r in result[:5])
    azimuth = np.broadcast_to(azimuth, flat[0].shape).reshape(shape)
    elevation = np.broadcast_to(apparent_elevation, flat[0].shape).reshape(shape)
    zenith = np.broadcast_to(apparent_zenith, flat[0].shape).reshape(shape)
    return SunPosition(
        azimuth_deg=azimuth,
        elevation_deg=elevation,
        zenith_deg=zenith,
        vector_enu=sun_vector_from_angles(azimuth, elevation),
    )


def sun_at_site(site, times: Any) -> SunPosition:
    """Sun position for a :class:`helicalib.config.Site` (its pressure and temperature)."""
    return sun_position(
        times,
        site.latitude_deg,
        site.longitude_deg,
        site.altitude_m,
        site.pressure_hpa_effective,
        site.temperature_c,
    )


def year_sun_times(site, year: int = 2026, step_days: float = 7.0, step_min: float = 30.0,
                   min_elevation_deg: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Instants of one year (every ``step_days`` days, every ``step_min`` minutes of the day) with
    the sun at least ``min_elevation_deg`` high: ``(times_s (T,), sun_enu (T, 3))``."""
    t0 = float(to_unix_seconds(f"{int(year)}-01-01T00:00:00Z"))
    days = np.arange(0.0, 365.0, step_days)
    minutes = np.arange(0.0, 1440.0, step_min)
    times = (t0 + days[:, None] * 86400.0 + minutes[None, :] * 60.0).ravel()
    pos = sun_at_site(site, times)
    keep = pos.elevation_deg >= min_elevation_deg
    return times[keep], np.asarray(pos.vector_enu)[keep]


def utc_now() -> _dt.datetime:
    """The current UTC time (for the CLI edge only; the core takes times as arguments)."""
    return _dt.datetime.now(tz=_dt.timezone.utc)


class SunTable:
    """NREL SPA for one site on a fixed time grid, interpolated: fast repeated look-ups.

    The campaign asks for the sun thousands of times a day at arbitrary instants; one SPA call
    costs milliseconds. The table computes SPA for whole days at ``step_s`` spacing (on demand)
    and interpolates the unit vector linearly, then renormalises. Over a 60 s step the sun turns
    by about 4.4 mrad, so the chord-interpolation error is below θ²/8 ≈ 2.4e-6 rad (0.002 mrad),
    well under SPA's own uncertainty (±0.0003° ≈ 0.005 mrad).

    Parameters
    ----------
    site : helicalib.config.Site
        Latitude, longitude, altitude, pressure and temperature.
    step_s : float
        Grid spacing [s].
    """

    CHUNK_S = 86400.0

    def __init__(self, site, step_s: float = 60.0):
        self.site = site
        self.step_s = float(step_s)
        self._chunks: dict[int, np.ndarray] = {}
        self._positions: dict[float, tuple] = {}

    def _chunk(self, k: int) -> np.ndarray:
        vec = self._chunks.get(k)
        if vec is None:
            t = k * self.CHUNK_S + np.arange(0.0, self.CHUNK_S + self.step_s, self.step_s)
            vec = np.asarray(sun_at_site(self.site, t).vector_enu, dtype=float)
            if len(self._chunks) > 64:
                self._chunks.clear()
            self._chunks[k] = vec
        return vec

    def vector_enu(self, t_s) -> np.ndarray:
        """Unit sun vector(s), ENU, shape (..., 3), at UTC seconds ``t_s``."""
        t = np.asarray(t_s, dtype=float)
        if t.ndim == 0:
            return self._vector_at(float(t))
        flat = t.reshape(-1)
        out = np.empty((flat.size, 3))
        k = np.floor(flat / self.CHUNK_S).astype(np.int64)
        for kk in np.unique(k):
            sel = k == kk
            table = self._chunk(int(kk))
            x = (flat[sel] - kk * self.CHUNK_S) / self.step_s
            i = np.minimum(np.floor(x).astype(np.int64), len(table) - 2)
            f = (x - i)[:, None]
            v = table[i] * (1.0 - f) + table[i + 1] * f
            out[sel] = v / np.linalg.norm(v, axis=1, keepdims=True)
        return out.reshape(t.shape + (3,))

    def _vector_at(self, t: float) -> np.ndarray:
        """:meth:`vector_enu` at one instant (3,): the same arithmetic, without the array bookkeeping."""
        kk = math.floor(t / self.CHUNK_S)
        table = self._chunk(kk)
        x = (t - kk * self.CHUNK_S) / self.step_s
        i = min(math.floor(x), len(table) - 2)
        f = x - i
        v = table[i] * (1.0 - f) + table[i + 1] * f
        return v / np.sqrt(np.add.reduce(v * v))

    def elevation_deg(self, t_s) -> np.ndarray:
        """Apparent sun elevation(s) [deg] at UTC seconds ``t_s``."""
        return np.degrees(np.arcsin(np.clip(self.vector_enu(t_s)[..., 2], -1.0, 1.0)))

    def position_elevations_deg(self, t_s) -> np.ndarray:
        """The elevation :meth:`position` gives at each of the instants ``t_s`` (T,) [deg], in one call."""
        return angles_from_sun_vector(self.vector_enu(np.asarray(t_s, dtype=float)))[1]

    def position(self, t_s) -> tuple[np.ndarray, float, float, bool]:
        """(vector_enu (3,), azimuth_deg, elevation_deg, rising) at one instant.

        The last few instants asked are kept (a campaign asks for the same instant several times in
        one step); the vector is a fresh copy each time, so a caller may change it."""
        key = float(t_s)
        hit = self._positions.get(key)
        if hit is None:
            v = np.stack([self._vector_at(key), self._vector_at(key + 60.0)])
            az, el = angles_from_sun_vector(v)
            hit = (v[0], float(az[0]), float(el[0]), bool(el[1] > el[0]))
            if len(self._positions) >= 16:
                self._positions.pop(next(iter(self._positions)))
            self._positions[key] = hit
        return hit[0].copy(), hit[1], hit[2], hit[3]
