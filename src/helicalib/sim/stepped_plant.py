"""``SteppedPlant``: the in-process simulated plant's reference motion (implements ``devices.protocols.Plant``).

One state machine per heliostat, vectorised over the field (``PLANT_INTERFACE.md``): commands
act on a new sequence number; actuators travel at a finite speed, then settle (MOVING → HOLDING /
STOWED); stroke commands outside the range are refused (FAULT, code 1); during a field or wind
stow every command but stow is refused (code 2); unknown commands give code 3 (state unchanged);
offline heliostats never answer. Tracking = the *nominal* model's strokes for the aim point plus
the written corrections. Nothing reads the wall clock: plant time moves by :meth:`advance_to`.

Two motions, one behaviour (:class:`~helicalib.sim.plant.SimulatedPlant` builds either):
``lazy=True`` (the default) is the closed-form :class:`~helicalib.sim.lazy_plant.LazyPlant`, a
subclass of this one whose heliostats are computed when read; ``lazy=False`` is this module's
reference, which steps every heliostat at every clock advance (≤ ``MAX_STEP_S``).
"""

from __future__ import annotations

import numpy as np

from helicalib.devices.protocols import HeliostatStatus, Weather
from helicalib.devices.registers import (
    FaultCode,
    FieldCommand,
    FieldState,
    HeliostatCommand,
    HeliostatState,
)
from helicalib.geometry.drives import strokes_in_range
from helicalib.geometry.sun import SunTable
from helicalib.sim.scenario import Scenario
from helicalib.sim.soiling import SoilingModel
from helicalib.sim.truth import TrueBeam, TrueField
from helicalib.sim.weather import WeatherModel

S = HeliostatState
MODE_IDLE, MODE_TRACK, MODE_HOLD, MODE_STOW = 0, 1, 3, 4
MAX_STEP_S = 300.0
"""Longest internal step of :meth:`SteppedPlant.advance_to` (tracking goals follow the sun)."""
WIND_RELEASE_MS = 3.0
"""A wind stow ends when the wind falls this far below ``gating.stow_wind_ms``."""
TRACK_GRID_S = 60.0
"""Tracking goals: the nominal strokes of the whole field are solved on this plant-time grid and
interpolated linearly in between (the strokes turn with the sun, ≈ 0.04 mm/s at most; the chord
error over 60 s is ≈ 1e-3 mm, a few µrad — far below what any measurement resolves)."""
_TRACK_NODES_KEPT = 8


class SteppedPlant:
    """A simulated tower plant with hidden true errors, weather, soiling and finite-speed drives.

    Parameters
    ----------
    cfg : config.FieldConfig
    scenario : Scenario
    start_s : float
        Initial plant time [UTC s].
    rate : float
        Plant time rate reported at registers 12-13 (1.0 in-process; the server sets its own).
    zero_errors : bool
        A perfect field (no hidden errors or unmodelled effects) — for checks of the nominal model.
    """

    def __init__(self, cfg, scenario: Scenario | None = None, start_s: float = 0.0, rate: float = 1.0,
                 zero_errors: bool = False):
        self.cfg = cfg
        self.scenario = scenario or Scenario()
        self.rate = float(rate)
        self.t_s = float(start_s)
        self.truth = TrueField(cfg, self.scenario, start_s, zero=zero_errors)
        self.nominal = self.truth.nominal
        self.weather_model = WeatherModel(self.scenario.weather, cfg.site, self.scenario.seed)
        n = len(self.nominal)
        self.n = n
        self.soiling = SoilingModel(self.scenario.soiling, n, self.scenario.seed)
        self.targets = [cfg.target(h.target) for h in cfg.heliostats]
        if self.scenario.tracking_aim == "target":
            aim = np.array([t.center_enu_m for t in self.targets], dtype=float)
        else:
            aim = np.broadcast_to(np.asarray(cfg.tower.receiver_aim_enu_m, dtype=float), (n, 3)).copy()
        self.tracking_aim_enu = aim
        d = self.nominal.drives
        self.speed_mm_s = self.scenario.actuators.speed_mm_s
        self.settle_s = self.scenario.actuators.settle_s
        self.stow_strokes_mm = self._stow_strokes()
        ids = [h.id for h in cfg.heliostats]
        self.offline = np.array([i in set(self.scenario.faults.offline) for i in ids], dtype=bool)
        # written (command) registers
        self.reg_command = np.zeros(n, dtype=np.int64)
        self.reg_sequence = np.zeros(n, dtype=np.int64)
        self.reg_strokes_cmd = np.zeros((n, 2))
        self.reg_corrections = np.zeros((n, 2))
        # state
        self.mode = np.full(n, MODE_TRACK, dtype=np.int64)
        self.sequence_done = np.zeros(n, dtype=np.int64)
        self.fault = np.zeros(n, dtype=np.int64)
        self.corrections_mm = np.zeros((n, 2))
        self.goal_cmd_mm = np.zeros((n, 2))
        self.command_count = np.zeros(n, dtype=np.int64)
        self.stroke_noise_mm = np.zeros((n, 2))
        self.field_stow = False
        self.wind_stow = False
        self._sun_cache: tuple[float, np.ndarray, float] | None = None
        self._sun_table = SunTable(cfg.site)
        self._track_nodes: dict[int, np.ndarray] = {}
        self._node_rows: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._cleanliness_cache: tuple[float, int, np.ndarray] | None = None
        self._weather_cache: tuple[float, Weather] | None = None
        self._drange = (d.stroke_min_mm, d.stroke_max_mm)
        self._init_motion()
        self.mode[self.offline] = MODE_IDLE

    def _init_motion(self) -> None:
        """Every heliostat tracking from the start (offline ones still, where tracking put them)."""
        self.state = np.full(self.n, int(S.TRACKING), dtype=np.int64)
        self.arrival_s = np.full(self.n, -np.inf)
        self.approach = np.ones((self.n, 2))
        self.strokes_mm = self._goal(self.t_s)
        self.state[self.offline] = int(S.OFFLINE)

    # -- helpers ---------------------------------------------------------------------------
    def _stow_strokes(self) -> np.ndarray:
        """Strokes that point each mirror up (clipped into range; mid-range if unreachable)."""
        up = np.broadcast_to([0.0, 0.0, 1.0], (self.n, 3))
        s, _, _ = self.nominal.normal_to_strokes(up)
        d = self.nominal.drives
        mid = 0.5 * (d.stroke_min_mm + d.stroke_max_mm)
        return np.clip(np.where(np.isfinite(s), s, mid), d.stroke_min_mm, d.stroke_max_mm)

    def sun(self, t_s: float) -> tuple[np.ndarray, float]:
        """(sun vector ENU (3,), elevation [deg]) at ``t_s`` (NREL SPA tabulated by
        :class:`~helicalib.geometry.sun.SunTable`, 0.003 mrad; cached per instant)."""
        if self._sun_cache is None or self._sun_cache[0] != t_s:
            vec = self._sun_table.vector_enu(float(t_s))
            elevation = float(np.degrees(np.arcsin(np.clip(vec[2], -1.0, 1.0))))
            self._sun_cache = (t_s, vec, elevation)
        return self._sun_cache[1], self._sun_cache[2]

    def _track_node(self, k: int) -> np.ndarray:
        """Nominal strokes (N, 2) of every heliostat for its tracking aim at grid node ``k`` (no corrections)."""
        node = self._track_nodes.get(k)
        if node is None:
            sun = self._sun_table.vector_enu(k * TRACK_GRID_S)
            node = self.nominal.strokes_for_aim(sun, self.tracking_aim_enu).strokes_mm
            if len(self._track_nodes) >= _TRACK_NODES_KEPT:
                self._track_nodes.pop(next(iter(self._track_nodes)))
            self._track_nodes[k] = node
        return node

    def _nominal_tracking(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Nominal tracking strokes (N, 2) of every heliostat at ``t_s``, interpolated on the grid
        (a new array), and which rows are finite (both grid nodes reachable)."""
        x = t_s / TRACK_GRID_S
        k = int(np.floor(x))
        f = x - k
        a = self._track_node(k)
        if f == 0.0:
            return a.copy(), self._node_finite(k)
        b = self._track_node(k + 1)
        return a + (b - a) * f, self._node_finite(k) & self._node_finite(k + 1)

    def _node_finite(self, k: int) -> np.ndarray:
        """Rows (N,) of grid node ``k`` with finite strokes (cached with the node)."""
        node = self._track_node(k)
        hit = self._node_rows.get(k)
        if hit is None or hit[0] is not node:
            hit = self._node_rows[k] = (node, np.all(np.isfinite(node), axis=-1))
            if len(self._node_rows) > _TRACK_NODES_KEPT:
                self._node_rows.pop(next(iter(self._node_rows)))
        return hit[1]

    def _tracking_strokes(self, t_s: float, sel: np.ndarray) -> np.ndarray:
        """Tracking strokes (N, 2) at ``t_s`` for the heliostats ``sel`` (bool (N,)); other rows
        are computed alike but not meant to be used. Row by row the arithmetic of one heliostat."""
        sun, elevation = self.sun(t_s)
        if elevation <= 0.0:
            return self.stow_strokes_mm
        nom, finite = self._nominal_tracking(t_s)
        sub = np.flatnonzero(sel & ~finite)
        if sub.size:  # a grid node unreachable: solve those heliostats at this instant
            nom[sub] = self.nominal.subset(sub).strokes_for_aim(sun, self.tracking_aim_enu[sub]).strokes_mm
        s = nom + self.corrections_mm
        s = np.clip(s, self._drange[0], self._drange[1])
        return np.where(np.isfinite(s), s, self.stow_strokes_mm)

    def _goal(self, t_s: float) -> np.ndarray:
        strokes = getattr(self, "strokes_mm", self.stow_strokes_mm)
        track = self.mode == MODE_TRACK
        hold = self.mode == MODE_HOLD
        stow = self.mode == MODE_STOW
        goal = np.where(hold[:, None], self.goal_cmd_mm, np.where(stow[:, None], self.stow_strokes_mm, strokes))
        if track.any():
            goal = np.where(track[:, None], self._tracking_strokes(t_s, track), goal)
        return goal

    # -- time ------------------------------------------------------------------------------
    def advance_to(self, t_s: float) -> None:
        """Move plant time to ``t_s`` [UTC s]: actuators travel, settle; wind stow starts/ends."""
        t_s = float(t_s)
        while self.t_s < t_s:
            t_next = min(t_s, self.t_s + MAX_STEP_S)
            self._step(t_next)

    def _step(self, t1: float) -> None:
        t0 = self.t_s
        dt = t1 - t0
        self._check_wind(t1)
        goal = self._goal(t1)
        delta = goal - self.strokes_mm
        travel = self.speed_mm_s * dt
        move = np.clip(delta, -travel, travel)
        moving = np.abs(move) > 1e-9
        self.approach = np.where(moving, np.sign(move), self.approach)
        self.strokes_mm = self.strokes_mm + move
        # the state machine, on the rows whose state can change: moving, or held or stowed (a
        # heliostat tracking on course only follows the sun, above)
        w = np.flatnonzero((self.state == S.MOVING) | (self.mode == MODE_HOLD) | (self.mode == MODE_STOW))
        if not w.size:
            self.t_s = t1
            return
        state, mode = self.state[w], self.mode[w]
        remaining = np.max(np.abs(goal[w] - self.strokes_mm[w]), axis=-1)
        arrived = remaining < 1e-6
        was_moving = state == S.MOVING
        arrival = self.arrival_s[w]
        newly = arrived & was_moving & ~np.isfinite(arrival)
        arrival = np.where(newly, t0 + np.max(np.abs(delta[w]), axis=-1) / self.speed_mm_s, arrival)
        self.arrival_s[w] = arrival
        settled = arrived & (t1 >= arrival + self.settle_s)
        active = ~self.offline[w] & (state != S.FAULT) & (state != S.IDLE)
        new = state.copy()
        for m, done_state in ((MODE_HOLD, S.HOLDING), (MODE_STOW, S.STOWED), (MODE_TRACK, S.TRACKING)):
            sel = active & (mode == m)
            if m == MODE_TRACK:  # tracking heliostats follow the sun; TRACKING once first on track
                new[sel & was_moving & arrived] = int(done_state)
            else:
                new[sel & settled] = int(done_state)
                new[sel & ~arrived] = int(S.MOVING)
        self.state[w] = new
        self.t_s = t1

    def _check_wind(self, t_s: float) -> None:
        wind = float(self.weather_model.wind_ms(t_s))
        limit = self.cfg.gating.stow_wind_ms
        if not self.wind_stow and wind >= limit:
            self.wind_stow = True
            self._stow_field()
        elif self.wind_stow and wind < limit - WIND_RELEASE_MS:
            self.wind_stow = False
            if not self.field_stow:
                self._resume_field()

    # -- field -----------------------------------------------------------------------------
    def _stow_field(self) -> None:
        sel = ~self.offline
        self._start(sel, MODE_STOW)

    def _resume_field(self) -> None:
        sel = ~self.offline
        self.fault[sel] = 0
        self._start(sel, MODE_TRACK)

    def _start(self, sel: np.ndarray, mode: int) -> None:
        """Begin a new motion of the heliostats ``sel`` (bool mask, or distinct indices) in ``mode``."""
        idx = np.flatnonzero(sel) if np.asarray(sel).dtype == bool else np.asarray(sel, dtype=np.int64)
        self.mode[idx] = mode
        self.state[idx] = int(S.MOVING)
        self.arrival_s[idx] = np.nan  # not arrived yet
        self.command_count[idx] += 1
        self.stroke_noise_mm[idx] = self.truth.repeat_noise_mm(self.command_count[idx], idx)

    @property
    def stow_active(self) -> bool:
        return self.field_stow or self.wind_stow

    def field_state(self) -> FieldState:
        if not self.stow_active:
            return FieldState.TRACKING
        on = ~self.offline
        return FieldState.STOWED if np.all(self.state[on] == S.STOWED) else FieldState.STOWING

    def field_command(self, command: int) -> None:
        """Field command register (3): 1 stow all, 2 resume tracking all (refused during a wind stow)."""
        if command == FieldCommand.STOW_ALL:
            self.field_stow = True
            self._stow_field()
        elif command == FieldCommand.RESUME_TRACKING:
            self.field_stow = False
            if not self.wind_stow:
                self._resume_field()

    # -- heliostat commands ------------------------------------------------------------------
    def write_command(self, index: int, command: int, sequence: int, strokes_mm=None, corrections_mm=None) -> None:
        """Write a heliostat's command registers, then its sequence number (acted on if it changed)."""
        self.reg_command[index] = int(command)
        if strokes_mm is not None:
            self.reg_strokes_cmd[index] = np.asarray(strokes_mm, dtype=float)
        if corrections_mm is not None:
            self.reg_corrections[index] = np.asarray(corrections_mm, dtype=float)
        self.write_sequence(index, sequence)

    def write_sequence(self, index: int, sequence: int) -> None:
        """Sequence register written: act on the command registers if the number changed."""
        sequence = int(sequence) & 0xFFFF
        changed = sequence != self.reg_sequence[index]
        self.reg_sequence[index] = sequence
        if changed and not self.offline[index]:
            self._process(index)

    def _process(self, i: int) -> None:
        cmd, seq = int(self.reg_command[i]), int(self.reg_sequence[i])
        sel = np.array([i])  # one row: a command costs the same on a field of 10⁴
        self.sequence_done[i] = seq
        if cmd == HeliostatCommand.NONE:
            return
        if cmd not in (HeliostatCommand.TRACK, HeliostatCommand.MOVE, HeliostatCommand.STOW):
            self.fault[i] = FaultCode.UNKNOWN_COMMAND
            return
        if self.stow_active and cmd != HeliostatCommand.STOW:
            self.fault[i] = FaultCode.REFUSED_DURING_STOW
            return
        if cmd == HeliostatCommand.MOVE:
            s = self.reg_strokes_cmd[i]
            ok = bool(np.all(strokes_in_range(self.nominal.drives.take([i]), s[None, :])))
            if not ok:
                self.fault[i] = FaultCode.STROKE_OUT_OF_RANGE
                self._halt(i)
                return
            self.goal_cmd_mm[i] = s
            self.fault[i] = FaultCode.NONE
            self._start(sel, MODE_HOLD)
        elif cmd == HeliostatCommand.TRACK:
            self.corrections_mm[i] = self.reg_corrections[i]
            self.fault[i] = FaultCode.NONE
            self._start(sel, MODE_TRACK)
        else:
            self.fault[i] = FaultCode.NONE
            self._start(sel, MODE_STOW)

    def _halt(self, i: int) -> None:
        """Heliostat ``i`` stops where it is, in FAULT (a refused stroke command)."""
        self.state[i] = int(S.FAULT)
        self.mode[i] = MODE_IDLE

    def _next_sequence(self, index: int) -> int:
        return (int(self.reg_sequence[index]) + 1) & 0xFFFF

    # -- Plant protocol --------------------------------------------------------------------
    def heliostat_count(self) -> int:
        return self.n

    def plant_time(self) -> tuple[float, float]:
        return self.t_s, self.rate

    def weather(self) -> Weather:
        """The weather block now (a frozen reading, kept for the instant: a visit reads it several times)."""
        hit = self._weather_cache
        if hit is None or hit[0] != self.t_s:
            _, elevation = self.sun(self.t_s)
            hit = self._weather_cache = (self.t_s, self.weather_model.at(self.t_s, elevation))
        return hit[1]

    def status(self, index: int) -> HeliostatStatus:
        return HeliostatStatus(
            index=int(index), state=HeliostatState(int(self.state[index])),
            sequence_done=int(self.sequence_done[index]), fault=int(self.fault[index]),
            strokes_mm=(float(self.strokes_mm[index, 0]), float(self.strokes_mm[index, 1])),
            cleanliness=self.cleanliness_of(index),
        )

    def cleanliness(self) -> np.ndarray:
        """Cleanliness (N,) of every mirror now (cached per plant instant; status() asks per heliostat)."""
        key = (self.t_s, len(self.soiling._extra_cleanings))
        c = self._cleanliness_cache
        if c is None or c[:2] != key:
            c = (*key, self.soiling.cleanliness(self.t_s))
            self._cleanliness_cache = c
        return c[2]

    def cleanliness_of(self, index: int) -> float:
        """Cleanliness of one mirror now: ``cleanliness()[index]``, at the cost of one heliostat."""
        c = self._cleanliness_cache
        if c is not None and c[:2] == (self.t_s, len(self.soiling._extra_cleanings)):
            return float(c[2][index])
        return float(self.soiling.cleanliness(self.t_s, rows=np.array([int(index)]))[0])

    def cleanliness_many(self, indices) -> np.ndarray:
        """The cleanliness registers of heliostats ``indices`` (k,) now, in one read: what
        :meth:`status` gives for each (the planner reads a board's candidates at once)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        c = self._cleanliness_cache
        if c is not None and c[:2] == (self.t_s, len(self.soiling._extra_cleanings)):
            return c[2][idx].astype(float)
        return self.soiling.cleanliness(self.t_s, rows=idx)

    def move_to(self, index: int, strokes_mm: np.ndarray) -> int:
        seq = self._next_sequence(index)
        self.write_command(index, HeliostatCommand.MOVE, seq, strokes_mm=strokes_mm)
        return seq

    def track(self, index: int, corrections_mm: np.ndarray) -> int:
        seq = self._next_sequence(index)
        self.write_command(index, HeliostatCommand.TRACK, seq, corrections_mm=corrections_mm)
        return seq

    def track_many(self, indices, corrections_mm: np.ndarray) -> np.ndarray:
        """:meth:`track` for many heliostats at once (distinct ``indices`` (k,), ``corrections_mm``
        (k, 2)): the same registers and state as one call per heliostat in any order, at the cost
        of array operations (the runner rewrites the corrections of a whole field every 15 min).
        Returns the sequence numbers (k,)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if np.unique(idx).size != idx.size:
            raise ValueError("track_many: indices must be distinct")
        seq = (self.reg_sequence[idx] + 1) & 0xFFFF
        self.reg_command[idx] = int(HeliostatCommand.TRACK)
        self.reg_corrections[idx] = np.asarray(corrections_mm, dtype=float).reshape(-1, 2)
        self.reg_sequence[idx] = seq  # always a new number: each acted on (offline ones never answer)
        on = idx[~self.offline[idx]]
        self.sequence_done[on] = self.reg_sequence[on]
        if self.stow_active:
            self.fault[on] = FaultCode.REFUSED_DURING_STOW
            return seq
        self.corrections_mm[on] = self.reg_corrections[on]
        self.fault[on] = FaultCode.NONE
        self._start(on, MODE_TRACK)
        return seq

    def stow(self, index: int) -> int:
        seq = self._next_sequence(index)
        self.write_command(index, HeliostatCommand.STOW, seq)
        return seq

    # -- truth (not part of the interface) ------------------------------------------------
    def true_beams(self, t_s: float | None = None, jitter: bool = True) -> TrueBeam:
        """True beams of every heliostat at its current strokes (at plant time ``t_s``, default now)."""
        t = self.t_s if t_s is None else float(t_s)
        sun, _ = self.sun(t)
        wind = float(self.weather_model.wind_ms(t))
        return self.truth.beam(self.strokes_mm, sun, t, wind, self.approach, self.stroke_noise_mm, jitter)

    def true_beam_of(self, index: int, t_s: float | None = None, jitter: bool = True) -> TrueBeam:
        """The true beam of one heliostat (arrays of one row): what :meth:`true_beams` gives for its
        row, at the cost of one heliostat (a field of 10⁴ is not recomputed per measurement)."""
        return self.true_beams_of(np.array([int(index)]), t_s, jitter)

    def true_beams_of(self, rows: np.ndarray, t_s: float | None = None, jitter: bool = True) -> TrueBeam:
        """The true beams of heliostats ``rows`` (k,): :meth:`true_beams`' rows, for the cost of k."""
        t = self.t_s if t_s is None else float(t_s)
        sun, _ = self.sun(t)
        wind = float(self.weather_model.wind_ms(t))
        return self.truth.beam(self.strokes_mm, sun, t, wind, self.approach, self.stroke_noise_mm, jitter,
                               rows=np.asarray(rows, dtype=np.int64))

    def moving_rows(self) -> np.ndarray:
        """Indices (ascending) of the heliostats MOVING now."""
        return np.flatnonzero(self.state == S.MOVING)

    def true_tracking_error_mrad(self, aim_enu: np.ndarray | None = None, jitter: bool = False) -> np.ndarray:
        """True tracking error (N,) [mrad] against ``aim_enu`` (N, 3) (default each target's centre),
        NaN for heliostats that are not HOLDING (a measurement belongs to held strokes)."""
        aim = np.array([t.center_enu_m for t in self.targets]) if aim_enu is None else np.asarray(aim_enu)
        err = self.truth.tracking_error_mrad(self.true_beams(jitter=jitter), aim, self.targets)
        return np.where(self.state == S.HOLDING, err, np.nan)
