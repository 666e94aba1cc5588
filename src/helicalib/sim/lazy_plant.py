"""``LazyPlant``: the simulated plant with every heliostat in closed form, computed when read.

The stepped reference (:class:`~helicalib.sim.stepped_plant.SteppedPlant`, ``SimulatedPlant(..., lazy=False)``) moves
every heliostat at every clock advance: O(N) per advance. Here a heliostat keeps the record of
its last motion (base time, strokes, state, approach, arrival; mode and goal) and its strokes,
state and approach at plant time t follow from it when something reads them (status, true
beams, the sensors' truth, the whole-field arrays):

* strokes: ``base + clip(goal(t) − base, ±speed · (t − base time))`` per actuator. The goal is
  the held strokes, the stow strokes, or the tracking strokes of ``t`` (the same 60 s grid as the
  stepped plant); the drives outrun the sun (≈ 0.04 mm/s against ``speed_mm_s``), so a chase of
  the tracking goal is this formula at every t, as the stepped plant's sum of its steps is;
* state: MOVING until arrived (``max |goal − strokes| < 1e-6``); then HOLDING / STOWED once the
  settle time after the arrival ``base time + max |goal − base| / speed`` has passed, TRACKING at
  once; FAULT, OFFLINE and a later offline row as the stepped plant keeps them;
* approach: the sign of the motion over the last clock step (as stepping sets it), else of the
  net motion since the base, else the base's.

Reading a heliostat re-bases it at the read time (an exact restart of the same motion; one at
rest, holding, stowed, faulted or offline, is left as it is: nothing about it changes). Nothing
is done per clock advance but the field-wide checks, O(1) each: the wind stow, and the sun
crossing the horizon (the tracking goal jumps to the stow strokes and back), where the tracking
heliostats are re-based once, vectorised, at the start of that clock step. The whole-field
arrays (``state``, ``strokes_mm``, ``approach``, ``arrival_s``) bring every heliostat up to now
when read (cached for the instant; the in-place writes of a test land in the base).
"""

from __future__ import annotations

import math

import numpy as np

from helicalib.devices.protocols import HeliostatStatus
from helicalib.devices.registers import FieldState, HeliostatState
from helicalib.sim.stepped_plant import (
    _TRACK_NODES_KEPT,
    MAX_STEP_S,
    MODE_HOLD,
    MODE_IDLE,
    MODE_STOW,
    MODE_TRACK,
    TRACK_GRID_S,
    SteppedPlant,
)
from helicalib.sim.truth import TrueBeam

S = HeliostatState
_MOVED_MM = 1e-9
"""A motion below this does not change the approach (as the stepped plant's)."""
_ARRIVED_MM = 1e-6
"""Arrived: every actuator this close to its goal (as the stepped plant's)."""
_AT_REST = frozenset(int(x) for x in (S.HOLDING, S.STOWED, S.FAULT, S.OFFLINE, S.IDLE))
"""States that stay until the next command unless tracking (strokes, state and approach unchanged)."""
_AT_REST_ARRAY = np.array(sorted(_AT_REST), dtype=np.int64)


def _sign_of(step: float, net: float, before: float) -> float:
    """One actuator's approach: the sign of its last clock step's motion, else of its net motion
    since the base, else as before (a motion under ``_MOVED_MM`` does not count)."""
    for x in (step, net):
        if abs(x) > _MOVED_MM:
            return 1.0 if x > 0 else -1.0
    return before


class _WatchedMask(np.ndarray):
    """A bool array that calls ``before_write()`` before an item is set: a heliostat put offline
    by hand stops changing state from then on, so the field is brought up to that instant first."""

    before_write = None

    def __setitem__(self, key, value):
        if self.before_write is not None:
            self.before_write()
        super().__setitem__(key, value)


class LazyPlant(SteppedPlant):
    """The closed-form simulated plant (see the module docstring); same constructor as
    :class:`~helicalib.sim.plant.SimulatedPlant`, built by it when ``lazy=True``."""

    def _init_motion(self) -> None:
        n = self.n
        self._nodes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._base_t = np.full(n, self.t_s)
        self._base_mm = self._tracking_rows(self.t_s, np.arange(n))
        self._base_state = np.full(n, int(S.TRACKING), dtype=np.int64)
        self._base_state[self.offline] = int(S.OFFLINE)
        self._base_approach = np.ones((n, 2))
        self._arrival = np.full(n, -np.inf)
        self._pending: set[int] = set()
        self._synced_t = self.t_s
        self._step_start_s = self.t_s
        self._sun_up = self.sun(self.t_s)[1] > 0.0
        self._stow_done_s = -np.inf
        self._stow_start_s = -np.inf
        self.offline = self.offline.view(_WatchedMask)
        self.offline.before_write = self._sync_all

    # -- the tracking goal, row by row ---------------------------------------------------------
    def _node_for_rows(self, k: int, rows: np.ndarray) -> np.ndarray:
        """Nominal tracking strokes (k, 2) of ``rows`` at grid node ``k``: the stepped plant's
        whole-field node, solved only for the rows asked (and kept)."""
        hit = self._nodes.get(k)
        if hit is None:
            if len(self._nodes) >= _TRACK_NODES_KEPT:
                self._nodes.pop(next(iter(self._nodes)))
            hit = self._nodes[k] = (np.full((self.n, 2), np.nan), np.zeros(self.n, dtype=bool))
        values, have = hit
        miss = rows[~have[rows]]
        if miss.size:
            sun = self._sun_table.vector_enu(k * TRACK_GRID_S)
            if miss.size == self.n and np.all(miss == np.arange(self.n)):
                values[:] = self.nominal.strokes_for_aim(sun, self.tracking_aim_enu).strokes_mm
                have[:] = True
            else:
                miss = np.unique(miss)
                values[miss] = self.nominal.subset(miss).strokes_for_aim(sun, self.tracking_aim_enu[miss]).strokes_mm
                have[miss] = True
        return values[rows]

    def _tracking_rows(self, t_s: float, rows: np.ndarray) -> np.ndarray:
        """Tracking strokes (k, 2) of ``rows`` at ``t_s``: the stepped plant's ``_tracking_strokes`` rows."""
        sun, elevation = self.sun(t_s)
        if elevation <= 0.0:
            return self.stow_strokes_mm[rows]
        x = t_s / TRACK_GRID_S
        k = int(np.floor(x))
        f = x - k
        a = self._node_for_rows(k, rows)
        if f == 0.0:
            nom = a.copy()
            finite = np.all(np.isfinite(a), axis=-1)
        else:
            b = self._node_for_rows(k + 1, rows)
            nom = a + (b - a) * f
            finite = np.all(np.isfinite(a), axis=-1) & np.all(np.isfinite(b), axis=-1)
        if not finite.all():  # a grid node unreachable: solve those heliostats at this instant
            sub = rows[~finite]
            nom[~finite] = self.nominal.subset(sub).strokes_for_aim(sun, self.tracking_aim_enu[sub]).strokes_mm
        s = np.clip(nom + self.corrections_mm[rows], self._drange[0][rows], self._drange[1][rows])
        return np.where(np.isfinite(s), s, self.stow_strokes_mm[rows])

    def _goal_rows(self, t_s: float, rows: np.ndarray, mode: np.ndarray, base: np.ndarray) -> np.ndarray:
        goal = np.where((mode == MODE_HOLD)[:, None], self.goal_cmd_mm[rows],
                        np.where((mode == MODE_STOW)[:, None], self.stow_strokes_mm[rows], base))
        track = mode == MODE_TRACK
        if track.any():
            goal[track] = self._tracking_rows(t_s, rows[track])
        return goal

    def _position(self, t_s: float, rows: np.ndarray, mode: np.ndarray, base: np.ndarray,
                  base_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(strokes (k, 2), goal (k, 2)) of ``rows`` at ``t_s`` ≥ their base times."""
        goal = self._goal_rows(t_s, rows, mode, base)
        travel = (self.speed_mm_s * (t_s - base_t))[:, None]
        return base + np.clip(goal - base, -travel, travel), goal

    # -- closed form ---------------------------------------------------------------------------
    def _eval(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(strokes (k, 2), state (k,), approach (k, 2), arrival (k,)) of ``rows`` now."""
        t = self.t_s
        base_t, base, state0 = self._base_t[rows], self._base_mm[rows], self._base_state[rows]
        approach0, arrival0, mode = self._base_approach[rows], self._arrival[rows], self.mode[rows]
        pos, goal = self._position(t, rows, mode, base, base_t)
        # approach: the last clock step's motion, else the net motion since the base, else the base's
        t0 = self._step_start_s
        prev = base.copy()
        later = base_t < t0
        if later.any():
            prev[later] = self._position(t0, rows[later], mode[later], base[later], base_t[later])[0]
        step, net = pos - prev, pos - base
        approach = np.where(np.abs(step) > _MOVED_MM, np.sign(step),
                            np.where(np.abs(net) > _MOVED_MM, np.sign(net), approach0))
        # the state machine (the stepped plant's, at the read time)
        arrived = np.max(np.abs(goal - pos), axis=-1) < _ARRIVED_MM
        moving = state0 == S.MOVING
        newly = arrived & moving & ~np.isfinite(arrival0)
        arrival = np.where(newly, base_t + np.max(np.abs(goal - base), axis=-1) / self.speed_mm_s, arrival0)
        settled = arrived & (t >= arrival + self.settle_s)
        active = ~self.offline[rows] & (state0 != S.FAULT) & (state0 != S.IDLE)
        state = state0.copy()
        state[active & (mode == MODE_TRACK) & moving & arrived] = int(S.TRACKING)
        for m, done in ((MODE_HOLD, S.HOLDING), (MODE_STOW, S.STOWED)):
            sel = active & (mode == m)
            state[sel & settled] = int(done)
            state[sel & ~arrived] = int(S.MOVING)
        fresh = base_t < t  # read at its base time: as based (no clock step since)
        if not fresh.all():
            pos[~fresh], state[~fresh], approach[~fresh], arrival[~fresh] = (
                base[~fresh], state0[~fresh], approach0[~fresh], arrival0[~fresh])
        return pos, state, approach, arrival

    def _sync_fixed_one(self, i: int) -> bool:
        """:meth:`_sync` of one heliostat on its way to held or stow strokes (a constant goal) in
        Python floats, the operations of :meth:`_eval` one by one (the same numbers, without its
        array overhead: a visit polls its heliostat every 2 s until it holds). False (nothing
        done) if a value is not finite."""
        t, t0, v = self.t_s, self._step_start_s, self.speed_mm_s
        tb, arrival = float(self._base_t[i]), float(self._arrival[i])
        b0, b1 = float(self._base_mm[i, 0]), float(self._base_mm[i, 1])
        hold = int(self.mode[i]) == MODE_HOLD
        g0, g1 = (float(x) for x in (self.goal_cmd_mm[i] if hold else self.stow_strokes_mm[i]))
        if not all(math.isfinite(x) for x in (b0, b1, g0, g1)):
            return False
        tr = v * (t - tb)
        p0, p1 = b0 + min(max(g0 - b0, -tr), tr), b1 + min(max(g1 - b1, -tr), tr)
        q0, q1 = b0, b1  # strokes at the start of the last clock step
        if tb < t0:
            tr0 = v * (t0 - tb)
            q0, q1 = b0 + min(max(g0 - b0, -tr0), tr0), b1 + min(max(g1 - b1, -tr0), tr0)
        a = self._base_approach[i]
        approach = (_sign_of(p0 - q0, p0 - b0, float(a[0])), _sign_of(p1 - q1, p1 - b1, float(a[1])))
        state = int(self._base_state[i])
        arrived = max(abs(g0 - p0), abs(g1 - p1)) < _ARRIVED_MM
        if arrived and state == S.MOVING and not math.isfinite(arrival):
            arrival = tb + max(abs(g0 - b0), abs(g1 - b1)) / v
        if not self.offline[i] and state not in (S.FAULT, S.IDLE):
            if arrived and t >= arrival + self.settle_s:
                state = int(S.HOLDING if hold else S.STOWED)
            elif not arrived:
                state = int(S.MOVING)
        self._base_t[i], self._base_mm[i], self._base_state[i] = t, (p0, p1), state
        self._base_approach[i], self._arrival[i] = approach, arrival
        if state != S.MOVING:
            self._pending.discard(i)
        return True

    def _sync(self, rows: np.ndarray) -> None:
        """Re-base ``rows`` (distinct indices) at plant time now (a row at rest stays as it is)."""
        if rows.size == 1:  # one heliostat (a status, a measured beam): decided without arrays
            i = int(rows[0])
            if self._base_t[i] >= self.t_s or (self.mode[i] != MODE_TRACK and int(self._base_state[i]) in _AT_REST):
                return
            if int(self.mode[i]) in (MODE_HOLD, MODE_STOW) and self._sync_fixed_one(i):
                return
        else:
            rows = rows[(self._base_t[rows] < self.t_s)
                        & ((self.mode[rows] == MODE_TRACK) | ~np.isin(self._base_state[rows], _AT_REST_ARRAY))]
            if not rows.size:
                return
        pos, state, approach, arrival = self._eval(rows)
        self._base_t[rows] = self.t_s
        self._base_mm[rows] = pos
        self._base_state[rows] = state
        self._base_approach[rows] = approach
        self._arrival[rows] = arrival
        if self._pending:
            self._pending.difference_update(rows[state != S.MOVING].tolist())

    def _sync_all(self) -> None:
        if self._synced_t != self.t_s:
            self._sync(np.arange(self.n))
            self._synced_t = self.t_s

    # -- time ------------------------------------------------------------------------------------
    def advance_to(self, t_s: float) -> None:
        """Move plant time to ``t_s`` [UTC s]: in clock steps of ≤ ``MAX_STEP_S`` as the stepped
        plant, each checking only the wind (stow) and the sun crossing the horizon."""
        t_s = float(t_s)
        while self.t_s < t_s:
            t1 = min(t_s, self.t_s + MAX_STEP_S)
            up = self.sun(t1)[1] > 0.0
            if up != self._sun_up:  # the tracking goal jumps (stow strokes at night): re-base at the step's start
                self._sync(np.flatnonzero(self.mode == MODE_TRACK))
                self._sun_up = up
            self._check_wind(t1)
            self._step_start_s = self.t_s
            self.t_s = t1

    # -- commands --------------------------------------------------------------------------------
    def _start(self, sel: np.ndarray, mode: int) -> None:
        idx = np.flatnonzero(sel) if np.asarray(sel).dtype == bool else np.asarray(sel, dtype=np.int64)
        self._sync(idx)
        self._base_t[idx] = self.t_s
        self.mode[idx] = mode
        self._base_state[idx] = int(S.MOVING)
        self._arrival[idx] = np.nan
        self.command_count[idx] += 1
        self.stroke_noise_mm[idx] = self.truth.repeat_noise_mm(self.command_count[idx], idx)
        self._pending.update(idx.tolist())
        if mode == MODE_STOW and self.stow_active and idx.size:
            travel_s = np.max(np.abs(self.stow_strokes_mm[idx] - self._base_mm[idx]), axis=-1) / self.speed_mm_s
            self._stow_done_s = max(self._stow_done_s, float(np.max(self.t_s + travel_s)) + self.settle_s)
            self._stow_start_s = self.t_s

    def _process(self, i: int) -> None:
        self._sync(np.array([i]))  # the motion so far, before the command's registers change its goal
        super()._process(i)

    def track_many(self, indices, corrections_mm: np.ndarray) -> np.ndarray:
        idx = np.unique(np.asarray(indices, dtype=np.int64).reshape(-1))
        self._sync(idx[~self.offline[idx]])
        return super().track_many(indices, corrections_mm)

    def _resume_field(self) -> None:
        self._stow_done_s = self._stow_start_s = -np.inf
        super()._resume_field()

    def _halt(self, i: int) -> None:
        self._sync(np.array([i]))
        self._base_t[i] = self.t_s
        self._base_state[i] = int(S.FAULT)
        self.mode[i] = MODE_IDLE
        self._pending.discard(int(i))

    def field_state(self) -> FieldState:
        """TRACKING, or during a stow STOWED once every online heliostat has settled at its stow
        strokes (known when the stow began: no heliostat is read)."""
        if not self.stow_active:
            return FieldState.TRACKING
        done = self.t_s > self._stow_start_s and self.t_s >= self._stow_done_s
        return FieldState.STOWED if done else FieldState.STOWING

    # -- reads -----------------------------------------------------------------------------------
    def status(self, index: int) -> HeliostatStatus:
        i = int(index)
        self._sync(np.array([i]))
        return HeliostatStatus(
            index=i, state=HeliostatState(int(self._base_state[i])), sequence_done=int(self.sequence_done[i]),
            fault=int(self.fault[i]), strokes_mm=(float(self._base_mm[i, 0]), float(self._base_mm[i, 1])),
            cleanliness=self.cleanliness_of(i),
        )

    def moving_rows(self) -> np.ndarray:
        """Indices (ascending) of the heliostats MOVING now: only those that began a motion are read."""
        if not self._pending:
            return np.zeros(0, dtype=np.int64)
        rows = np.array(sorted(self._pending), dtype=np.int64)
        self._sync(rows)
        return rows[self._base_state[rows] == S.MOVING]

    def true_beams_of(self, rows: np.ndarray, t_s: float | None = None, jitter: bool = True) -> TrueBeam:
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        self._sync(rows if rows.size == 1 else np.unique(rows))
        t = self.t_s if t_s is None else float(t_s)
        sun, _ = self.sun(t)
        wind = float(self.weather_model.wind_ms(t))
        return self.truth.beam_of_rows(rows, self._base_mm[rows], sun, t, wind, self._base_approach[rows],
                                       self.stroke_noise_mm[rows], jitter)

    state = property(lambda self: self._synced("_base_state"),
                     doc="State (N,) of every heliostat now (the field brought up to now).")
    strokes_mm = property(lambda self: self._synced("_base_mm"), doc="Encoder strokes (N, 2) of every heliostat now [mm].")
    approach = property(lambda self: self._synced("_base_approach"), doc="Sign (N, 2) of each actuator's last motion now.")
    arrival_s = property(lambda self: self._synced("_arrival"),
                         doc="Plant time (N,) each heliostat's last motion arrived (NaN: not yet; −inf: none since the start).")

    def _synced(self, name: str) -> np.ndarray:
        """The whole-field array ``name``, every heliostat brought up to now (the array itself: writes land in the base)."""
        self._sync_all()
        return getattr(self, name)
