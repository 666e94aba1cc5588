"""The simulator's hidden truth: each heliostat's true errors and where its beam really lands.

True geometry = a :class:`~helicalib.geometry.heliostat.HeliostatModel` with hidden parameters
drawn from the scenario's distributions, plus effects the error model does not contain:

* backlash: the mirror lags the encoder by half the dead band against the last approach direction;
* stroke repeatability: a fresh stroke error at every command;
* gravity sag: the normal droops by ``sag · sin(normal zenith)`` (most when the mirror stands upright);
* wind jitter: the normal wanders with std ``k · wind`` (redrawn every second of plant time);
* slow drift: the pedestal tilts (foundation settlement) at a constant hidden rate;
* drift events (``scenario.drift``) on a share of the heliostats: a pedestal tilt step
  (settling), an actuator's zero-offset step (actuator swap) or a tilt creep over some days, at
  random times, listed in :attr:`TrueField.drift_events`.

Everything is vectorised over heliostats and deterministic from the scenario seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.sim import noise
from helicalib.sim.scenario import Scenario

WEEK_S = 7 * 86400.0
UP = np.array([0.0, 0.0, 1.0])
_S_PARAMS, _S_BACKLASH, _S_SAG, _S_DRIFT, _S_JITTER, _S_REPEAT = 31, 32, 33, 34, 35, 36
_S_EV_WHO, _S_EV_KIND, _S_EV_TIME, _S_EV_SIZE, _S_EV_DIR = 37, 38, 39, 40, 41
DAY_S = 86400.0


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of 3-vectors (broadcast), with its very operations (the same bits), without
    its per-call overhead (a measured heliostat is one row)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) perpendicular to the unit normals ``n`` (N, 3) and to each other."""
    t1 = _cross(UP, n)
    norm = np.linalg.norm(t1, axis=-1, keepdims=True)
    t1 = np.where(norm > 1e-9, t1 / np.where(norm > 1e-9, norm, 1.0), np.array([1.0, 0.0, 0.0]))
    return t1, _cross(n, t1)


@dataclass(frozen=True)
class DriftEvent:
    """One injected drift of one heliostat (the simulator's truth, never the controller's).

    ``delta`` holds the change of each error parameter once the event is complete (a step: at
    ``start_s``; a creep: at ``end_s``, growing linearly from ``start_s``) [parameter units].
    """

    heliostat_id: str
    row: int
    kind: str          # "settle" | "actuator" | "creep"
    start_s: float     # plant time the event begins [UTC s]
    end_s: float       # plant time it is complete (= start_s for a step) [UTC s]
    delta: dict[str, float]

    def to_dict(self) -> dict:
        return {"heliostat_id": self.heliostat_id, "kind": self.kind, "start_s": self.start_s,
                "end_s": self.end_s, "delta": dict(self.delta)}


def draw_drift_events(cfg, scenario: Scenario, start_s: float) -> tuple[DriftEvent, ...]:
    """The drift events of ``scenario.drift`` for the heliostats of ``cfg``, deterministic from the
    scenario seed: who drifts (each heliostat with probability ``share``), which kind, when, how much."""
    d = scenario.drift
    n = len(cfg.heliostats)
    if d.share <= 0 or n == 0:
        return ()
    seed = int(scenario.seed)
    idx = np.arange(n)
    rows = idx[noise.uniform(seed, _S_EV_WHO, idx) < d.share]
    kinds = [k for k, w in d.kinds.items() if w > 0]
    cum = np.cumsum([d.kinds[k] for k in kinds]) / sum(d.kinds[k] for k in kinds)
    kind_of = np.searchsorted(cum, noise.uniform(seed, _S_EV_KIND, rows), side="right").clip(0, len(kinds) - 1)
    within = d.within_days if d.within_days is not None else scenario.duration_days - d.after_days
    t0 = start_s + DAY_S * (d.after_days + within * noise.uniform(seed, _S_EV_TIME, rows))
    size = noise.uniform(seed, _S_EV_SIZE, rows)
    angle = 2.0 * np.pi * noise.uniform(seed, _S_EV_DIR, rows)
    events = []
    for r, k, t, u, a in zip(rows, kind_of, t0, size, angle):
        kind = kinds[int(k)]
        t = float(np.round(t))  # whole plant seconds
        if kind == "actuator":
            lo, hi = d.actuator_mm
            which = 1 if np.cos(a) >= 0 else 2  # one of the two actuators, with a random sign
            sign = 1.0 if np.sin(a) >= 0 else -1.0
            delta = {f"stroke_offset_{which}_mm": sign * (lo + (hi - lo) * float(u))}
            end = t
        else:
            lo, hi = d.settle_mrad if kind == "settle" else d.creep_mrad_per_day
            mag = lo + (hi - lo) * float(u)
            end = t if kind == "settle" else t + d.creep_days * DAY_S
            if kind == "creep":
                mag *= d.creep_days  # the tilt reached at the end of the creep
            delta = {"pedestal_tilt_e_mrad": mag * float(np.cos(a)), "pedestal_tilt_n_mrad": mag * float(np.sin(a))}
        events.append(DriftEvent(cfg.heliostats[int(r)].id, int(r), kind, t, float(end), delta))
    return tuple(events)


@dataclass(frozen=True)
class TrueBeam:
    """True beams of N heliostats: ``origin_enu`` (N, 3) [m], ``direction_enu`` (N, 3), ``normal_enu`` (N, 3)."""

    origin_enu: np.ndarray
    direction_enu: np.ndarray
    normal_enu: np.ndarray


class TrueField:
    """Hidden true errors of every heliostat of a field config.

    Parameters
    ----------
    cfg : config.FieldConfig
    scenario : Scenario
        ``errors`` (std per parameter; None = the error model's priors), ``unmodelled``, ``seed``.
    start_s : float
        Plant time at which the drift is zero [UTC s].
    zero : bool
        True for a perfect field (no errors of any kind), e.g. to check the nominal model.
    """

    def __init__(self, cfg, scenario: Scenario, start_s: float, zero: bool = False):
        self.cfg = cfg
        self.nominal = HeliostatModel.from_config(cfg)
        n = len(self.nominal)
        self.n = n
        self.start_s = float(start_s)
        self.seed = int(scenario.seed)
        u = scenario.unmodelled
        idx = np.arange(n)
        sigma = em.prior_sigma(scenario.errors if scenario.errors is not None else None)
        if scenario.errors is not None:  # only the listed parameters carry errors
            sigma = np.array([scenario.errors.get(name, 0.0) for name in em.NAMES], dtype=float)
        z = noise.normal(self.seed, _S_PARAMS, idx[:, None], np.arange(em.P)[None, :])
        scale = 0.0 if zero else 1.0
        # the truth's backlash is its own effect below (backlash_mm, with the plant's real approach)
        sigma[[em.index(name) for name in em.BACKLASH]] = 0.0
        self.params0 = scale * z * sigma
        self.backlash_mm = scale * u.backlash_mm * np.abs(noise.normal(self.seed, _S_BACKLASH, idx[:, None], np.arange(2)))
        self.sag_mrad = scale * np.maximum(0.0, u.gravity_sag_mrad + u.gravity_sag_spread_mrad
                                           * noise.normal(self.seed, _S_SAG, idx))
        self.drift_mrad_per_s = scale * (u.drift_mrad_per_week / WEEK_S) * noise.normal(
            self.seed, _S_DRIFT, idx[:, None], np.arange(2))
        self.jitter_mrad_per_ms = scale * u.wind_jitter_mrad_per_ms
        self.repeatability_mm = scale * u.repeatability_mm
        self._cols_drift = [em.index("pedestal_tilt_e_mrad"), em.index("pedestal_tilt_n_mrad")]
        self.drift_events: tuple[DriftEvent, ...] = () if zero else draw_drift_events(cfg, scenario, start_s)
        ev = self.drift_events
        self._ev_rows = np.array([e.row for e in ev], dtype=int)
        self._ev_start = np.array([e.start_s for e in ev], dtype=float)
        self._ev_end = np.array([e.end_s for e in ev], dtype=float)
        self._ev_delta = np.zeros((len(ev), em.P))
        for i, e in enumerate(ev):
            for name, value in e.delta.items():
                self._ev_delta[i, em.index(name)] = value
        self._cache: tuple[tuple[int, int], HeliostatModel] | None = None
        self._row_models: dict[int, HeliostatModel] = {}

    # -- hidden parameters -----------------------------------------------------------------
    def params_at(self, t_s: float) -> np.ndarray:
        """True error parameters (N, P) at plant time ``t_s`` (drift and drift events included)."""
        p = self.params0.copy()
        p[:, self._cols_drift] += self.drift_mrad_per_s * (float(t_s) - self.start_s)
        if len(self._ev_rows):
            te = float(t_s)
            span = self._ev_end - self._ev_start
            done = np.where(span > 0, np.clip((te - self._ev_start) / np.where(span > 0, span, 1.0), 0.0, 1.0),
                            (te >= self._ev_start).astype(float))
            np.add.at(p, self._ev_rows, done[:, None] * self._ev_delta)
        return p

    def model_at(self, t_s: float) -> HeliostatModel:
        """The true :class:`HeliostatModel` at ``t_s``: the slow drift and creeps evaluated per hour
        of plant time, a step event from its own second on."""
        t = float(t_s)
        hour = int(np.floor(t / 3600.0))
        steps = int(np.count_nonzero((self._ev_end == self._ev_start) & (self._ev_start <= t)))
        if self._cache is None or self._cache[0] != (hour, steps):
            # creeps at the hour, every step already passed at t (none of the hour's later ones)
            t_eval = hour * 3600.0
            p = self.params_at(t_eval)
            late = (self._ev_end == self._ev_start) & (self._ev_start > t_eval) & (self._ev_start <= t)
            if late.any():
                np.add.at(p, self._ev_rows[late], self._ev_delta[late])
            self._cache = ((hour, steps), self.nominal.with_params(p))
            self._row_models.clear()
        return self._cache[1]

    def _model_of_row(self, t_s: float, row: int) -> HeliostatModel:
        """``model_at(t_s).subset([row])``, kept while that model holds (a visit reads its
        heliostat many times within the plant hour)."""
        model = self.model_at(t_s)
        hit = self._row_models.get(row)
        if hit is None:
            if len(self._row_models) >= 256:
                self._row_models.clear()
            hit = self._row_models[row] = model.subset(np.array([row]))
        return hit

    def repeat_noise_mm(self, command_count: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
        """Stroke repeatability error (k, 2) [mm] of the given command number of each heliostat."""
        idx = np.arange(self.n) if idx is None else np.asarray(idx)
        return self.repeatability_mm * noise.normal(self.seed, _S_REPEAT, idx[:, None],
                                                    np.asarray(command_count)[:, None], np.arange(2)[None, :])

    # -- forward ---------------------------------------------------------------------------
    def beam(self, strokes_mm: np.ndarray, sun_enu: np.ndarray, t_s: float, wind_ms: float = 0.0,
             approach: np.ndarray | None = None, stroke_noise_mm: np.ndarray | None = None,
             jitter: bool = True, rows: np.ndarray | None = None) -> TrueBeam:
        """True beams of all N heliostats (or of ``rows``) at encoder strokes (N, 2) [mm].

        Parameters
        ----------
        strokes_mm : (N, 2) encoder strokes (what the plant reports) [mm]
        sun_enu : (3,) unit sun vector
        t_s : plant time [UTC s] (drift, jitter draw)
        wind_ms : 10-min mean wind [m/s] (jitter amplitude)
        approach : (N, 2) sign of the last motion of each actuator (+1 extending); None = no backlash
        stroke_noise_mm : (N, 2) repeatability error of the current command; None = none
        jitter : include the wind jitter
        rows : (k,) heliostat indices, optional
            Only these heliostats (the other arguments still cover all N): the same beams as the
            full call's rows, for the cost of k heliostats, not N.
        """
        sel = np.arange(self.n) if rows is None else np.asarray(rows, dtype=int)
        return self.beam_of_rows(None if rows is None else sel, np.asarray(strokes_mm, dtype=float)[sel], sun_enu,
                                 t_s, wind_ms, None if approach is None else np.asarray(approach)[sel],
                                 None if stroke_noise_mm is None else np.asarray(stroke_noise_mm)[sel], jitter)

    def beam_of_rows(self, rows: np.ndarray | None, strokes_mm: np.ndarray, sun_enu: np.ndarray, t_s: float,
                     wind_ms: float = 0.0, approach: np.ndarray | None = None,
                     stroke_noise_mm: np.ndarray | None = None, jitter: bool = True) -> TrueBeam:
        """:meth:`beam` of the heliostats ``rows`` (k,) (None: all N) from their own rows (k, 2) of
        strokes, approach and repeatability error: the same beams, without field-sized arguments."""
        sel = np.arange(self.n) if rows is None else np.asarray(rows, dtype=int)
        s = np.asarray(strokes_mm, dtype=float)
        if approach is not None:
            s = s - 0.5 * self.backlash_mm[sel] * np.sign(np.asarray(approach))
        if stroke_noise_mm is not None:
            s = s + np.asarray(stroke_noise_mm)
        if rows is None:
            model = self.model_at(t_s)
        elif sel.size == 1:
            model = self._model_of_row(t_s, int(sel[0]))
        else:
            model = self.model_at(t_s).subset(sel)
        n = model.normal(s)
        # gravity sag: tilt the normal down toward the horizon by sag · sin(zenith of the normal)
        up_t = UP - n[:, 2:3] * n
        sin_zen = np.linalg.norm(up_t, axis=-1)
        e_up = up_t / np.where(sin_zen > 1e-9, sin_zen, 1.0)[:, None]
        a = 1e-3 * self.sag_mrad[sel] * sin_zen
        n = np.cos(a)[:, None] * n - np.sin(a)[:, None] * e_up
        if jitter and self.jitter_mrad_per_ms > 0 and wind_ms > 0:
            t1, t2 = _tangent_basis(n)
            tick = np.int64(np.floor(t_s))
            j = 1e-3 * self.jitter_mrad_per_ms * wind_ms * noise.normal(
                self.seed, _S_JITTER, tick, sel[:, None], np.arange(2)[None, :])
            n = optics.unit(n + j[:, :1] * t1 + j[:, 1:] * t2)
        sun = optics.unit(np.broadcast_to(np.asarray(sun_enu, dtype=float), n.shape))
        origin = optics.mirror_centre(model.pivots_eff_enu, n, model.mirror_offset_m)
        return TrueBeam(origin, optics.reflect(sun, n), n)

    def spots(self, beam: TrueBeam, targets) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where each beam meets the plane of its own target (one ``config.Target`` per heliostat).

        Returns ``(uv_m (N, 2), hit_enu (N, 3), on_board (N,) bool)``.
        """
        uv = np.full((self.n, 2), np.nan)
        hit = np.full((self.n, 3), np.nan)
        for t in {id(t): t for t in targets}.values():
            sel = np.array([tt is t for tt in targets])
            uv[sel], hit[sel], _ = optics.intersect_target(beam.origin_enu[sel], beam.direction_enu[sel], t)
        half = np.array([t.size_m for t in targets], dtype=float) / 2.0
        with np.errstate(invalid="ignore"):
            on = np.all(np.abs(uv) <= half, axis=-1)
        return uv, hit, on

    def tracking_error_mrad(self, beam: TrueBeam, aim_enu: np.ndarray, targets) -> np.ndarray:
        """True tracking error (N,) [mrad] of each beam against its aim point (N, 3) on its target plane."""
        _, hit, _ = self.spots(beam, targets)
        return optics.tracking_error_mrad(hit, aim_enu, self.nominal.pivots_enu)
