"""A mirror's present cleanliness, measured from the power its spot puts on the board.

The power a heliostat delivers to the board is

    P = DNI · A · ρ_clean · c · cos θ · τ_atm · η_int

(DNI [W/m²], mirror area A [m²], clean reflectivity ρ_clean, cleanliness c (soiled/clean
reflectance ratio), cosine of the sun's incidence on the mirror, atmospheric transmittance over the
slant range, intercept = fraction of the reflected beam that lands on the board). With P measured
from the flux map (:mod:`helicalib.flux.fluxmap`), :func:`estimate_cleanliness` solves for c.
Everything the model leaves out (shading, blocking, mirror curvature losses, an F_e error) lands
in the estimate too: it is the mirror's *effective* cleanliness.

Atmospheric attenuation: the clear-day (23 km visibility) polynomial of Vittitoe & Biggs (1978),
as used by DELSOL/SolarPILOT (Leary & Hankins 1979), with slant range S in metres:

    τ = 0.99321 − 1.176e-4·S + 1.97e-8·S²    (S <= 1000 m)
    τ = exp(−1.106e-4·S)                       (S >  1000 m)

and the hazy-day (5 km visibility) polynomial ``τ = 0.98707 − 2.748e-4·S + 3.394e-8·S²``, given
for S <= 1000 m only. ``none`` is τ = 1: no attenuation (the simulated plant renders none).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

__all__ = [
    "atmospheric_attenuation",
    "cos_incidence",
    "estimate_cleanliness",
    "expected_power_w",
    "gaussian_intercept",
]

Atmosphere = Literal["clear", "hazy", "none"]


def atmospheric_attenuation(slant_range_m: np.ndarray | float, model: Atmosphere = "clear") -> np.ndarray | float:
    """Transmittance τ of the air between mirror and board (Vittitoe & Biggs 1978).

    Parameters
    ----------
    slant_range_m : float or np.ndarray, shape (...)
        Distance mirror centre → aim point [m], >= 0.
    model : {"clear", "hazy", "none"}
        23 km visibility (default), 5 km visibility (valid to 1000 m), or no attenuation (τ = 1).

    Returns
    -------
    float or np.ndarray, shape (...)
        Transmittance in (0, 1].
    """
    s = np.asarray(slant_range_m, dtype=float)
    if np.any(~np.isfinite(s)) or np.any(s < 0):
        raise ValueError("slant_range_m must be finite and >= 0")
    if model == "clear":
        tau = np.where(s <= 1000.0, 0.99321 - 1.176e-4 * s + 1.97e-8 * s**2, np.exp(-1.106e-4 * s))
    elif model == "hazy":
        if np.any(s > 1000.0):
            raise ValueError("the hazy-day attenuation polynomial is given for slant ranges up to 1000 m only")
        tau = 0.98707 - 2.748e-4 * s + 3.394e-8 * s**2
    elif model == "none":
        tau = np.ones_like(s)
    else:
        raise ValueError(f"unknown atmosphere model {model!r}; expected 'clear', 'hazy' or 'none'")
    return float(tau) if tau.ndim == 0 else tau


def cos_incidence(sun_enu: np.ndarray, mirror_enu_m: np.ndarray, aim_enu_m: np.ndarray) -> np.ndarray | float:
    """Cosine of the sun's incidence angle on a mirror that reflects the sun onto ``aim_enu_m``.

    The normal bisects the sun vector s and the direction r to the aim point, so
    ``cos θ = s·n = sqrt((1 + s·r) / 2)``.

    Parameters
    ----------
    sun_enu : np.ndarray, shape (3,) or (..., 3)
        Unit vector toward the sun [ENU].
    mirror_enu_m : np.ndarray, shape (..., 3)
        Mirror centres (or pivots) [m, ENU].
    aim_enu_m : np.ndarray, shape (3,) or (..., 3)
        Aim points [m, ENU].
    """
    s = np.asarray(sun_enu, dtype=float)
    s = s / np.linalg.norm(s, axis=-1, keepdims=True)
    r = np.asarray(aim_enu_m, dtype=float) - np.asarray(mirror_enu_m, dtype=float)
    r = r / np.linalg.norm(r, axis=-1, keepdims=True)
    c = np.sqrt(np.clip((1.0 + np.sum(s * r, axis=-1)) / 2.0, 0.0, 1.0))
    return float(c) if np.ndim(c) == 0 else c


def gaussian_intercept(sigma_m: np.ndarray | float, half_size_m: tuple[float, float],
                       offset_uv_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray | float:
    """Fraction of a circular Gaussian beam that falls on a rectangular board.

    ``η = Π_{x∈{u,v}} ½[erf((a_x − c_x)/(σ√2)) + erf((a_x + c_x)/(σ√2))]``.

    Parameters
    ----------
    sigma_m : float or np.ndarray
        Standard deviation of the beam's flux on the board, per axis [m].
    half_size_m : (float, float)
        Half width and half height of the board [m].
    offset_uv_m : (float, float)
        Beam centre relative to the board centre [m, target frame].
    """
    sig = np.asarray(sigma_m, dtype=float)
    if np.any(sig <= 0):
        raise ValueError("sigma_m must be positive")
    from scipy.special import erf

    out = np.ones_like(sig)
    for a, c in zip(half_size_m, offset_uv_m, strict=True):
        out = out * 0.5 * (erf((a - c) / (sig * math.sqrt(2))) + erf((a + c) / (sig * math.sqrt(2))))
    return float(out) if out.ndim == 0 else out


def expected_power_w(dni_wm2, mirror_area_m2, reflectivity_clean, cos_incidence, attenuation, intercept):
    """Power a perfectly clean mirror would put on the board [W] (all arguments broadcast).

    ``P_clean = DNI · A · ρ_clean · cos θ · τ_atm · η_int``; see :func:`estimate_cleanliness`.
    """
    p = (np.asarray(dni_wm2, dtype=float) * np.asarray(mirror_area_m2, dtype=float)
         * np.asarray(reflectivity_clean, dtype=float) * np.asarray(cos_incidence, dtype=float)
         * np.asarray(attenuation, dtype=float) * np.asarray(intercept, dtype=float))
    return float(p) if p.ndim == 0 else p


def estimate_cleanliness(power_w, dni_wm2, mirror_area_m2, reflectivity_clean, cos_incidence, attenuation,
                         intercept):
    """Estimate a mirror's cleanliness from the power its spot delivers to the board.

    ``c = P_measured / (DNI · A · ρ_clean · cos θ · τ_atm · η_int)``. Pure; every argument is a
    scalar or an array and they broadcast against each other (one value per heliostat or visit).

    Parameters
    ----------
    power_w : float or np.ndarray
        Measured beam power on the board [W]: ``FluxMap.power_w`` of the after − before flux map.
    dni_wm2 : float or np.ndarray
        Direct normal irradiance at the capture time [W/m²] (weather block, addr 104).
    mirror_area_m2 : float or np.ndarray
        Reflective area of the heliostat [m²], e.g. ``prod(Drive.mirror_size_m)``.
    reflectivity_clean : float or np.ndarray
        Reflectivity of the clean mirror, 0..1 (e.g. 0.93).
    cos_incidence : float or np.ndarray
        Cosine of the sun's incidence on the mirror (:func:`cos_incidence`).
    attenuation : float or np.ndarray
        Atmospheric transmittance over the slant range (:func:`atmospheric_attenuation`).
    intercept : float or np.ndarray
        Fraction of the reflected beam that lands on the board, 0..1 (1 for a spot well inside
        the board; :func:`gaussian_intercept` for a Gaussian spot).

    Returns
    -------
    float or np.ndarray
        Estimated cleanliness (ratio of soiled to clean reflectance). Not clipped: noise can push
        it slightly above 1 or below 0. NaN where the expected power is not positive (sun below
        the horizon, DNI 0, missing intercept), so a caller must treat NaN as "no estimate".
    """
    expected = np.asarray(expected_power_w(dni_wm2, mirror_area_m2, reflectivity_clean, cos_incidence,
                                           attenuation, intercept), dtype=float)
    p = np.asarray(power_w, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(expected > 0, p / np.where(expected > 0, expected, 1.0), np.nan)
    return float(c) if c.ndim == 0 else c
