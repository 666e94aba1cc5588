"""The T/GRLM 02-2014 tracking-accuracy test (clauses 3.2, 3.3, 7.3, 8.1, 8.2).

Per measurement ``i`` the tracking error η (formula 1) is the angle, seen from the heliostat's
rotation centre P, between the spot centre X_i on the board and the target centre T:
``η = |X_i - T| / |T - P| × 1000`` [mrad]. Accuracy (3.2) is the RMS of η over the series;
precision (3.3) the RMS of the angle between each X_i and the mean spot centre of the series.

Clause 8.2: a heliostat passes when, in every wind bin of ``tracking_test`` (default 4, 8 and
11 m/s, each ± ``bin_half_width_ms``), the fraction of measurements with η ≤ ``threshold_mrad``
is *greater* than the bin's ``min_fraction`` (99 %, 62 %, 33 %). A bin without measurements
cannot be judged: the verdict is then "incomplete" unless another bin already fails.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from helicalib.config import TrackingTest
from helicalib.geometry.optics import tracking_error_mrad


@dataclass(frozen=True)
class WindBinResult:
    """One wind bin of clause 8.2."""

    wind_ms: float
    low_ms: float
    high_ms: float
    n: int
    within: int
    fraction: float | None
    required: float
    passed: bool | None  # None: no measurement in the bin

    def to_json(self) -> dict:
        return {"wind_ms": self.wind_ms, "low_ms": self.low_ms, "high_ms": self.high_ms, "n": self.n,
                "within": self.within, "fraction": self.fraction, "required": self.required, "pass": self.passed}


@dataclass(frozen=True)
class TrackingTestResult:
    """The clause 8.2 verdict for one heliostat's series ("pass", "fail" or "incomplete")."""

    threshold_mrad: float
    n: int
    accuracy_rms_mrad: float | None
    precision_rms_mrad: float | None
    fraction_within: float | None
    bins: tuple[WindBinResult, ...]
    verdict: str
    message: str

    def to_json(self) -> dict:
        def num(x):
            return None if x is None else round(float(x), 5)

        return {"threshold_mrad": self.threshold_mrad, "n": self.n, "accuracy_rms_mrad": num(self.accuracy_rms_mrad),
                "precision_rms_mrad": num(self.precision_rms_mrad), "fraction_within": num(self.fraction_within),
                "bins": [b.to_json() for b in self.bins], "verdict": self.verdict, "message": self.message}


def tracking_errors_mrad(spots_enu: np.ndarray, aim_enu: np.ndarray, pivot_enu: np.ndarray) -> np.ndarray:
    """Formula (1) per measurement: spot centres (N, 3), aim point (3,) or (N, 3), pivot (3,) or (N, 3) [m] → (N,) [mrad]."""
    return tracking_error_mrad(np.asarray(spots_enu, float), np.asarray(aim_enu, float), np.asarray(pivot_enu, float))


def precision_angles_mrad(spots_enu: np.ndarray, pivot_enu: np.ndarray) -> np.ndarray:
    """Clause 3.3 per measurement: angle from P between each spot centre (N, 3) and their mean [mrad], (N,)."""
    x = np.asarray(spots_enu, dtype=float).reshape(-1, 3)
    return tracking_error_mrad(x, x.mean(axis=0), np.asarray(pivot_enu, dtype=float))


def rms(values: np.ndarray) -> float | None:
    v = np.asarray(values, dtype=float)
    return None if v.size == 0 else float(np.sqrt(np.mean(v**2)))


def _greater(within: int, n: int, required: float) -> bool:
    # exact rational comparison: 62 of 100 is not "greater than 62 %"
    return Fraction(within, n) > Fraction(repr(float(required)))


def tracking_test(errors_mrad, wind_ms, spec: TrackingTest, precision_mrad=None) -> TrackingTestResult:
    """Clause 8.2 on one heliostat's series.

    Parameters
    ----------
    errors_mrad : array (N,)
        Tracking error η of each measurement [mrad] (formula 1).
    wind_ms : array (N,)
        Wind speed at each measurement [m/s].
    spec : config.TrackingTest
        Threshold, wind bins (centre, minimum fraction) and bin half width.
    precision_mrad : array (N,), optional
        Clause 3.3 angles to the mean spot centre [mrad]; their RMS is reported.
    """
    eta = np.asarray(errors_mrad, dtype=float).ravel()
    wind = np.asarray(wind_ms, dtype=float).ravel()
    if eta.shape != wind.shape:
        raise ValueError(f"errors_mrad has {eta.size} values but wind_ms has {wind.size}")
    ok = np.isfinite(eta) & np.isfinite(wind)
    eta, wind = eta[ok], wind[ok]
    thr = float(spec.threshold_mrad)
    inside = eta <= thr
    bins = []
    for b in spec.wind_bins:
        lo, hi = b.wind_ms - spec.bin_half_width_ms, b.wind_ms + spec.bin_half_width_ms
        sel = (wind >= lo) & (wind <= hi)
        n, k = int(np.count_nonzero(sel)), int(np.count_nonzero(inside & sel))
        bins.append(WindBinResult(float(b.wind_ms), float(lo), float(hi), n, k, (k / n) if n else None,
                                  float(b.min_fraction), _greater(k, n, b.min_fraction) if n else None))
    failed = [b for b in bins if b.passed is False]
    empty = [b for b in bins if b.passed is None]
    if failed:
        verdict = "fail"
        msg = "fails clause 8.2: " + "; ".join(
            f"{100 * b.fraction:.1f} % within {thr:g} mrad at {b.wind_ms:g} m/s (needs > {100 * b.required:g} %)"
            for b in failed) + "."
    elif empty:
        verdict = "incomplete"
        msg = ("no measurements at " + ", ".join(f"{b.wind_ms:g} m/s (±{spec.bin_half_width_ms:g})" for b in empty)
               + "; the test must cover these wind speeds (clause 6.1).")
    else:
        verdict = "pass"
        msg = "passes clause 8.2 in every wind bin."
    prec = None if precision_mrad is None else rms(np.asarray(precision_mrad, dtype=float)[ok])
    return TrackingTestResult(thr, int(eta.size), rms(eta), prec, float(np.mean(inside)) if eta.size else None,
                              tuple(bins), verdict, msg)


def plot_tracking_test(series: dict, spec: TrackingTest, path=None, title: str | None = None):
    """Figure 3 of T/GRLM 02-2014: frequency of η within the threshold against wind speed.

    ``series`` maps a heliostat id to ``(errors_mrad, wind_ms)``. Each heliostat is a line over
    1 m/s wind classes; the clause 8.2 bins are drawn as their required minimum. Returns the
    matplotlib Figure; writes a PNG when ``path`` is given.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=110)
    thr = float(spec.threshold_mrad)
    for k, (hid, (eta, wind)) in enumerate(series.items()):
        eta, wind = np.asarray(eta, float), np.asarray(wind, float)
        ok = np.isfinite(eta) & np.isfinite(wind)
        eta, wind = eta[ok], wind[ok]
        if eta.size == 0:
            continue
        classes = np.rint(wind).astype(int)
        xs = np.unique(classes)
        ys = [100.0 * np.mean(eta[classes == c] <= thr) for c in xs]
        ax.plot(xs, ys, marker="o", lw=1.2, label=hid if k < 12 else None)
    for b in spec.wind_bins:
        ax.hlines(100 * b.min_fraction, b.wind_ms - spec.bin_half_width_ms, b.wind_ms + spec.bin_half_width_ms,
                  colors="red", lw=3, alpha=0.7)
        ax.annotate(f"> {100 * b.min_fraction:g} %", (b.wind_ms, 100 * b.min_fraction), textcoords="offset points",
                    xytext=(0, -14), ha="center", color="red", fontsize=8)
    ax.set_xlabel("wind speed [m/s]")
    ax.set_ylabel(f"frequency of η ≤ {thr:g} mrad [%]")
    ax.set_ylim(0, 105)
    ax.grid(alpha=0.3)
    ax.set_title(title or "Tracking accuracy within threshold by wind speed (T/GRLM 02-2014 fig. 3, clause 8.2)",
                 fontsize=9)
    if series:
        ax.legend(fontsize=7, loc="lower left", ncol=2)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
        plt.close(fig)
    return fig
