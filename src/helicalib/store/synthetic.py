"""A synthetic campaign database of any size, written through the store's own API.

What a crew reads (``status``, the console, ``report``, ``export-paint``) and what the store
keeps (rows, frames, retention) must be measured at a real plant's size: 10⁴ heliostats over a
month. Simulating that costs hours; this module writes the same kinds of rows in a minute, with
the shapes a campaign leaves behind, so tests and ``benchmarks/`` can build such a database.

The schedule is a commissioning campaign followed by operation:

* Commissioning: the field is taken in order, ``per_day`` heliostats a plant day (by default the
  band-capacity estimate of 8 boards with turns, ``docs/benchmarks.md``). A heliostat's first day
  has a visit in the rising 5–15° band, three above 15° two hours apart, and one in the setting
  band: five points, which the paper's rules accept when the errors are small.
* Operation: from the day after, one check visit every ``check_every_days`` plant days.

Each visit has one or two readings (the first placement's error from the uncalibrated model, the
second after the loop's correction), ``invalid_share`` of readings invalid with a vision reason,
a fit after each valid visit, a verdict, and a ``tracking_written`` event; the gate opens and
closes once a day. Sun positions are the site's (NREL SPA, :func:`helicalib.geometry.sun.sun_at_site`)
at the capture times. Frames are written only when asked (``frame_shape``): a noise background
with a bright disc, the size a real camera frame of that shape compresses to.

Nothing here is a measurement: the numbers are drawn from seeded distributions (the values the
demo campaign shows), not from a model of the plant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from helicalib.geometry.sun import sun_at_site, to_unix_seconds
from helicalib.store.records import Observation
from helicalib.store.sqlite import Store

INVALID_REASONS = ("clipped", "no_spot", "low_contrast", "camera_timeout")
"""The invalid readings' reasons, drawn evenly."""

FIT_PARAMS = ("arm_scale_1", "arm_scale_2", "axis_nonorthogonality_mrad", "backlash_1_mm", "backlash_2_mm",
              "canting_1_mrad", "canting_2_mrad", "pedestal_tilt_e_mrad", "pedestal_tilt_n_mrad", "pedestal_yaw_mrad",
              "pivot_de_m", "pivot_dn_m", "pivot_du_m", "stroke_offset_1_mm", "stroke_offset_2_mm")
"""The campaign model's parameters (``geometric-backlash-v2``), as a fit records them."""


@dataclass(frozen=True)
class SyntheticSummary:
    """What :func:`build_synthetic_campaign` wrote."""

    campaign_id: int
    heliostats: int
    days: float
    visits: int
    observations: int
    fits: int
    verdicts: int
    events: int
    frames: int


def build_synthetic_campaign(store: Store, cfg, *, days: float = 30.0, start: str = "2026-09-22T00:00:00Z",
                             seed: int = 0, per_day: int | None = None, check_every_days: float = 5.0,
                             invalid_share: float = 0.03, frame_shape: tuple[int, int] | None = None,
                             heliostat_ids: list[str] | None = None, finished: bool = True,
                             progress: Callable[[int, int], None] | None = None) -> SyntheticSummary:
    """Write one synthetic campaign of ``cfg``'s heliostats (a :class:`helicalib.config.FieldConfig`)
    into ``store`` (open it ``batched=True``, ``durable=False`` for speed); returns the counts.

    ``progress(done, total)`` is called as heliostats are written."""
    rng = np.random.default_rng(seed)
    ids = list(heliostat_ids) if heliostat_ids is not None else [h.id for h in cfg.heliostats]
    n = len(ids)
    per_day = int(per_day or max(1, math.ceil(n / 13.0)))
    t0 = float(to_unix_seconds(start))
    n_days = max(1, int(math.ceil(days)))
    grid_s = t0 + np.arange(0.0, n_days * 86400.0, 120.0)
    sun = sun_at_site(cfg.site, grid_s)
    elev = np.asarray(sun.elevation_deg, dtype=float)
    rising = np.gradient(elev) > 0
    cid = store.start_campaign(name=f"synthetic {cfg.site.name}", mode="simulate", started_s=t0,
                               heliostats=[(hid, cfg.heliostat_index(hid), cfg.heliostat(hid).target) for hid in ids],
                               config_path=str(cfg.source or ""), settings={"synthetic": True, "seed": seed,
                                                                            "days": days})
    counts = dict(visits=0, observations=0, fits=0, verdicts=0, events=0, frames=0)
    end_s = t0 + days * 86400.0
    writer = _Writer(store, cid, rng, cfg, sun, grid_s, invalid_share, frame_shape, counts)
    for d in range(n_days):  # the gate: closed at night, open from the first minute the sun is 5° high
        day = (grid_s >= t0 + d * 86400.0) & (grid_s < t0 + (d + 1) * 86400.0) & (elev >= 5.0)
        if day.any():
            first, last = grid_s[day][0], grid_s[day][-1]
            writer.event(first, "ungated", None, "calibration allowed: wind 3.1 m/s (good), DNI 812 W/m²")
            writer.event(last, "gated", None, "sun below 5°: no calibration")
    windows: dict[int, tuple] = {}  # a commissioning day's band and high-sun instants, found once per day
    for i, hid in enumerate(ids):
        d = i // per_day
        if d not in windows:
            windows[d] = _day_windows(grid_s, elev, rising, t0 + d * 86400.0)
        times = _commissioning_times(*windows[d], rng)
        if times:
            times += [t for t in np.arange(times[-1] + check_every_days * 86400.0, end_s, check_every_days * 86400.0)]
        points = 0
        for k, t in enumerate(t for t in times if t < end_s):
            points += writer.visit(hid, cfg.heliostat(hid).target, float(t), first=(k == 0))
            accepted = points >= 5 and k >= 4
            writer.verdict(hid, float(t) + 60.0, accepted, points, k)
        if progress is not None and ((i + 1) % 500 == 0 or i + 1 == n):
            progress(i + 1, n)
    store.flush()
    if finished:
        store.finish_campaign(cid, end_s)
    return SyntheticSummary(campaign_id=cid, heliostats=n, days=float(days), **counts)


def _day_windows(grid_s, elev, rising, day0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The instants of one plant day with the sun in the rising 5–15° band, in the setting one, and above 15°."""
    day = (grid_s >= day0) & (grid_s < day0 + 86400.0)
    up = day & (elev >= 5.0) & (elev <= 15.0)
    return grid_s[up & rising], grid_s[up & ~rising], grid_s[day & (elev > 15.0)]


def _commissioning_times(rise, sets, high, rng) -> list[float]:
    """A commissioning day's five visit times: rising band, three above 15° 2 h apart, setting band."""
    if not len(rise) or not len(sets) or not len(high):
        return []
    noon = high[0] + (high[-1] - high[0]) / 2.0
    return [float(rng.choice(rise)), noon - 7200.0, noon, noon + 7200.0, float(rng.choice(sets))]


class _Writer:
    """Writes one visit's rows (readings, fit, event) through the store's API."""

    def __init__(self, store, cid, rng, cfg, sun, grid_s, invalid_share, frame_shape, counts):
        self.store, self.cid, self.rng, self.cfg = store, cid, rng, cfg
        self.sun, self.grid_s = sun, grid_s
        self.invalid_share, self.frame_shape, self.counts = invalid_share, frame_shape, counts
        self.sun_enu = np.asarray(sun.vector_enu, dtype=float)
        elev = np.asarray(sun.elevation_deg, dtype=float)
        self.rising = np.append(elev[1:] > elev[:-1], False)  # the sun higher at the next instant

    def event(self, t: float, kind: str, hid: str | None, reason: str) -> None:
        self.store.record_event(campaign_id=self.cid, time_s=t, kind=kind, reason=reason, heliostat_id=hid)
        self.counts["events"] += 1

    def visit(self, hid: str, target_id: str, t: float, first: bool) -> int:
        """One visit; returns how many valid readings it had."""
        rng = self.rng
        vid = self.store.begin_visit(self.cid, hid, target_id, t)
        self.counts["visits"] += 1
        errors = [float(rng.lognormal(math.log(4.0 if first else 1.2), 0.4))]
        if errors[0] > 3.5:
            errors.append(float(abs(rng.normal(0.0, 0.6))))
        valid_n = 0
        when = t
        for it, err in enumerate(errors):
            when = t + 40.0 + 45.0 * it
            valid = bool(rng.random() >= self.invalid_share)
            self._reading(hid, target_id, vid, it, when, err, valid)
            valid_n += valid
        ok = valid_n > 0 and errors[-1] < 3.5
        self.store.end_visit(vid, ended_s=when + 20.0, outcome="converged" if ok else "invalid",
                             reason="ok" if ok else "the last reading was not valid", iterations=len(errors),
                             first_error_mrad=errors[0], final_error_mrad=errors[-1])
        if valid_n:
            self._fit(hid, when + 25.0)
            self.event(when + 30.0, "tracking_written", hid, f"{hid}: tracking corrections "
                       f"{rng.normal(0, 2):+.2f}, {rng.normal(0, 2):+.2f} mm")
        return valid_n

    def _reading(self, hid, target_id, vid, it, when, err, valid) -> None:
        rng = self.rng
        j = min(int(np.searchsorted(self.grid_s, when)), len(self.grid_s) - 1)
        centre = np.asarray(self.cfg.target(target_id).center_enu_m, dtype=float)
        u, v = rng.normal(0.0, err * 0.12 / math.sqrt(2.0), 2)  # ≈ 120 m / mrad·1e-3 at the board
        strokes = tuple(float(x) for x in rng.uniform(300.0, 900.0, 2))
        reason = "ok" if valid else str(rng.choice(INVALID_REASONS))
        obs = Observation(
            campaign_id=self.cid, heliostat_id=hid, target_id=target_id, visit_id=vid, iteration=it,
            capture_time_s=when, strokes_cmd_mm=strokes, strokes_read_mm=strokes,
            sun_enu=tuple(float(x) for x in self.sun_enu[j]), sun_azimuth_deg=float(self.sun.azimuth_deg[j]),
            sun_elevation_deg=float(self.sun.elevation_deg[j]), valid=valid, reason=reason,
            message=f"spot centre at u = {u:+.3f} m, v = {v:+.3f} m from the board centre" if valid else
            f"{reason.replace('_', ' ')} (synthetic)", sun_rising=bool(self.rising[j]),
            wind_ms=float(rng.uniform(0.5, 8.0)), wind_direction_deg=float(rng.uniform(0, 360)),
            dni_wm2=float(rng.uniform(600, 950)), temperature_c=float(rng.uniform(5, 30)), cleanliness=0.95,
            exposure_ms=float(rng.uniform(1.5, 3.0)),
            offset_u_m=float(u) if valid else None, offset_v_m=float(v) if valid else None,
            spot_x_px=float(640 + u * 50) if valid else None, spot_y_px=float(512 - v * 50) if valid else None,
            spot_area_px=float(rng.uniform(2.5e4, 3.2e4)) if valid else None, threshold=50.0 if valid else None,
            spot_enu_m=(float(centre[0] + u), float(centre[1]), float(centre[2] + v)) if valid else None,
            error_mrad=err if valid else None, approach=(-1, -1))
        before = after = None
        if self.frame_shape is not None:
            before, after = _frame(self.frame_shape, rng, lit=False), _frame(self.frame_shape, rng, lit=valid)
            self.counts["frames"] += 2
        self.store.record_observation(obs, before_frame=before, after_frames=None if after is None else [after])
        self.counts["observations"] += 1

    def _fit(self, hid: str, t: float) -> None:
        rng = self.rng
        params = {k: float(rng.normal(0.0, 1.0)) for k in FIT_PARAMS}
        sigma = {k: float(abs(rng.normal(0.5, 0.2))) for k in FIT_PARAMS}
        self.store.record_fit(campaign_id=self.cid, heliostat_id=hid, time_s=t, model="geometric-backlash-v2",
                              params=params, sigma=sigma, rms_mrad=float(rng.uniform(0.3, 0.9)),
                              n_points=int(rng.integers(5, 15)))
        self.counts["fits"] += 1

    def verdict(self, hid: str, t: float, accepted: bool, points: int, k: int) -> None:
        reasons = [] if accepted else ["fewer than 5 valid points" if points < 5 else "no point in the setting band"]
        rms = float(self.rng.uniform(0.4, 1.1)) if points >= 3 else None
        self.store.record_verdict(campaign_id=self.cid, heliostat_id=hid, time_s=t, accepted=accepted,
                                  n_points=points, rms_mrad=rms, reasons=reasons,
                                  details={"rising_ok": True, "setting_ok": k >= 4,  # the rising band's visit is first
                                           "window_counts": [1] * min(points, 6)})
        self.counts["verdicts"] += 1


def _frame(shape: tuple[int, int], rng, lit: bool) -> np.ndarray:
    """A grey 8-bit frame: sensor noise on a board, with a bright disc when the beam is on it."""
    h, w = shape
    img = rng.normal(60.0, 6.0, (h, w))
    if lit:
        yy, xx = np.ogrid[:h, :w]
        img[(yy - h / 2) ** 2 + (xx - w / 2) ** 2 < (min(h, w) / 6) ** 2] += 120.0
    return np.clip(img, 0, 255).astype(np.uint8)


def open_for_synthesis(path: str | Path) -> Store:
    """A fast writer for a synthetic database (batched, not fsynced: it is not a plant's record)."""
    return Store.open(path, durable=False, batched=True)
