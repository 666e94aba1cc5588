"""Acceptance of a calibrated heliostat (the 2022 paper, section 2.4), and what is still missing.

The three rules, as helicalib reads them (``docs/campaign.md`` explains each choice):

1. **Low band.** At least one valid point with ``low_band_deg[0] <= elevation <= low_band_deg[1]``
   while the sun rises (before the day's transit), and at least one while it sets (after).
2. **High windows.** Each day's time with the sun above ``high_elevation_deg`` (strictly) is cut,
   from the moment the sun rises through it, into ``n = ceil(span / high_window_h)`` equal windows
   (each at most ``high_window_h`` long; no sliver window at the end). ``n`` is taken from the
   evaluation day (the last day whose high span has begun at ``now_s``). A point of any day counts
   for the window at the same fraction of that day's span, so days of different length line up.
   Every window needs at least one valid point.
3. **Count and accuracy.** At least ``min_points`` valid points, and the RMS of their tracking
   errors ``<= max_rms_mrad``.

Pure functions: arrays and :class:`~helicalib.calibration.sun_days.SunDay` lists in, frozen
dataclasses out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from helicalib.calibration.sun_days import SunDay, is_rising, n_high_windows

_CLAMP_S = 300.0
"""A point above ``high_elevation_deg`` within this of a day's interpolated high span belongs to it [s]."""


@dataclass(frozen=True)
class AcceptanceVerdict:
    """The verdict of one heliostat.

    Attributes
    ----------
    accepted : bool
        All rules hold.
    n_points : int
        Valid points counted (finite error).
    rms_mrad : float or None
        RMS tracking error of those points [mrad]; None without points.
    rising_ok, setting_ok : bool
        Rule 1 for the rising and the setting sun.
    n_windows : int
        High-elevation windows of the evaluation day.
    window_counts : tuple of int
        Valid points in each window.
    reasons : tuple of str
        One sentence per failed rule, naming the band or window that lacks a point.
    """

    accepted: bool
    n_points: int
    rms_mrad: float | None
    rising_ok: bool
    setting_ok: bool
    n_windows: int
    window_counts: tuple[int, ...]
    reasons: tuple[str, ...]

    @property
    def missing_windows(self) -> tuple[int, ...]:
        """Indices (0-based) of high windows without a valid point."""
        return tuple(k for k, c in enumerate(self.window_counts) if c == 0)


@dataclass(frozen=True)
class Gap:
    """Something a heliostat still needs, and when it can next be filled.

    ``kind`` is ``'rising'``, ``'setting'``, ``'window'`` (with ``window``), ``'points'`` or ``'rms'``.
    ``next_start_s``/``next_end_s`` [UTC s] bound the next opening at or after ``now_s`` (the
    start is ``now_s`` when it is open now); None when no given day has one.
    """

    kind: str
    window: int | None
    next_start_s: float | None
    next_end_s: float | None
    description: str

    def is_open(self, now_s: float) -> bool:
        """True when a valid point taken at ``now_s`` fills this gap."""
        return self.next_start_s is not None and self.next_start_s <= now_s < self.next_end_s

    @property
    def opening_s(self) -> float:
        """Length of the next opening [s] (0 when none): the shorter, the scarcer."""
        if self.next_start_s is None:
            return 0.0
        return self.next_end_s - self.next_start_s


def evaluation_day(days: Sequence[SunDay], now_s: float | None) -> SunDay | None:
    """The day whose high windows define ``n``: the last one whose high span began by ``now_s``."""
    with_high = [d for d in days if d.high_start_s is not None and d.high_end_s is not None]
    if not with_high:
        return None
    if now_s is None:
        return with_high[-1]
    begun = [d for d in with_high if d.high_start_s <= now_s]
    return begun[-1] if begun else with_high[0]


def high_window_index(times_s: np.ndarray, days: Sequence[SunDay], n_windows: int) -> np.ndarray:
    """Window index (0..n-1) of each time by its fraction of its own day's high span; -1 outside.

    Times within a few minutes outside a span (interpolated crossings) are clamped into it.
    """
    t = np.atleast_1d(np.asarray(times_s, dtype=float))
    out = np.full(t.shape, -1, dtype=int)
    if n_windows <= 0:
        return out
    for d in days:
        if d.high_start_s is None or d.high_end_s is None:
            continue
        inside = (t >= d.high_start_s - _CLAMP_S) & (t <= d.high_end_s + _CLAMP_S)
        phase = np.clip((t - d.high_start_s) / d.high_span_s, 0.0, 1.0 - 1e-12)
        out = np.where(inside & (out < 0), np.floor(phase * n_windows).astype(int), out)
    return out


def _hhmm(t: float) -> str:
    import datetime as dt

    return dt.datetime.fromtimestamp(t, tz=dt.timezone.utc).strftime("%H:%M")


def evaluate(times_s, elevation_deg, error_mrad, rules, days: Sequence[SunDay], *,
             rising=None, now_s: float | None = None) -> AcceptanceVerdict:
    """The paper-2.4 verdict of one heliostat from its VALID points.

    Parameters
    ----------
    times_s : array_like, shape (N,)
        Capture times [UTC s].
    elevation_deg : array_like, shape (N,)
        Sun elevation at each capture [deg].
    error_mrad : array_like, shape (N,)
        Tracking error of each point [mrad]; non-finite entries are not counted.
    rules : helicalib.config.Acceptance
        ``low_band_deg``, ``high_elevation_deg``, ``high_window_h``, ``min_points``, ``max_rms_mrad``.
    days : sequence of SunDay
        The solar days of the campaign (:func:`~helicalib.calibration.sun_days.sun_days`).
    rising : array_like of bool, shape (N,), optional
        The sun was rising at each point; default: before the day's transit.
    now_s : float, optional
        Evaluation time, choosing the evaluation day (default: the last day given).
    """
    t = np.atleast_1d(np.asarray(times_s, dtype=float))
    elev = np.atleast_1d(np.asarray(elevation_deg, dtype=float))
    err = np.atleast_1d(np.asarray(error_mrad, dtype=float))
    if not (t.shape == elev.shape == err.shape):
        raise ValueError(f"times, elevations and errors differ in shape: {t.shape}, {elev.shape}, {err.shape}")
    rise = is_rising(t, days) if rising is None else np.atleast_1d(np.asarray(rising, dtype=bool))
    keep = np.isfinite(err) & np.isfinite(t) & np.isfinite(elev)
    t, elev, err, rise = t[keep], elev[keep], err[keep], rise[keep]

    lo, hi = rules.low_band_deg
    in_band = (elev >= lo) & (elev <= hi)
    rising_ok = bool(np.any(in_band & rise))
    setting_ok = bool(np.any(in_band & ~rise))

    ref = evaluation_day(days, now_s)
    n_win = n_high_windows(ref.high_span_s, rules.high_window_h) if ref is not None else 0
    idx = high_window_index(t[elev > rules.high_elevation_deg], days, n_win)
    counts = tuple(int(np.sum(idx == k)) for k in range(n_win))

    n = int(t.size)
    rms = float(np.sqrt(np.mean(err**2))) if n else None
    reasons = []
    band = f"{lo:g}–{hi:g}°"
    if not rising_ok:
        reasons.append(f"no valid point while the sun rose through {band}")
    if not setting_ok:
        reasons.append(f"no valid point while the sun set through {band}")
    for k, c in enumerate(counts):
        if c == 0:
            a, b = ref.high_window(k, n_win)
            reasons.append(f"no valid point in high-elevation window {k + 1} of {n_win} "
                           f"(sun above {rules.high_elevation_deg:g}°, {_hhmm(a)}–{_hhmm(b)} UTC)")
    if n < rules.min_points:
        reasons.append(f"{n} valid point{'s' if n != 1 else ''}, {rules.min_points} needed")
    if rms is not None and rms > rules.max_rms_mrad:
        reasons.append(f"RMS error {rms:.2f} mrad > {rules.max_rms_mrad:g} mrad")
    return AcceptanceVerdict(accepted=not reasons, n_points=n, rms_mrad=rms, rising_ok=rising_ok,
                             setting_ok=setting_ok, n_windows=n_win, window_counts=counts, reasons=tuple(reasons))


def evaluate_observations(observations, rules, days: Sequence[SunDay], *, now_s: float | None = None,
                          errors_mrad=None) -> AcceptanceVerdict:
    """:func:`evaluate` on stored observations (:class:`helicalib.store.Observation`); invalid ones are skipped.

    ``errors_mrad`` (one per VALID observation, in order) replaces the stored errors, e.g. by the
    residuals of the current error model.
    """
    valid = [o for o in observations if o.valid and o.error_mrad is not None]
    t = np.array([o.capture_time_s for o in valid], dtype=float)
    rise_stored = [o.sun_rising for o in valid]
    rise = is_rising(t, days) if len(valid) else np.zeros(0, bool)
    rise = np.array([r if r is not None else bool(d) for r, d in zip(rise_stored, rise)], dtype=bool)
    err = np.array([o.error_mrad for o in valid], dtype=float) if errors_mrad is None else np.asarray(errors_mrad, float)
    return evaluate(t, np.array([o.sun_elevation_deg for o in valid], dtype=float), err, rules, days,
                    rising=rise, now_s=now_s)


RMS_GAP_POINTS_FACTOR = 4
"""An RMS above the limit asks for more points only while the heliostat has fewer than this many
times ``min_points`` valid points. Past that, more points of the same quality do not lower a
leave-one-out RMS. On the benchmark field such heliostats (the nearest to their boards, whose
spots measure poorly) took about 150 visits each without getting there. The verdict still
refuses them and says why."""


@dataclass(frozen=True)
class Need:
    """Something a verdict still lacks, without its timing: what :func:`gaps` times against the sun.

    ``kind`` and ``window`` as in :class:`Gap`; ``n_windows``: the verdict's high windows (for a
    window need, which fraction of each day's high span it is). Needs compare equal across
    heliostats whatever their descriptions say (point counts, RMS), so the planner can time each
    distinct set of needs once for a whole field (:func:`needs_key`)."""

    kind: str
    window: int | None
    n_windows: int
    description: str = field(compare=False)


def needs(verdict: AcceptanceVerdict, rules) -> tuple[Need, ...]:
    """What ``verdict`` still lacks (rules 1-3, more points, a better RMS), in rule order."""
    out: list[Need] = []
    lo, hi = rules.low_band_deg
    n = verdict.n_windows
    if not verdict.rising_ok:
        out.append(Need("rising", None, n, f"a valid point while the sun rises through {lo:g}–{hi:g}°"))
    if not verdict.setting_ok:
        out.append(Need("setting", None, n, f"a valid point while the sun sets through {hi:g}–{lo:g}°"))
    for k in verdict.missing_windows:
        out.append(Need("window", k, n, f"a valid point in high-elevation window {k + 1} of {n}"))
    if verdict.n_points < rules.min_points:
        need = rules.min_points - verdict.n_points
        out.append(Need("points", None, n, f"{need} more valid point{'s' if need != 1 else ''}"))
    if (verdict.rms_mrad is not None and verdict.rms_mrad > rules.max_rms_mrad
            and verdict.n_points < RMS_GAP_POINTS_FACTOR * rules.min_points):
        out.append(Need("rms", None, n, f"RMS error {verdict.rms_mrad:.2f} mrad down to {rules.max_rms_mrad:g} mrad"))
    return tuple(out)


def needs_key(verdict: AcceptanceVerdict, rules) -> tuple:
    """A hashable key equal for verdicts with the same :func:`needs` (so the same gaps at any time)."""
    return tuple((nd.kind, nd.window, nd.n_windows) for nd in needs(verdict, rules))


def gaps(verdict: AcceptanceVerdict, rules, days: Sequence[SunDay], now_s: float) -> tuple[Gap, ...]:
    """What ``verdict`` still lacks and the next opening of each, soonest first.

    The rising band opens between the sun's rising crossings of ``low_band_deg``; the setting band
    likewise; window k opens at the same fraction of each day's high span; more points (or a
    better RMS, up to :data:`RMS_GAP_POINTS_FACTOR` × ``min_points`` points) can be had whenever
    the sun is above ``low_band_deg[0]``.
    """
    return time_needs(needs(verdict, rules), days, now_s)


def time_needs(wanted: Sequence[Need], days: Sequence[SunDay], now_s: float) -> tuple[Gap, ...]:
    """The :class:`Gap` of each need: its next opening at or after ``now_s``, soonest first."""

    def next_opening(spans) -> tuple[float | None, float | None]:
        for a, b in spans:
            if a is not None and b is not None and b > now_s:
                return max(a, now_s), b
        return None, None

    out: list[Gap] = []
    for nd in wanted:
        if nd.kind == "rising":
            spans = ((d.rise_band_start_s, d.rise_band_end_s) for d in days)
        elif nd.kind == "setting":
            spans = ((d.set_band_start_s, d.set_band_end_s) for d in days)
        elif nd.kind == "window":
            spans = (d.high_window(nd.window, nd.n_windows) or (None, None) for d in days)
        else:  # points, rms: whenever the sun is up
            spans = (d.daylight or (None, None) for d in days)
        a, b = next_opening(spans)
        out.append(Gap(nd.kind, nd.window, a, b, nd.description))
    return tuple(sorted(out, key=lambda g: (g.next_start_s is None, g.next_start_s or 0.0)))
