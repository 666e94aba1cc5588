"""Weather of the simulated plant: wind, direction, DNI with passing clouds, temperature, pressure.

Pure functions of plant time, deterministic from the scenario seed and random-access (the same
instant always gives the same weather, whatever was asked before). DNI follows the sun: a clear
sky of Meinel's form ``DNI = I0 · 0.7^(AM^0.678) / 0.7`` (scaled so the zenith gives
``clear_sky_wm2``), dimmed by passing clouds.
"""

from __future__ import annotations

import numpy as np

from helicalib.devices.protocols import Weather
from helicalib.geometry.sun import parse_time, sun_at_site, to_unix_seconds
from helicalib.sim import noise
from helicalib.sim.scenario import WeatherSpec

_STREAM_WIND, _STREAM_DIR, _STREAM_CLOUD, _STREAM_PRESSURE, _STREAM_TEMP = 11, 12, 13, 14, 15


def air_mass(elevation_deg: np.ndarray) -> np.ndarray:
    """Kasten & Young (1989) relative air mass; inf below the horizon."""
    el = np.asarray(elevation_deg, dtype=float)
    zen = 90.0 - el
    with np.errstate(invalid="ignore", divide="ignore"):
        am = 1.0 / (np.cos(np.radians(zen)) + 0.50572 * (96.07995 - zen) ** -1.6364)
    return np.where(el > 0.0, am, np.inf)


def clear_sky_dni_wm2(elevation_deg: np.ndarray, zenith_dni_wm2: float) -> np.ndarray:
    """Clear-sky DNI for sun elevations [deg]; ``zenith_dni_wm2`` at air mass 1, 0 below the horizon."""
    am = air_mass(elevation_deg)
    with np.errstate(invalid="ignore"):
        dni = zenith_dni_wm2 * 0.7 ** (am**0.678) / 0.7
    return np.where(np.isfinite(am), dni, 0.0)


class WeatherModel:
    """Weather at any plant time for one site and scenario.

    Parameters
    ----------
    spec : WeatherSpec
        The scenario's ``weather`` section.
    site : config.Site
        Longitude (local solar time of the daily cycles), sun, default pressure.
    seed : int
        Scenario seed.
    """

    def __init__(self, spec: WeatherSpec, site, seed: int):
        self.spec = spec
        self.site = site
        self.seed = int(seed)
        self._events = [(float(to_unix_seconds(parse_time(e.start))), float(to_unix_seconds(parse_time(e.end))), e)
                        for e in spec.events]

    # -- components, vectorised over times ------------------------------------------------
    def _solar_hour(self, t_s: np.ndarray) -> np.ndarray:
        return ((np.asarray(t_s, dtype=float) / 3600.0) + self.site.longitude_deg / 15.0) % 24.0

    def wind_ms(self, t_s) -> np.ndarray:
        """10-min mean wind speed [m/s] at times ``t_s`` [UTC s]."""
        w = self.spec.wind
        t = np.asarray(t_s, dtype=float)
        diurnal = w.diurnal_amplitude_ms * np.cos(2 * np.pi * (self._solar_hour(t) - 15.0) / 24.0)
        slow = w.variability_ms * noise.smooth_normal(self.seed, _STREAM_WIND, t, w.correlation_h * 3600.0)
        return self._override(t, np.maximum(0.0, w.mean_ms + diurnal + slow), "wind_ms")

    def wind_direction_deg(self, t_s) -> np.ndarray:
        """Wind direction [deg from north, clockwise] in [0, 360)."""
        w = self.spec.wind
        t = np.asarray(t_s, dtype=float)
        d = w.direction_deg + w.direction_variability_deg * noise.smooth_normal(
            self.seed, _STREAM_DIR, t, 3 * w.correlation_h * 3600.0)
        return self._override(t, d, "wind_direction_deg") % 360.0

    def cloud_transmittance(self, t_s) -> np.ndarray:
        """Fraction of the clear-sky DNI that passes the clouds, in [1 − attenuation, 1]."""
        d = self.spec.dni
        t = np.asarray(t_s, dtype=float)
        if d.cloudy_fraction <= 0.0:
            return np.ones_like(t)
        from scipy.special import ndtri

        z = noise.smooth_normal(self.seed, _STREAM_CLOUD, t, d.cloud_duration_min * 60.0)
        threshold = ndtri(1.0 - d.cloudy_fraction) if d.cloudy_fraction < 1.0 else -np.inf
        # soft cloud edges: a cloud passes in ~1/10 of its duration
        cover = np.clip((z - threshold) / 0.3 + 0.5, 0.0, 1.0)
        return 1.0 - d.cloud_attenuation * cover

    def dni_wm2(self, t_s, elevation_deg=None) -> np.ndarray:
        """DNI [W/m²]; pass the sun elevation [deg] if known, else it is computed (NREL SPA)."""
        t = np.asarray(t_s, dtype=float)
        if elevation_deg is None:
            elevation_deg = sun_at_site(self.site, t).elevation_deg
        dni = clear_sky_dni_wm2(elevation_deg, self.spec.dni.clear_sky_wm2) * self.cloud_transmittance(t)
        return self._override(t, dni, "dni_factor", multiply=True)

    def temperature_c(self, t_s) -> np.ndarray:
        """Ambient temperature [°C], warmest at 15:00 local solar time."""
        s = self.spec.temperature
        t = np.asarray(t_s, dtype=float)
        temp = s.mean_c + s.diurnal_amplitude_c * np.cos(2 * np.pi * (self._solar_hour(t) - 15.0) / 24.0)
        temp = temp + 0.5 * noise.smooth_normal(self.seed, _STREAM_TEMP, t, 3 * 3600.0)
        return self._override(t, temp, "temperature_c")

    def pressure_hpa(self, t_s) -> np.ndarray:
        """Air pressure [hPa]: the scenario's (or the site's) mean with a slow synoptic wander."""
        p = self.spec.pressure
        mean = p.mean_hpa if p.mean_hpa is not None else self.site.pressure_hpa_effective
        t = np.asarray(t_s, dtype=float)
        return mean + p.variability_hpa * noise.smooth_normal(self.seed, _STREAM_PRESSURE, t, 2 * 86400.0)

    def _override(self, t: np.ndarray, values: np.ndarray, key: str, multiply: bool = False) -> np.ndarray:
        out = np.array(values, dtype=float, copy=True)
        for start, end, event in self._events:
            v = getattr(event, key)
            if v is None:
                continue
            inside = (t >= start) & (t < end)
            out = np.where(inside, out * v if multiply else v, out)
        return out

    # -- one reading -----------------------------------------------------------------------
    def at(self, t_s: float, elevation_deg: float | None = None) -> Weather:
        """The weather block at plant time ``t_s`` [UTC s]."""
        return Weather(
            wind_ms=float(self.wind_ms(t_s)),
            wind_direction_deg=float(self.wind_direction_deg(t_s)),
            dni_wm2=float(self.dni_wm2(t_s, elevation_deg)),
            temperature_c=float(self.temperature_c(t_s)),
            pressure_hpa=float(self.pressure_hpa(t_s)),
        )
