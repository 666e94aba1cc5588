"""Mirror cleanliness per heliostat: falls linearly with soiling, jumps back at every cleaning.

Closed form and random-access: heliostat i is cleaned at ``phase_i + k · interval`` (the cleaning
crew works through the field, so the phases are spread over one interval) and loses
``rate_i`` of cleanliness per day in between, never below ``floor``.
"""

from __future__ import annotations

import numpy as np

from helicalib.sim import noise
from helicalib.sim.scenario import Soiling

DAY_S = 86400.0
_STREAM_RATE = 21


class SoilingModel:
    """Cleanliness of N heliostats at any plant time.

    Parameters
    ----------
    spec : Soiling
        The scenario's ``soiling`` section.
    n : int
        Number of heliostats.
    seed : int
        Scenario seed (heliostat rates).
    """

    def __init__(self, spec: Soiling, n: int, seed: int):
        self.spec = spec
        idx = np.arange(int(n))
        self.rate_per_day = np.maximum(
            0.0, spec.rate_per_day * (1.0 + spec.rate_spread * noise.normal(seed, _STREAM_RATE, idx)))
        # cleaning order: heliostats in block order, evenly spread over the interval
        self.phase_s = (idx / max(int(n), 1)) * spec.cleaning_interval_days * DAY_S
        self._extra_cleanings: list[tuple[float, np.ndarray]] = []

    def last_cleaning_s(self, t_s: float, rows: np.ndarray | None = None) -> np.ndarray:
        """Time of each heliostat's last cleaning at or before ``t_s`` [UTC s], shape (N,) (or of
        the heliostats ``rows`` (k,): the same values for the cost of k)."""
        interval = self.spec.cleaning_interval_days * DAY_S
        phase = self.phase_s if rows is None else self.phase_s[rows]
        last = phase + np.floor((float(t_s) - phase) / interval) * interval
        for when, which in self._extra_cleanings:
            if when <= t_s:
                last = np.where(which if rows is None else which[rows], np.maximum(last, when), last)
        return last

    def clean(self, t_s: float, which: np.ndarray | None = None) -> None:
        """Record an extra cleaning at ``t_s`` of the heliostats selected by bool mask ``which`` (all if None)."""
        mask = np.ones_like(self.phase_s, dtype=bool) if which is None else np.asarray(which, dtype=bool)
        self._extra_cleanings.append((float(t_s), mask))

    def cleanliness(self, t_s: float, rows: np.ndarray | None = None) -> np.ndarray:
        """Cleanliness in [floor, clean_value] of every heliostat at ``t_s``, shape (N,) (or of
        the heliostats ``rows`` (k,))."""
        days = (float(t_s) - self.last_cleaning_s(t_s, rows)) / DAY_S
        rate = self.rate_per_day if rows is None else self.rate_per_day[rows]
        return np.maximum(self.spec.floor, self.spec.clean_value - rate * days)
