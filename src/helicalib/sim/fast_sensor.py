"""The simulated "fast" spot sensor: the simulator's true spot plus a measurement-error model.

A :class:`~helicalib.campaign.sensor.SpotSensor` like the camera + vision, for simulated fields
too large to render: no frame is drawn, encoded, decoded or searched. For each after frame it
takes the measured heliostat's true beam (wind jitter included, the same truth the renderer
draws) and where it meets the board, with the footprint, blur and power the renderer would give
it (:func:`helicalib.sim.camera.spot_geometry`). It then decides validity with the vision's own
limits (:class:`helicalib.vision.spot.SpotLimits`), computed from the spot's irradiance profile
instead of from pixels:

* ``no_spot``: the beam misses the board (or lights fewer cells than the vision needs);
* ``low_contrast``: the peak of the after − before difference below ``min_contrast`` grey levels;
* ``saturated``: more than ``max_saturated_fraction`` of the spot at ≥ 250 grey levels;
* ``clipped``: the thresholded spot (threshold a fitted fraction of its peak, where Otsu's lands
  on rendered spots) reaches the board's rim; its centre is then the visible part's centroid;
* ``ambient_change``: the ambient light changed by more than ``max_ambient_change`` between the
  before and the after frames (DNI moved);
* ``jitter``: with several after frames, the RMS spread of their spot centres above the limit;
* exposure (PLANT_INTERFACE 1.1; the scenario's ``camera.exposure``): a camera that takes one is
  exposed as the controller's policy exposes it once it has learnt the camera's gain
  (:mod:`helicalib.campaign.exposure`): the spot's brightest grey level, board light included, at
  ``TARGET_GREY`` (so the white board stays under it), within the camera's range
  (:func:`policy_exposure`). Light scales with the exposure and the sensor's noise as the
  renderer's (:func:`helicalib.sim.camera.noise_scale`), so a faint spot is judged on its peak at
  that exposure (``low_contrast``) and on its peak over the noise's growth (``no_spot``). A camera
  without exposure control stays at the nominal exposure, where the error model was fitted;
* ``ambient_change`` with ``before_beam``: another heliostat's beam lay on the board at the before
  frame (one the plant shows moving, drawn as the renderer would, not stopped by another board) and
  its light is gone in the after frames over at least ``max_lost_light_share`` of the spot's area,
  judged on one grid over the board (:func:`lost_light_share`). As the camera sensor, the sensor can
  take the before frame again (:meth:`FastSensor.retake`) and judge the same after spots against it.

A valid spot's measured centre is the mean true centre plus the vision's error: a bias and a
Gaussian spread ``sqrt(floor² + (k · σ_spot)²)`` per board axis, both fitted on rendered
measurements by ``simulations/fit_fast_sensor.py`` into ``fast_sensor.json`` beside this module.
The measured cleanliness is the plant's true soiling with the vision's relative spread.
"""

from __future__ import annotations

import json
import math
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import ndtr

from helicalib.campaign.exposure import TARGET_GREY
from helicalib.devices.protocols import Before, Reading
from helicalib.sim.camera import noise_scale, spot_geometry, stopped_before
from helicalib.vision.spot import SATURATED_LEVEL, SpotLimits

MODEL_PATH = Path(__file__).with_name("fast_sensor.json")


@dataclass(frozen=True)
class SensorErrorModel:
    """The vision's measurement error and threshold, as fitted on rendered spots."""

    bias_m: tuple[float, float] = (0.0, 0.0)
    """Mean measured − true spot centre (u, v) [m]."""
    floor_m: float = 0.004
    """Spread of the measured centre for a sharp spot [m]."""
    per_sigma: float = 0.02
    """Added spread per metre of the spot's blur σ [m/m]."""
    threshold_fraction: float = 0.3
    """Annex A threshold as a fraction of the spot's peak difference (Otsu's, on rendered spots)."""
    cleanliness_sigma: float = 0.004
    """Relative spread of the measured cleanliness."""
    contrast_scale: float = 1.0
    """The vision's peak difference over the spot's analytic peak (3×3 smoothing, pixel footprint,
    noise on the brightest pixel), as fitted: faint spots are judged on the scaled peak."""
    no_spot_fraction: float = 0.5
    """A peak below this fraction of ``min_contrast`` reads as no spot (the vision's signal-to-noise
    limit) rather than a faint one, as fitted."""

    @classmethod
    def load(cls, path: Path | str = MODEL_PATH) -> SensorErrorModel:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        p = data["model"]
        return cls(bias_m=tuple(p["bias_m"]), floor_m=p["floor_m"], per_sigma=p["per_sigma"],
                   threshold_fraction=p["threshold_fraction"], cleanliness_sigma=p["cleanliness_sigma"],
                   contrast_scale=p.get("contrast_scale", 1.0), no_spot_fraction=p.get("no_spot_fraction", 0.5))

    def spread_m(self, sigma_spot_m: np.ndarray) -> np.ndarray:
        """Spread (2,) [m] of the measured centre of a spot blurred by ``sigma_spot_m`` (2,)."""
        return np.sqrt(self.floor_m ** 2 + (self.per_sigma * np.asarray(sigma_spot_m, dtype=float)) ** 2)


def _profile(grid: np.ndarray, centre: float, width: float, sigma: float) -> np.ndarray:
    """The renderer's box ⊗ Gaussian profile along one axis (integrates to 1)."""
    half = width / 2.0
    return (ndtr((grid - centre + half) / sigma) - ndtr((grid - centre - half) / sigma)) / width


@dataclass(frozen=True)
class SpotPhysics:
    """One spot as the camera would see it: true centre, footprint, blur, power, grey levels."""

    uv_m: np.ndarray
    width_m: np.ndarray
    sigma_m: np.ndarray
    power_w: float
    on_plane: bool


def peak_wm2(s: SpotPhysics) -> float:
    """The spot's peak irradiance [W/m²] (its centre's, wherever that lands)."""
    width, sigma = np.asarray(s.width_m, dtype=float), np.maximum(np.asarray(s.sigma_m, dtype=float), 1e-9)
    per_axis = (2.0 * ndtr(width / (2.0 * sigma)) - 1.0) / width
    return float(s.power_w * per_axis[0] * per_axis[1])


def policy_exposure(s: SpotPhysics, spec, ambient_wm2: float, contrast_scale: float = 1.0) -> float:
    """The exposure, relative to the nominal one, the controller's policy gives a camera that takes
    one for spot ``s`` on a board lit by ``ambient_wm2``: the after frame's brightest grey level at
    ``TARGET_GREY``, within ``spec.exposure_range_ms``."""
    gain = spec.gain_counts_per_wm2 * spec.board_albedo
    board, spot = gain * ambient_wm2, contrast_scale * gain * peak_wm2(s)
    e = TARGET_GREY / max(board + spot, 1e-9)
    lo, hi = (float(x) / float(spec.exposure_ms) for x in spec.exposure_range_ms)
    return float(min(max(e, lo), hi))


def judge_spot(s: SpotPhysics, target, spec, limits: SpotLimits, threshold_fraction: float, ambient_before: float,
               ambient_after: float, contrast_scale: float = 1.0, no_spot_fraction: float = 0.5,
               exposure: float = 1.0):
    """(reason, message, centroid (2,) or None) of one spot by the vision's limits: ``spec`` is the
    scenario's camera (gain, albedo), ``threshold_fraction`` the annex A threshold over the peak;
    ``contrast_scale`` and ``no_spot_fraction`` as in :class:`SensorErrorModel`; ``exposure`` the
    frames' exposure relative to the nominal one (light scales with it, noise by
    :func:`~helicalib.sim.camera.noise_scale`)."""
    lim, half = limits, np.asarray(target.size_m, dtype=float) / 2.0
    if not s.on_plane or not np.all(np.isfinite(s.uv_m)):
        return "no_spot", "no spot on the board.", None
    gain = spec.gain_counts_per_wm2 * spec.board_albedo * exposure
    # the irradiance over the spot's support (clipped to the board), on a 64 × 64 grid
    reach = s.width_m / 2.0 + 3.0 * s.sigma_m
    lo, hi = np.maximum(s.uv_m - reach, -half), np.minimum(s.uv_m + reach, half)
    if np.any(hi <= lo):
        return "no_spot", "no spot on the board: the beam lands beside it.", None
    gu, gv = np.linspace(lo[0], hi[0], 64), np.linspace(lo[1], hi[1], 64)
    pu = _profile(gu, s.uv_m[0], s.width_m[0], s.sigma_m[0])
    pv = _profile(gv, s.uv_m[1], s.width_m[1], s.sigma_m[1])
    flux = s.power_w * np.multiply.outer(pv, pu)
    diff = gain * flux
    peak = contrast_scale * float(diff.max())
    if peak < lim.min_contrast:
        over_noise = peak if exposure == 1.0 else peak / noise_scale(exposure, spec.read_noise_share)
        return ("no_spot" if over_noise < no_spot_fraction * lim.min_contrast else "low_contrast",
                f"the spot's peak difference {peak:.0f} grey levels is below {lim.min_contrast:.0f}.", None)
    region = diff >= threshold_fraction * peak
    w = np.where(region, flux, 0.0)
    centroid = np.array([np.sum(w.sum(axis=0) * gu), np.sum(w.sum(axis=1) * gv)]) / max(float(w.sum()), 1e-12)
    cell = np.abs(gu[1] - gu[0]) + np.abs(gv[1] - gv[0])
    rim = ((np.abs(gu) >= half[0] - cell)[None, :] | (np.abs(gv) >= half[1] - cell)[:, None]) & region
    if np.count_nonzero(rim) > 0:
        return "clipped", "the spot reaches the board's rim.", centroid
    level = gain * (flux + ambient_after)
    saturated = np.count_nonzero(region & (level >= SATURATED_LEVEL)) / max(np.count_nonzero(region), 1)
    if saturated > lim.max_saturated_fraction:
        return "saturated", f"{100 * saturated:.0f} % of the spot is saturated.", centroid
    change = abs(ambient_after / max(ambient_before, 1e-9) - 1.0)
    if change > lim.max_ambient_change:
        return "ambient_change", f"the ambient light changed by {100 * change:.0f} % since the before frame.", None
    return "ok", "ok", centroid


LOST_GRID = 128
"""Cells per side of the board grid on which light lost since the before frame is compared."""


def _board_flux(s: SpotPhysics, gu: np.ndarray, gv: np.ndarray) -> np.ndarray:
    """The irradiance of spot ``s`` on the board grid (rows v, columns u) [W/m²]."""
    return s.power_w * np.multiply.outer(_profile(gv, s.uv_m[1], s.width_m[1], s.sigma_m[1]),
                                         _profile(gu, s.uv_m[0], s.width_m[0], s.sigma_m[0]))


def lost_light_share(s: SpotPhysics, others, target, threshold_fraction: float, contrast_scale: float = 1.0) -> float:
    """The board area where the before frame was lit by the beams ``others`` at least the threshold
    above what the after frame shows (the spot ``s`` there), over the spot's own thresholded area:
    the vision's lost-light test (``SpotLimits.max_lost_light_share``), on one grid over the board
    (:data:`LOST_GRID`). 0 when there is no other beam or no spot."""
    if not others or not s.on_plane:
        return 0.0
    half = np.asarray(target.size_m, dtype=float) / 2.0
    gu, gv = (np.linspace(-h, h, LOST_GRID) for h in half)
    ours = _board_flux(s, gu, gv)
    peak = contrast_scale * float(ours.max())
    if peak <= 0.0:
        return 0.0
    T = threshold_fraction * peak
    area = np.count_nonzero(contrast_scale * ours >= T)
    lost = np.zeros_like(ours)
    for o in others:
        lost += _board_flux(o, gu, gv)
    return float(np.count_nonzero(contrast_scale * (lost - ours) >= T)) / max(area, 1)


@dataclass(frozen=True)
class _Reference:
    """What the fast sensor keeps of a before frame: the diffuse light on the board [W/m²] and the
    spots of other beams on it then."""

    ambient_wm2: float
    others: tuple[SpotPhysics, ...] = ()


class FastSensor:
    """The simulated fast sensor of one board (see the module docstring).

    Parameters
    ----------
    plant : sim.plant.SimulatedPlant
        The in-process simulated plant (its truth, weather, soiling and camera settings).
    target_id : str
    model : SensorErrorModel, optional
        Default: the fitted ``fast_sensor.json``.
    seed : int
        Seed of the measurement noise (with the board, so boards draw independently).
    limits : SpotLimits, optional
        The vision's limits (default ones, as the camera sensor uses).
    """

    def __init__(self, plant, target_id: str, model: SensorErrorModel | None = None, seed: int = 0,
                 limits: SpotLimits | None = None):
        self.plant = plant
        self.target = plant.cfg.target(target_id)
        self.model = model or SensorErrorModel.load()
        self.limits = limits or SpotLimits()
        self.spec = plant.scenario.camera
        self.optics = plant.scenario.optics
        index = [t.id for t in plant.cfg.targets].index(target_id)
        self.boards = tuple(t for t in plant.cfg.targets if t.id != target_id)  # boards that may stop a beam
        self._rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 7919, index])

    # ------------------------------------------------------------------ physics
    def _ambient_wm2(self, t_s: float) -> float:
        """The diffuse light on the board [W/m²], as the renderer lights it."""
        _sun, elevation = self.plant.sun(t_s)
        dni = float(self.plant.weather_model.dni_wm2(t_s, elevation))
        return self.spec.ambient_fraction * dni + self.spec.ambient_offset_wm2

    def spot(self, index: int, t_s: float | None = None) -> SpotPhysics:
        """The true spot of heliostat ``index`` on this board now (wind jitter included)."""
        p = self.plant
        t = p.t_s if t_s is None else float(t_s)
        beam = p.true_beam_of(index, t)
        sun, _ = p.sun(t)
        dni = float(p.weather().dni_wm2)
        clean = np.array([p.cleanliness_of(index)])
        uv, power, width, sigma, near = spot_geometry(self.target, self.optics, beam.origin_enu, beam.direction_enu,
                                                      sun, beam.normal_enu, p.nominal.drives.mirror_size_m[[index]],
                                                      dni, clean)
        return SpotPhysics(uv[0], width[0], sigma[0], float(power[0]), bool(near[0]))

    def other_spots(self, index: int, t_s: float) -> tuple[SpotPhysics, ...]:
        """The spots on this board of the beams of heliostats other than ``index`` that the plant
        shows moving at ``t_s`` (now): the ones the renderer would draw there, less those another
        board stops first. (Resting beams are on their own boards, at standby points kept off
        other boards by ``validate``, or on the receiver.)"""
        p = self.plant
        rows = p.moving_rows()
        rows = rows[rows != int(index)]
        if not rows.size:
            return ()
        sun, _ = p.sun(t_s)
        beams = p.true_beams_of(rows, t_s)
        uv, power, width, sigma, near = spot_geometry(
            self.target, self.optics, beams.origin_enu, beams.direction_enu, sun, beams.normal_enu,
            p.nominal.drives.mirror_size_m[rows], float(p.weather().dni_wm2), p.cleanliness_many(rows))
        if near.any() and self.boards:
            idx = np.flatnonzero(near)
            near[idx[stopped_before(self.target, self.boards, beams.origin_enu[idx], beams.direction_enu[idx])]] = False
        return tuple(SpotPhysics(uv[i], width[i], sigma[i], float(power[i]), True) for i in np.flatnonzero(near))

    # ------------------------------------------------------------------ the protocol
    def before(self, ctx) -> Before:
        t = float(ctx.now())
        return Before(capture_time_s=t, data=None, state=_Reference(self._ambient_wm2(t), self.other_spots(ctx.index, t)))

    def after(self, ctx, before: Before) -> Generator[float, None, Reading]:
        spots, times = [], []
        for k in range(ctx.settings.after_frames):
            times.append(float(ctx.now()))
            spots.append(self.spot(ctx.index, times[-1]))
            if ctx.settings.after_frames > 1:
                yield 1.0
        return self._judge(ctx, before, spots, times)

    def retake(self, ctx, before: Before, reading: Reading) -> tuple[Before, Reading]:
        """A new before frame now (the beam at standby) and the same after spots judged against it."""
        new = self.before(ctx)
        return new, self._judge(ctx, new, *reading.state)

    def _judge(self, ctx, before: Before, spots: list[SpotPhysics], times: list[float]) -> Reading:
        """The reading of the after ``spots`` (taken at ``times``) against ``before``."""
        capture_s = float(np.mean(times))
        state = (spots, times)
        s = spots[-1]
        m = self.model
        ref = before.state
        ambient = self._ambient_wm2(times[-1])
        exposure = policy_exposure(s, self.spec, ambient, m.contrast_scale) if self.spec.exposure else 1.0
        reason, message, centroid = judge_spot(s, self.target, self.spec, self.limits, m.threshold_fraction,
                                               ref.ambient_wm2, ambient, m.contrast_scale, m.no_spot_fraction,
                                               exposure)
        if reason in ("ok", "clipped", "saturated") and ref.others:  # where the vision tests for lost light
            share = lost_light_share(s, ref.others, self.target, m.threshold_fraction, m.contrast_scale)
            if share >= self.limits.max_lost_light_share:
                return Reading(False, "ambient_change", f"a patch of {100 * share:.0f} % of the spot's area was lit in "
                               "the before frame and is dark in the after frame: another beam crossed the board "
                               "while the before frame was taken.", capture_s, before_beam=True, state=state)
        if reason == "ok" and len(spots) > 1:
            uvs = np.array([x.uv_m for x in spots])
            jitter = float(np.sqrt(np.mean(np.sum((uvs - uvs.mean(axis=0)) ** 2, axis=1))))
            distance_m = float(np.linalg.norm(np.asarray(self.target.center_enu_m) - ctx.model.pivots_enu[0]))
            limit = 1e-3 * ctx.settings.max_jitter_mrad * distance_m
            if jitter > limit:
                reason, message = "jitter", f"the spot moved {jitter * 1000:.0f} mm RMS over {len(spots)} frames."
            centroid = centroid + (uvs.mean(axis=0) - s.uv_m)
        if reason != "ok":
            offset = None if centroid is None else (float(centroid[0]), float(centroid[1]))
            return Reading(False, reason, message, capture_s, offset_m=offset, state=state)
        measured = (centroid + np.asarray(self.model.bias_m)
                    + self._rng.normal(0.0, 1.0, 2) * self.model.spread_m(s.sigma_m) / math.sqrt(len(spots)))
        return Reading(True, "ok", "ok", capture_s, offset_m=(float(measured[0]), float(measured[1])), state=state)

    def cleanliness(self, ctx, before: Before, reading: Reading, held_mm, weather, sun_enu) -> float | None:
        true = self.plant.cleanliness_of(ctx.index)
        return float(true * (1.0 + self.model.cleanliness_sigma * self._rng.normal()))


def fast_sensors(plant, seed: int = 0, model: SensorErrorModel | None = None) -> dict[str, FastSensor]:
    """One fast sensor per board of the simulated plant."""
    model = model or SensorErrorModel.load()
    return {t.id: FastSensor(plant, t.id, model, seed) for t in plant.cfg.targets}

