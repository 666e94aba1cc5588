"""Weather and mirror gating of calibration (the 2022 paper, section 3).

The paper's limits, as the field config names them (``gating``):

=====================  =================================================================
wind ≤ wind_preferred  good (≥ 60 % pass rate in the paper)
wind > wind_max        no calibration ("not recommended above 10 m/s")
wind > stow_wind       the whole field to stow ("above 15 m/s, to a safe position");
                       resume when the wind is back at or below ``wind_max_ms``
DNI > dni_min          needed ("only above 300 W/m² can spot data be taken")
DNI > dni_preferred    good
cleanliness > min      needed for that mirror ("above 0.55 the camera sees the spot")
cleanliness > pref.    good
=====================  =================================================================

Preferred limits never block: they mark conditions "good", which raises a heliostat's priority
in the planner. A missing (non-finite) reading blocks calibration but never stows: the plant's
own wind protection stays in charge. Pure functions; the caller records the reason sentences.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FieldGate:
    """The field-wide decision for one weather reading.

    Attributes
    ----------
    stow : bool
        Stow the whole field now (wind above ``stow_wind_ms``, or still stowed and not calm yet).
    calibrate : bool
        Calibration visits may run (wind ≤ ``wind_max_ms`` and DNI > ``dni_min_wm2``, not stowed).
    wind_good, dni_good : bool
        The preferred limits hold (wind ≤ ``wind_preferred_ms``, DNI > ``dni_preferred_wm2``).
    reason : str
        One sentence saying why, with the readings and limits.
    """

    stow: bool
    calibrate: bool
    wind_good: bool
    dni_good: bool
    reason: str

    @property
    def good(self) -> bool:
        """Both the wind and the DNI are within their preferred limits."""
        return self.wind_good and self.dni_good


def gate_field(wind_ms: float, dni_wm2: float, gating, *, stowed: bool = False) -> FieldGate:
    """Field-wide gating from the wind [m/s] and DNI [W/m²].

    Parameters
    ----------
    wind_ms : float
        Wind speed, 10-min mean [m/s].
    dni_wm2 : float
        Direct normal irradiance [W/m²].
    gating : helicalib.config.Gating
        The limits.
    stowed : bool
        The field is stowed because of wind now: it stays stowed until the wind is at or below
        ``wind_max_ms`` (hysteresis between ``wind_max_ms`` and ``stow_wind_ms``).
    """
    wind_known = math.isfinite(wind_ms)
    dni_known = math.isfinite(dni_wm2)
    if wind_known and wind_ms > gating.stow_wind_ms:
        return FieldGate(True, False, False, False,
                         f"wind {wind_ms:.1f} m/s > {gating.stow_wind_ms:g} m/s: stow the whole field")
    if stowed and (not wind_known or wind_ms > gating.wind_max_ms):
        shown = f"{wind_ms:.1f} m/s" if wind_known else "unknown"
        return FieldGate(True, False, False, False,
                         f"wind {shown}, not yet ≤ {gating.wind_max_ms:g} m/s: stay stowed")
    wind_good = wind_known and wind_ms <= gating.wind_preferred_ms
    dni_good = dni_known and dni_wm2 > gating.dni_preferred_wm2
    blocks = []
    if not wind_known:
        blocks.append("no wind reading")
    elif wind_ms > gating.wind_max_ms:
        blocks.append(f"wind {wind_ms:.1f} m/s > {gating.wind_max_ms:g} m/s")
    if not dni_known:
        blocks.append("no DNI reading")
    elif dni_wm2 <= gating.dni_min_wm2:
        blocks.append(f"DNI {dni_wm2:.0f} W/m² ≤ {gating.dni_min_wm2:g} W/m²")
    if blocks:
        return FieldGate(False, False, wind_good, dni_good, "; ".join(blocks) + ": no calibration")
    quality = [
        f"wind {wind_ms:.1f} m/s" + (" (good)" if wind_good else f" (above the preferred {gating.wind_preferred_ms:g})"),
        f"DNI {dni_wm2:.0f} W/m²" + (" (good)" if dni_good else f" (below the preferred {gating.dni_preferred_wm2:g})"),
    ]
    return FieldGate(False, True, wind_good, dni_good, "calibration allowed: " + ", ".join(quality))


@dataclass(frozen=True)
class MirrorGate:
    """Per-heliostat cleanliness gating, arrays of shape (N,).

    ``allowed``: cleanliness > ``cleanliness_min``; ``good``: > ``cleanliness_preferred``.
    """

    allowed: np.ndarray
    good: np.ndarray

    def reason(self, i: int, cleanliness: float, gating) -> str:
        """The sentence for heliostat ``i``."""
        if not self.allowed[i]:
            return f"cleanliness {cleanliness:.2f} ≤ {gating.cleanliness_min:g}: mirror too soiled to calibrate"
        if self.good[i]:
            return f"cleanliness {cleanliness:.2f} (good)"
        return f"cleanliness {cleanliness:.2f} (below the preferred {gating.cleanliness_preferred:g})"


def gate_mirrors(cleanliness, gating) -> MirrorGate:
    """Cleanliness gating of every heliostat (0..1, NaN = unknown = not allowed), vectorised."""
    c = np.atleast_1d(np.asarray(cleanliness, dtype=float))
    known = np.isfinite(c)
    return MirrorGate(allowed=known & (c > gating.cleanliness_min), good=known & (c > gating.cleanliness_preferred))
