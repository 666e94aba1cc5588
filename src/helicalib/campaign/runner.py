"""The campaign runner: weather polling, stow, gating, planning and visits on the plant clock.

One :class:`CampaignRunner` drives the same campaign core in every place it runs:

* in-process on a virtual clock (``helicalib simulate``): :meth:`run_until` jumps plant time
  from event to event, so days pass in seconds;
* against a plant over Modbus TCP + HTTP (``helicalib simulate --over-network``, ``helicalib run``):
  the same :meth:`tick` is called by APScheduler jobs on the plant clock (see :mod:`.live`).

Visits are generators (:func:`~helicalib.campaign.controller.run_visit`) that yield the plant
seconds they want to wait; the runner steps each when its wake-up time comes. A board serves up to
``spots_per_board`` visits at once, whose beams take turns on it (:mod:`.board`).
Every observation goes to the store as soon as it is made.
"""

from __future__ import annotations

import errno
import math
import sqlite3
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from helicalib.campaign import gating as gating_mod
from helicalib.campaign.operation import rules as op_rules
from helicalib.campaign import policy
from helicalib.campaign.board import AUTO_SPOTS, Board
from helicalib.campaign.operation.checks import OperationChecks
from helicalib.campaign.controller import (
    APPROACH_LEAD_S,
    REQUESTS,
    Corrections,
    Record,
    Refit,
    SaveFrame,
    Left,
    VisitContext,
    VisitOutcome,
    VisitSettings,
    leave_board,
    run_visit,
)
from helicalib.campaign.events import STORED, BoardState, RunEvent, Snapshot
from helicalib.campaign.sensor import SpotSensor, camera_sensors
from helicalib.devices.clock import ClockJumpError
from helicalib.devices.protocols import FieldStowedError, PlantUnreachableError
from helicalib.devices.registers import FieldCommand, HeliostatState
from helicalib.errors import HelicalibError, PlantError, StorageError
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import SunTable
from helicalib.store.records import off_tracking

WEATHER_POLL_S = 60.0
"""Plant seconds between weather polls (a stow follows within one poll)."""
WEATHER_MAX_AGE_S = 3 * WEATHER_POLL_S
"""A weather reading older than this [plant s] opens no gate: calibration waits for a fresh one."""
STORAGE_RETRIES = 5
"""Failed writes to the database or its frames folder (full disk, read-only file or folder), with
no observation stored with its frames between them, after which a live run gives up: every beam leaves its board and goes back to
tracking, and the process exits with :data:`helicalib.app.session.EXIT_STORAGE`."""
CLEANLINESS_MAX_AGE_S = 1800.0
"""The gaps planner re-reads a heliostat's cleanliness register when its last read is this old
[plant s]. Soiling changes over days; a washed mirror counts as clean within half an hour. Re-read
every minute, a 10⁴-heliostat field would cost 10⁴ register reads a minute."""
PLANNER_TICK_S = 30.0
"""Plant seconds between planner ticks while a target is free."""
SHARE_REACH_S = 1800.0
"""A borrowed board must be within the heliostat's stroke range now and this much later [plant s]."""
RETURN_CHECK_S = 10.0
"""Plant seconds after a track command before the plant's state is read to confirm tracking."""
RETURN_RETRY_S = 30.0
"""Plant seconds before the first new attempt to bring back to tracking a heliostat the plant has
not confirmed; the wait doubles with each attempt, up to :data:`RETURN_RETRY_MAX_S`."""
RETURN_RETRY_MAX_S = 600.0
STEADY_TICK_S = 300.0
"""Plant seconds between planner ticks in operation while every heliostat is accepted (checks only)."""

@dataclass
class Returning:
    """A heliostat sent back to tracking whose state 1 the plant has not confirmed yet."""

    since_s: float
    next_check_s: float
    corrections_mm: object = None
    attempts: int = 1
    failed: bool = False
    """True once a return failed (then its confirmation is news: an event says so)."""
    last_error: str = ""

    def retry_at(self, now: float) -> float:
        """When to try again: 30 s after the first attempt, doubling up to 10 min (a heliostat the
        plant reports faulted or offline is not sent a command every 30 s for a night)."""
        return now + min(RETURN_RETRY_S * 2.0 ** max(self.attempts - 1, 0), RETURN_RETRY_MAX_S)


def storage_error(err: BaseException) -> bool:
    """Whether ``err`` says the database or its frames folder cannot be written (full disk,
    read-only file or folder): :class:`~helicalib.errors.StorageError`, SQLite's "full",
    "readonly" or I/O errors, or the system's "no space", "read-only file system", "permission"
    errors. A busy database ("locked") is not."""
    if isinstance(err, StorageError):
        return True
    if isinstance(err, sqlite3.OperationalError):
        text = str(err).lower()
        return any(k in text for k in ("full", "readonly", "read-only", "disk i/o", "unable to open"))
    if isinstance(err, OSError) and not isinstance(err, (ConnectionError, TimeoutError)):
        return err.errno in (errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT)
    return False


@dataclass
class RunningVisit:
    """A visit under way: its generator and when it next wants a step."""

    heliostat_id: str
    target_id: str
    gen: object
    ctx: VisitContext
    wake_s: float


STATS_KEPT = 200_000
"""Visits whose iterations and first placements the runner's statistics keep in memory."""


@dataclass
class RunnerStats:
    visits: int = 0
    valid_visits: int = 0
    gated_s: float = 0.0
    stowed_s: float = 0.0
    night_s: float = 0.0
    # the newest STATS_KEPT of each (a service runs for years; the summaries read the last day)
    iterations: deque = field(default_factory=lambda: deque(maxlen=STATS_KEPT))
    first_errors: deque = field(default_factory=lambda: deque(maxlen=STATS_KEPT))  # (time, mrad, had a model)
    outcomes: dict[str, int] = field(default_factory=dict)
    shared_visits: int = 0
    """Visits that started while another visit was under way on the same board."""
    peak_on_board: int = 0
    """The most visits under way on one board at once."""


class CampaignRunner:
    """Run a calibration campaign on a plant.

    Parameters
    ----------
    cfg : FieldConfig
    plant : Plant protocol implementation
    cameras : dict target id → Camera or SpotSensor
        Each board's camera (measured with :class:`~helicalib.campaign.sensor.CameraSensor`: the
        vision), or a spot sensor of its own (the measurement seam, :mod:`.sensor`).
    clock : Clock protocol (``now_s``, ``sleep``)
    store : helicalib.store.Store
    campaign_id : int
        The campaign (new or resumed) in ``store``.
    heliostat_ids : list of str, optional
        Heliostats to calibrate (default all).
    planner : str
        ``"gaps"`` (fill acceptance gaps fastest), ``"round-robin"`` (the paper's "in turn", each
        heliostat on its own board) or ``"round-robin-shared"`` (in turn over the whole field,
        boards shared as for gaps: a benchmark baseline).
    recheck : bool
        Visit every heliostat once regardless of acceptance (operators' re-check).
    refine : bool
        Gaps planner: spend target time that no acceptance gap asks for on the heliostats whose
        model is most uncertain at the present sun, accepted ones included (asked for; default off).
    armed : bool
        False: read the plant and plan, but write nothing (each decision is recorded as an event).
    operation : str or None
        Year-round operation (:mod:`.operation`): board time no acceptance gap needs goes to checks
        of accepted heliostats, ``"ranked"`` by the expected reduction of the year-round error or on
        a fixed ``"rota"`` (every ``rota_days``); a check outside its fit's band is drift, confirmed
        drift reopens the calibration. None (default): a campaign, no checks.
    spots_per_board : int or "auto"
        Visits under way on one board at once (gaps planner; :mod:`.board`): their beams take turns
        on the board while the others travel to or from it or wait at its standby point. 1
        (default) is one visit at a time; ``"auto"`` is :data:`~.board.AUTO_SPOTS`.
    flux : dict, optional
        Target id → (Fe, atmosphere) of each board's camera for the cleanliness measured from the
        spot (:func:`~.sensor.camera_sensors`; default each camera's FLUX.yaml from the config).
    """

    def __init__(self, cfg, plant, cameras, clock, store, campaign_id, heliostat_ids=None, planner="gaps",
                 recheck=False, model=None, armed=True, refine=False, listeners=(), operation=None,
                 rota_days=14.0, spots_per_board=1, flux=None):
        self.cfg, self.plant, self.cameras, self.clock, self.store = cfg, plant, cameras, clock, store
        # the measurement seam: each board's spot sensor (a camera is wrapped in the camera + vision sensor)
        wrapped = camera_sensors(cfg, {t: c for t, c in cameras.items() if not isinstance(c, SpotSensor)}, flux)
        self.sensors = {t: (c if isinstance(c, SpotSensor) else wrapped[t]) for t, c in cameras.items()}
        self.campaign_id = campaign_id
        self.ids = list(heliostat_ids) if heliostat_ids else [h.id for h in cfg.heliostats]
        self.planner_kind = planner
        self.recheck = recheck
        self.refine = bool(refine) and planner == "gaps"
        self.share = bool(cfg.calibration.share_targets) and planner in ("gaps", "round-robin-shared")
        self._home = {t.id: [hid for hid in self.ids if cfg.heliostat(hid).target == t.id] for t in cfg.targets}
        self._guests = (policy.shared_targets(cfg, self.ids, [t for t in cameras if cfg.cameras_for(t)])
                        if self.share else {})
        self.armed = armed
        self.settings = VisitSettings.from_config(cfg)
        # an operation's checks average more after frames (operation.CHECK_AFTER_FRAMES)
        self.check_settings = replace(self.settings,
                                      after_frames=max(self.settings.after_frames, op_rules.CHECK_AFTER_FRAMES))
        self.sun_table = SunTable(cfg.site)
        base = model if model is not None else HeliostatModel.from_config(cfg, self.ids)
        self.nominal = HeliostatModel.from_config(cfg, self.ids)
        self.models: dict[str, HeliostatModel] = {hid: base.subset([i]) for i, hid in enumerate(self.ids)}
        self._index = {hid: i for i, hid in enumerate(self.ids)}
        self._plant_index = np.array([cfg.heliostat_index(hid) for hid in self.ids], dtype=np.int64)
        self.book = policy.Book(cfg, self.ids)
        self.book.table.set_guests(self._guests)
        self.stats = RunnerStats()
        self.active: dict[str, RunningVisit] = {}
        """Visits under way, by heliostat id."""
        if spots_per_board not in (None, "auto") and int(spots_per_board) < 1:
            raise ValueError(f"spots per board: {spots_per_board} (at least 1, or 'auto')")
        self.spots_per_board = "auto" if spots_per_board in (None, "auto") else int(spots_per_board)
        # several visits per board with the gaps planner (the round robins are the paper's baselines)
        cap = (AUTO_SPOTS if self.spots_per_board == "auto" else self.spots_per_board) if planner == "gaps" else 1
        self.boards: dict[str, Board] = {t.id: Board(t.id, cap=cap) for t in cfg.targets}
        self.stowed = False
        self.last_weather = None
        self.last_poll_s = -math.inf
        self._gate_reason = None
        self.last_refresh_s = -math.inf
        self._nominal_one: dict[str, HeliostatModel] = {}
        self._clean_cache: dict[str, tuple[float, float | None]] = {}
        self._clean_rows = (np.full(len(self.ids), np.nan), np.full(len(self.ids), -math.inf))  # values, read at
        self.corrections: dict[str, np.ndarray | None] = {hid: None for hid in self.ids}
        self.listeners: list[Callable[[RunEvent], None]] = list(listeners)
        """Called with every :class:`RunEvent` after the fact (views, JSON lines); a listener that
        raises is dropped from the call, never allowed to stop the campaign."""
        self.stopping = False
        """Set by a live run's stop: jobs still queued do nothing more."""
        self.returning: dict[str, Returning] = {}
        self._flagged: set[str] = set()  # newest stored off_tracking not yet followed by back_to_tracking
        self._boards: dict[str, BoardState] = {}
        self._band_cache: tuple[float, str] = (-math.inf, "")
        self._last_gate = None
        self.plant_unreachable_since_s: float | None = None
        """Plant time (the controller's estimate) since which the plant has not answered (its clock or
        weather could not be read); None while it answers. No visit starts meanwhile."""
        self._lost_links: dict[str, float] = {}
        """Each link that does not answer (``"scs"``: the plant's clock and commands, ``"weather"``) and
        since when; a link is back only when a read over that same link succeeds."""
        self.state_lock = threading.RLock()
        """Held while the tick's thread or the weather job changes state both read (stowed, the last
        poll, the plant's reachability, the storage and clock faults); never across a device's reply."""
        self.weather_time_s: float | None = None
        """Plant time of the weather reading behind :attr:`last_weather`."""
        self._said_lost: set[str] = set()  # jobs that said the plant failed them during this loss
        self.job_fault: dict[str, str] = {}
        """Each job's last fault line (:meth:`job_failed`), until the job succeeds."""
        self._weather_lock = threading.Lock()  # one weather poll at a time (the tick's or the weather job's)
        self.clock_jump: str | None = None
        """Set (one line) when the plant's clock jumped (backwards, or forwards beyond where it can be)
        during the run: no visit starts and a live run stops (:mod:`.live`)."""
        self.clock_jump_hint = "; to go on from the plant's time, restart with --accept-clock-jump"
        """What the clock-jump line tells the crew to do after checking the plant's clock (a command
        without that option, ``check``, sets it empty)."""
        self.storage_errors = 0
        """Failed writes to the database or its frames folder with no observation stored with its
        frames since (a fault line the database takes is no proof that frames can be written)."""
        self._storage_fault = False  # the storage's fault line is being written (its own failure is the same one)
        self.storage_lost: str | None = None
        """Set (one line) after :data:`STORAGE_RETRIES` failed writes in a row: a live run stops."""
        self.operator = None  # operator actions: a campaign.operator.OperatorDesk (armed live runs: console.server)
        if operation is not None and operation not in op_rules.OPERATION_MODES:
            raise ValueError(f"operation {operation!r}: choose one of {', '.join(op_rules.OPERATION_MODES)}")
        self.operation = operation if planner == "gaps" else None
        self.ops = OperationChecks(self, self.operation, rota_days)
        """Operation's checks and drift detection (:mod:`.checks`)."""
        self.retention: tuple[int, bool] | None = None
        """(keep_last, keep_invalid): every night the frames of all but each heliostat's newest
        ``keep_last`` observations (and, with keep_invalid, the rejected ones) are deleted
        (:func:`helicalib.store.retention.retain_frames`); None keeps every frame."""
        self._retained_day: int | None = None
        self._resume_from_store()

    # ------------------------------------------------------------------ state from the store
    def _resume_from_store(self) -> None:
        """Rebuild the campaign's state after a restart (also after kill -9).

        Valid points, visit counts, fits and verdicts come from the store (a heliostat without a fit
        in this campaign starts from its newest fit of any earlier one); visits a killed process
        left open are closed as 'interrupted' and their heliostats sent back to tracking; a field
        the plant reports stowed stays stowed until the wind allows a resume.
        """
        now = self.clock.now_s()
        epochs = self.ops.load_drifts()
        stored = policy.stored_epochs(self.store, self.campaign_id) if epochs else {}
        for hid in self.ids:
            self.book.h[hid].drifted = hid in epochs  # its book under the cap after a drift
            observations = self.store.observations(campaign_id=self.campaign_id, heliostat_id=hid)
            for obs in observations:
                if obs.capture_time_s >= epochs.get(hid, -math.inf):
                    self.book.add(obs)
            if hid in epochs:  # the points before its drifts (after its newest repair), for the fits
                ep = stored.get(hid, policy.NO_EPOCH)
                self.book.h[hid].earlier = policy.earlier_points(observations, ep.floor_s, ep.boundaries)
            visits = self.store.visits(campaign_id=self.campaign_id, heliostat_id=hid)
            self.book.h[hid].visits = len(visits)
            if visits:
                self.book.h[hid].last_visit_s = max(v.started_s for v in visits)
            fit = self.store.latest_fit(hid, campaign_id=self.campaign_id) or self.store.latest_fit(hid)
            if fit is not None:
                self.models[hid] = policy.model_from_fit(self.models[hid], fit)
            if self.book.points(hid):  # the fit's covariance (planner) and linearisation (verdict)
                _model, self.book.h[hid].fit = policy.refit(self.nominal_of(hid), self.book.points(hid),
                                                            self.models[hid], prior_mean=self.ops.prior_mean(hid),
                                                            tilt_rate=self.ops.tilt_rate_of(hid),
                                                            earlier=self.book.h[hid].earlier)
            if visits:
                self.book.set_verdict(hid, policy.verdict(self.cfg, self.book, hid, self.nominal_of(hid), now,
                                                          self.models[hid]))
        # stowed by THIS campaign for wind (its newest stow/resume event is a stow): stay stowed until
        # the wind allows; a plant stowed by its own logic (night, its own wind protection) is left alone
        marks = [e.kind for e in self.store.events(campaign_id=self.campaign_id) if e.kind in ("stow", "resume")]
        self.stowed = bool(marks) and marks[-1] == "stow"
        # heliostats a previous process left off tracking, in any campaign of the database (a run, a
        # check, a campaign left for --new-campaign): a visit it was killed in, or a return the plant
        # never confirmed (its newest off_tracking event has no back_to_tracking after it)
        known = {h.id for h in self.cfg.heliostats}
        running = {v.heliostat_id for v in self.store.visits() if v.outcome == "running"}
        self.store.close_interrupted_visits(None, now)
        self._flagged = set(off_tracking(self.store.events())) & known
        if self.armed:
            for hid in sorted((running & known) | self._flagged):
                if self.stowed:  # never a track command into a wind stow: checked once the field resumes
                    self.returning[hid] = Returning(since_s=now, next_check_s=now, failed=True)
                else:
                    self._send_back(hid, None, now, why="left off tracking by the previous run")

    # ------------------------------------------------------------------ events
    def now(self) -> float:
        """Plant time for the visits and a stop's legs: the plant clock's, or, once that clock jumped
        (:attr:`clock_jump`; the plant clock refuses every read after a jump), the controller's own
        extrapolation of it, so a beam on a board still leaves via its standby point."""
        if self.clock_jump is None:
            try:
                return self.clock.now_s()
            except ClockJumpError as err:
                self.clock_jumped(err)
        return self.clock.estimate_s()

    def safe_now(self) -> tuple[float, str]:
        """(plant time, ``"plant"``), or the controller's own extrapolation of it and ``"controller"``
        when the plant's clock cannot be read (records made during an outage still get a time)."""
        try:
            return self.clock.now_s(), "plant"
        except HelicalibError:
            return self.clock.estimate_s(), "controller"

    def event(self, kind: str, reason: str, heliostat_id: str | None = None, target_id: str | None = None,
              data: dict | None = None, time_s: float | None = None) -> RunEvent:
        """Record an event after the fact: to the store when its kind lasts (:data:`STORED`), then to
        every listener. ``time_s`` None: now, from the plant clock or, if that fails, the controller's."""
        source = "plant"
        if time_s is None:
            time_s, source = self.safe_now()
        ev = RunEvent(time_s=float(time_s), kind=kind, reason=reason, heliostat_id=heliostat_id, target_id=target_id,
                      data=dict(data or {}), clock=source)
        if kind == "off_tracking" and heliostat_id is not None:
            self._flagged.add(heliostat_id)
        elif kind == "back_to_tracking":
            self._flagged.discard(heliostat_id)
        if kind in STORED:
            try:
                self.store.record_event(campaign_id=self.campaign_id, time_s=ev.time_s, kind=kind, reason=reason,
                                        heliostat_id=heliostat_id, data=dict(ev.data, clock=source)
                                        if source != "plant" else ev.data or None)
            except Exception as err:  # noqa: BLE001 - a full disk must not break the step that records (a stow)
                if not self.storage_fault(err):
                    raise
        for listener in list(self.listeners):
            try:
                listener(ev)
            except Exception:  # noqa: BLE001 - a broken view (a closed pipe) must not stop the campaign
                pass
        return ev

    def _record(self, obs, **frames) -> int:
        """Store an observation (frames first), then tell the listeners. An observation stored with its
        after frames is the write that proves the storage works again (:attr:`storage_errors`)."""
        obs_id = self.store.record_observation(obs, **frames)
        if frames.get("after_frames"):
            self.storage_errors = 0
        if obs.iteration >= 0:
            self._boards[obs.target_id] = BoardState(
                obs.target_id, obs.heliostat_id, obs.iteration, obs.error_mrad if obs.valid else None,
                self._boards.get(obs.target_id, BoardState(obs.target_id)).since_s)
        if self.listeners:
            text = f"{obs.error_mrad:.2f} mrad" if obs.valid and obs.error_mrad is not None else f"invalid: {obs.reason}"
            self.event("measurement", f"{obs.heliostat_id} on {obs.target_id}, placement {obs.iteration}: {text}",
                       obs.heliostat_id, obs.target_id, time_s=obs.capture_time_s,
                       data={"iteration": obs.iteration, "valid": obs.valid, "error_mrad": obs.error_mrad,
                             "observation": obs_id})
        return obs_id

    # ------------------------------------------------------------------ faults of the plant and the database
    def plant_failed(self, err, link: str = "scs") -> bool:
        """The plant did not answer over ``link`` (``"scs"``: its clock, ``"weather"``): the first lost
        link gives ONE ``plant_lost`` event and sets :attr:`plant_unreachable_since_s`; returns
        whether this was news. (A plant that answered with a refusal is reachable: not this.)"""
        with self.state_lock:
            if link in self._lost_links:
                return False
            since = self._lost_links[link] = self.clock.estimate_s()
            if self.plant_unreachable_since_s is not None:  # another link is lost already: said
                return False
            self.plant_unreachable_since_s = since
            self.event("plant_lost", f"plant not answering ({err}); no visit starts until it answers",
                       time_s=since, data={"since_s": since})
            return True

    def plant_answered(self, now: float, link: str = "scs") -> None:
        """A read over ``link`` succeeded: once no link is lost any more, ONE ``plant_back`` event with
        how long the plant was unreachable."""
        with self.state_lock:
            if self._lost_links.pop(link, None) is None or self._lost_links:
                return
            since = self.plant_unreachable_since_s
            self.plant_unreachable_since_s = None
            self._said_lost.clear()
            lost = max(0.0, now - since)
            # never stamped before its plant_lost: ``since`` is the controller's estimate, which may run a
            # little ahead of the time the plant gives when it answers again
            self.event("plant_back", f"plant answers again after {_duration(lost)} unreachable",
                       time_s=max(now, since), data={"lost_s": lost})

    def job_failed(self, job: str, reason: str, time_s: float | None = None) -> None:
        """``job`` failed with ``reason`` (the plant refused, a device said no): a ``fault`` line,
        but only when the reason differs from the job's last one (:attr:`job_fault`; a job that
        succeeds clears it), not one a tick."""
        with self.state_lock:
            if self.job_fault.get(job) == reason:
                return
            self.job_fault[job] = reason
        self.event("fault", reason, time_s=time_s)

    def probe_scs(self, now: float) -> None:
        """While the plant's SCS link is lost: one read of its field state; an answer ends the loss."""
        try:
            self.plant.field_state()
        except PlantUnreachableError:
            return
        except PlantError:  # a refusal is an answer
            pass
        self.plant_answered(now, link="scs")

    def said_once(self, job: str) -> bool:
        """Whether ``job`` already said, during this loss of the plant, that the plant failed it
        (its next failures are silent until the plant answers again); marks it as said."""
        with self.state_lock:
            if job in self._said_lost:
                return True
            self._said_lost.add(job)
            return False

    def storage_fault(self, err: BaseException) -> bool:
        """Count ``err`` (:meth:`storage_failed`) if it says the storage cannot be written
        (:func:`storage_error`); returns whether it did (anything else is the caller's to raise)."""
        if not storage_error(err):
            return False
        self.storage_failed(err)
        return True

    def storage_failed(self, err) -> None:
        """A write to the database failed (full disk, read-only): the first is one ``fault`` line,
        :data:`STORAGE_RETRIES` in a row set :attr:`storage_lost` (a live run then stops)."""
        with self.state_lock:
            self._storage_failed(err)

    def _storage_failed(self, err) -> None:
        if self._storage_fault:  # the fault line's own write failed: the same failure, counted once
            return
        self.storage_errors += 1
        where = str(err) if isinstance(err, StorageError) else \
            f"database {self.store.path}: cannot be written ({type(err).__name__}: {err})"
        if self.storage_errors == 1:
            self._storage_fault = True
            try:
                self.event("fault", f"{where}; trying again", data={"storage": True})
            finally:
                self._storage_fault = False
        elif self.storage_errors >= STORAGE_RETRIES and self.storage_lost is None:
            self.storage_lost = f"{where} after {self.storage_errors} attempts"

    def clock_jumped(self, err) -> None:
        """The plant's clock jumped: ONE fault line; no visit starts (a live run stops)."""
        with self.state_lock:
            self._clock_jumped(err)

    def _clock_jumped(self, err) -> None:
        if self.clock_jump is not None:
            return
        self.clock_jump = (f"{err}: no visit starts; the run stops and every beam goes back to tracking. Check the "
                           f"plant's clock{self.clock_jump_hint}")
        self.event("fault", self.clock_jump, time_s=self.clock.estimate_s())

    # ------------------------------------------------------------------ back to tracking
    def _send_back(self, hid: str, corrections, now: float, why: str) -> None:
        """Send ``hid`` back to tracking and keep it in :attr:`returning` until the plant confirms."""
        ret = self.returning.get(hid) or Returning(since_s=now, next_check_s=now)
        ret.corrections_mm = corrections
        try:
            self.plant.track(self.cfg.heliostat_index(hid), corrections)
        except PlantError as err:
            ret.failed = True
            ret.last_error = str(err)
            ret.next_check_s = ret.retry_at(now)
            self.returning[hid] = ret
            if ret.attempts == 1:
                self.event("off_tracking", f"{hid}: not back to tracking ({why}): {err}; retrying until the plant "
                                           "confirms", hid)
            return
        self._written(hid, corrections)
        # the first command is checked soon; a repeated one (the plant took it but did not track: a
        # faulted or offline heliostat) waits longer each time, so no heliostat is commanded every 10 s
        ret.next_check_s = now + RETURN_CHECK_S if ret.attempts <= 1 else ret.retry_at(now)
        self.returning[hid] = ret

    def _check_returns(self, now: float) -> None:
        """Confirm or retry every return to tracking that is due (state 1 read from the plant)."""
        if self.stowed:  # the field's resume brings every heliostat back; no track command into a stow
            return
        busy = self.active
        for hid in [h for h, r in self.returning.items() if r.next_check_s <= now and h not in busy]:
            ret = self.returning[hid]
            try:
                state = self.plant.status(self.cfg.heliostat_index(hid)).state
            except PlantError as err:
                ret.last_error, ret.next_check_s = str(err), ret.retry_at(now)
                continue
            if state in (HeliostatState.TRACKING, HeliostatState.STOWED):
                # stowed: the plant's own protection (wind, night) holds it safely; it tracks with the field
                del self.returning[hid]
                if ret.failed or hid in self._flagged:
                    how = ("tracking again" if state == HeliostatState.TRACKING else
                           "stowed by the plant's own logic (safe; it tracks again with the field)")
                    self.event("back_to_tracking", f"{hid}: {how} (confirmed by the plant after "
                                                   f"{ret.attempts} attempt(s), {now - ret.since_s:.0f} s)", hid)
                continue
            if state == HeliostatState.MOVING:
                ret.next_check_s = now + RETURN_CHECK_S
                continue
            ret.attempts += 1
            if not ret.failed:
                ret.failed = True
                self.event("off_tracking", f"{hid}: the plant reports state {state.name.lower()} after a return to "
                                           "tracking; sending it again until it tracks", hid)
            self._send_back(hid, ret.corrections_mm, now, why=f"state {state.name.lower()}")

    # ------------------------------------------------------------------ sun
    def sun(self, t_s: float):
        """(vector_enu, azimuth_deg, elevation_deg, rising) at plant time ``t_s`` (SPA, tabulated)."""
        return self.sun_table.position(t_s)

    # ------------------------------------------------------------------ the loop
    def run_until(self, end_s: float, progress=None) -> None:
        """Advance plant time to ``end_s`` (virtual or real clock), running the campaign."""
        while True:
            now = self.clock.now_s()
            if now >= end_s:
                break
            wake = self.tick(now)
            if progress is not None:
                progress(now)
            nxt = min(wake, end_s)
            if nxt > now:
                self.clock.sleep(nxt - now)

    def tick(self, now: float) -> float:
        """Do everything due at plant time ``now``; returns the plant time of the next thing due."""
        if self._lost_links and "scs" in self._lost_links:  # does the plant's SCS answer again?
            self.probe_scs(now)
        if self.operator is not None:  # operator actions (campaign/operation/crew.py): the crew's requests first
            self.operator.apply(self, now)
        if self.stowed and self.active:  # stowed by the weather job while this tick's thread waited on a device
            self._abort_visits(now, "field stowed for wind")
        if now - self.last_poll_s >= WEATHER_POLL_S:
            self._poll_weather(now)
        if now - self.last_refresh_s >= policy.TRACKING_REFRESH_S and self.plant_unreachable_since_s is None:
            self._refresh_tracking(now)  # (not into a plant that does not answer: once it answers again)
        if self.retention is not None:
            self._nightly_retention(now)
        if self.returning and self.armed:
            self._check_returns(now)
        due = sorted((v.wake_s, hid) for hid, v in self.active.items() if v.wake_s <= now)
        for _wake, hid in due:
            if hid in self.active:
                self._step(hid, now)
        free = self._free_targets()
        gate = None
        if free and not self.stowed:
            gate = self._gate(now)
            if gate.open and self.clock_jump is None and not (self.operator is not None and self.operator.paused):
                for tid in free:
                    while self._start_visit(tid, now):  # a board fills its places (--spots-per-board)
                        pass
        wakes = [v.wake_s for v in self.active.values()]
        wakes.append(self.last_poll_s + WEATHER_POLL_S)
        if self.armed and not self.stowed:  # (while stowed, or for a heliostat in a visit, no check is due)
            wakes.extend(r.next_check_s for h, r in self.returning.items() if h not in self.active)
        if self._free_targets() and not self.stowed:
            if gate is not None and not gate.open and gate.night:
                wakes.append(max(now + PLANNER_TICK_S, gate.next_open_s))
            elif self._steady():  # operation with every heliostat accepted: the next check can wait minutes
                wakes.append(now + STEADY_TICK_S)
            else:
                wakes.append(now + PLANNER_TICK_S)
        nxt = min(wakes)
        self._account(now, nxt, gate)
        return max(nxt, now + 1e-3)

    def _nightly_retention(self, now: float) -> None:
        """Once a solar day, at night (sun below the low band) with no visit under way, prune the frames."""
        day = int((now + self.cfg.site.longitude_deg / 15.0 * 3600.0) // 86400.0)
        if self._retained_day is None:
            self._retained_day = day - 1  # a service started at night prunes that night
        if day == self._retained_day or self.active or self.sun(now)[2] >= self.cfg.acceptance.low_band_deg[0]:
            return
        from helicalib.store.retention import retain_frames

        self._retained_day = day
        keep, keep_invalid = self.retention
        try:
            r = retain_frames(self.store, keep, keep_invalid=keep_invalid)
        except HelicalibError as err:
            self.event("fault", f"frame retention: {err}", time_s=now)
            return
        if r.files:
            self.event("note", f"frame retention: {r.files} frame file(s) of {r.observations} observation(s) deleted "
                               f"({r.bytes / 1e6:.1f} MB; frames of the newest {keep} per heliostat"
                               + (" and of every rejected one" if keep_invalid else "") + f" kept, {r.kept_files} files)",
                       time_s=now, data=r.as_dict())

    def _steady(self) -> bool:
        """Operation with nothing but checks to plan: every heliostat accepted, none suspected of drift,
        no crew request waiting."""
        if self.operation is None or self.ops.suspects or (self.operator is not None and self.operator.queue):
            return False
        return bool(np.all(self.book.table.accepted))

    def _account(self, now: float, nxt: float, gate) -> None:
        dt = max(0.0, nxt - now)
        if self.stowed:  # stowed hours count in daylight only (the sun above the low band), as gated ones
            if self.sun(now)[2] >= self.cfg.acceptance.low_band_deg[0]:
                self.stats.stowed_s += dt
            else:
                self.stats.night_s += dt
        elif gate is not None and not gate.open and not self.active:
            if gate.night:
                self.stats.night_s += dt
            else:
                self.stats.gated_s += dt

    def _poll_weather(self, now: float, preempt: bool = False) -> None:
        """Read the weather; stow or resume. ``preempt``: from the weather job while a tick waits on a
        slow device (:mod:`.live`): it reads and stows, but leaves the visits and a resume to the tick."""
        if not self._weather_lock.acquire(blocking=not preempt):
            return  # the tick's own poll is under way
        try:
            self._weather_now(now, preempt)
        finally:
            self._weather_lock.release()

    def _weather_now(self, now: float, preempt: bool) -> None:
        with self.state_lock:
            self.last_poll_s = now
        try:
            w = self.plant.weather()
        except PlantUnreachableError as err:
            self.plant_failed(f"weather: {err}", link="weather")  # one line for the loss, not one per poll
            return
        except PlantError as err:  # the weather station answered with a refusal: reachable, one line a change
            self.plant_answered(now, link="weather")
            self.job_failed("weather station", f"weather: {err}", now)
            return
        self.job_fault.pop("weather station", None)
        with self.state_lock:
            self.last_weather, self.weather_time_s = w, now
        self.plant_answered(now, link="weather")
        g = gating_mod.gate_field(w.wind_ms, w.dni_wm2, self.cfg.gating, stowed=self.stowed)
        if g.stow and not self.stowed:
            if preempt:
                self._stow_field(now, g.reason)
            else:
                self._stow(now, g.reason)
        elif self.stowed and not g.stow and not preempt:
            try:
                if self.armed:
                    self.plant.field_command(FieldCommand.RESUME_TRACKING)
                with self.state_lock:
                    self.stowed = False
                    self.event("resume", g.reason)
            except PlantError as err:
                self.event("fault", f"resume: {err}")

    def _stow(self, now: float, reason: str) -> None:
        if self._stow_field(now, reason) and self.armed:
            self._abort_visits(now, "field stowed for wind")

    def _stow_field(self, now: float, reason: str) -> bool:
        """Stow the whole field (armed) or say what a dry run would do; returns whether it is stowed."""
        if not self.armed:  # reads and plans only: say what it would do
            with self.state_lock:
                self.stowed = True
                self.event("note", f"not armed: would stow the field ({reason})", time_s=now)
            return True
        try:
            self.plant.field_command(FieldCommand.STOW_ALL)
        except PlantError as err:
            self.event("fault", f"stow: {err}")
            return False
        with self.state_lock:
            self.stowed = True
            self.event("stow", reason)
        return True

    def _abort_visits(self, now: float, why: str) -> None:
        """End every visit under way as aborted (the field is stowed: no command follows)."""
        for hid in list(self.active):
            v = self.active.pop(hid)
            v.gen.close()
            self.boards[v.target_id].leave(hid)
            self.store.end_visit(v.ctx.visit_id, ended_s=now, outcome="aborted", reason=why)
            self.event("visit_end", f"{hid} off {v.target_id}: aborted ({why})", hid,
                       v.target_id, data={"outcome": "aborted"})

    def _gate(self, now: float):
        """Judge the gate now (:meth:`_judge_gate`); log ``gated``/``ungated`` when it changes."""
        gate = self._judge_gate(now)
        lost = self.plant_unreachable_since_s is not None
        if self._gate_reason != (gate.open, gate.night):
            if not gate.night and not (lost and not gate.open):
                self.event("ungated" if gate.open else "gated", gate.reason, time_s=now)
            self._gate_reason = (gate.open, gate.night)
        self._last_gate = gate
        return gate

    def _judge_gate(self, now: float):
        """The field's gate from the newest weather reading, the sun and the plant's state (no event)."""
        _vec, _az, el, _rising = self.sun(now)
        gate = policy.field_gate(self.cfg, self.last_weather, el, now, self.sun, stowed=self.stowed,
                                 elevations=self.sun_table.position_elevations_deg)
        lost = self.plant_unreachable_since_s is not None
        if gate.open and lost:  # (plant_lost said it: no gated line of its own)
            gate = replace(gate, open=False, reason=self._unreachable_reason())
        elif gate.open and (self.weather_time_s is None or now - self.weather_time_s > WEATHER_MAX_AGE_S):
            age = "none yet" if self.weather_time_s is None else f"{_duration(now - self.weather_time_s)} old"
            gate = replace(gate, open=False, reason=f"no fresh weather reading ({age})")
        return gate

    # ------------------------------------------------------------------ visits
    def _free_targets(self) -> list[str]:
        """Boards that can take a visit now."""
        return [t.id for t in self.cfg.targets if self.boards[t.id].has_room]

    def _busy_targets(self) -> list[str]:
        """Boards with a visit under way."""
        return sorted({v.target_id for v in self.active.values()})

    def _start_visit(self, target_id: str, now: float) -> bool:
        """Start the visit the planner (or the crew, or a drift check) puts on ``target_id`` now.
        Returns whether one started."""
        board = self.boards[target_id]
        if not board.has_room:
            return False
        cands = self._home[target_id]
        busy = list(self.active)
        spreads = None
        if self.refine:
            spreads = policy.model_spreads(self.cfg, self.book, self.models, self._nominal_rows,
                                           [h for h in cands if h not in busy], self.sun(now)[0], now)
        usable = lambda hid: self._reaches(hid, target_id, now)  # noqa: E731
        # operator actions (campaign/operation/crew.py): a queued re-check goes before the planner's choice
        choice = self.operator.next_for(self, target_id, now) if self.operator is not None else None
        check = False
        if choice is None and self.operation is not None:  # a suspected drift is checked again first
            choice = self.ops.suspect_for(target_id, now, busy)
            check = choice is not None
        if choice is None and self.planner_kind == "gaps":
            # a board is lent only to heliostats whose own board is busy (a free own board takes them)
            choice = policy.choose_next_vectorised(
                self.cfg, self.book, target_id, now, lambda rows: self._cleanliness_of_rows(rows, now),
                recheck=self.recheck, busy_heliostats=busy, refine=self.refine, spreads=spreads,
                active_targets=self._busy_targets(), usable=usable)
            if choice is None and self.operation is not None:
                choice = self.ops.check_for(target_id, now, busy)
                check = choice is not None
        elif choice is None:
            busy_boards = set(self._busy_targets())  # once, not per guest
            guests = {h: r for h, r in self._guests.get(target_id, {}).items()
                      if self.cfg.heliostat(h).target in busy_boards}
            cleanliness = {hid: self._cleanliness(hid, now) for hid in [*cands, *guests]}
            choice = policy.choose_next(self.cfg, self.book, cands, now, cleanliness, planner=self.planner_kind,
                                        recheck=self.recheck, busy_heliostats=busy, target_id=target_id,
                                        guests=guests, usable=usable)
        if choice is None:
            return False
        hid = choice
        if not self.armed:
            self.event("note", f"not armed: would send {hid} to {target_id}", hid, target_id, time_s=now)
            self.book.visiting(hid, now)
            self.book.h[hid].cooldown_until_s = now + policy.COOLDOWN_VALID_S
            return False
        visit_id = self.store.begin_visit(self.campaign_id, hid, target_id, now)
        index = self.cfg.heliostat_index(hid)
        shared = not board.empty
        board.join(hid)
        ctx = VisitContext(
            campaign_id=self.campaign_id, visit_id=visit_id, heliostat_id=hid,
            index=index, target=self.cfg.target(target_id), board=board,
            sensor=self.sensors[target_id], plant=self.plant, now=self.now, sun=self.sun,
            model=self.models[hid], settings=self.check_settings if check else self.settings,
            time_slack_s=lambda: float(self.clock.uncertainty_s),
        )
        self.book.visiting(hid, now)
        self.ops.started(hid, visit_id, self.models[hid], now, check)
        self.returning.pop(hid, None)  # the visit commands it now; it ends with its own return
        self._boards[target_id] = BoardState(target_id, hid, None, None, now)
        self.active[hid] = RunningVisit(hid, target_id, run_visit(ctx), ctx, now)
        self.stats.visits += 1
        self.stats.shared_visits += int(shared)
        self.stats.peak_on_board = max(self.stats.peak_on_board, len(board.visitors))
        why = "" if self.cfg.heliostat(hid).target == target_id else \
            f" (lent; its own board {self.cfg.heliostat(hid).target} is busy)"
        if shared:
            why += f" ({len(board.visitors)} visits on the board, beams taking turns)"
        if check:
            why += " (check: suspected drift)" if hid in self.ops.suspects else " (check)"
        self.event("visit", f"{hid} onto {target_id}{why}", hid, target_id, time_s=now,
                   data={"check": True} if check else None)
        if check:  # stored: which visits were checks, and how many frames their measurements average
            suspect = hid in self.ops.suspects
            self.event("check", f"{hid}: visit {visit_id} is a {'suspected drift ' if suspect else ''}check, "
                       f"{ctx.settings.after_frames} after frames per measurement", hid, target_id, time_s=now,
                       data={"visit_id": visit_id, "after_frames": ctx.settings.after_frames, "suspect": suspect})
        return True

    def _reaches(self, hid: str, target_id: str, now: float) -> bool:
        """Whether ``hid``'s model puts both the standby point and the centre of ``target_id``
        inside its stroke range now and :data:`SHARE_REACH_S` later (a borrowed board)."""
        target = self.cfg.target(target_id)
        aims = np.array([target.uvw_to_enu(np.asarray(target.standby_uvw_m)), target.center_enu_m], dtype=float)
        model = self.models[hid]
        for t in (now, now + SHARE_REACH_S):
            sun = self.sun(t)[0]
            if not all(bool(model.strokes_for_aim(sun, aim).in_range[0]) for aim in aims):
                return False
        return True

    def _nominal_rows(self, hids) -> HeliostatModel:
        return self.nominal.subset([self._index[h] for h in hids])

    def nominal_of(self, hid: str) -> HeliostatModel:
        model = self._nominal_one.get(hid)
        if model is None:
            model = self._nominal_one[hid] = self.nominal.subset([self._index[hid]])
        return model

    def _cleanliness(self, hid: str, now: float) -> float | None:
        """The plant's cleanliness register of a heliostat, read at most once per weather poll
        (soiling changes over days; a crowded board would otherwise cost a read per candidate per visit)."""
        hit = self._clean_cache.get(hid)
        if hit is not None and now - hit[0] < WEATHER_POLL_S:
            return hit[1]
        try:
            value = self.plant.status(self.cfg.heliostat_index(hid)).cleanliness
        except PlantError:
            value = None
        self._clean_cache[hid] = (now, value)
        return value

    def _cleanliness_of_rows(self, rows: np.ndarray, now: float) -> np.ndarray:
        """:meth:`_cleanliness` of the heliostats at ``rows`` of :attr:`ids` (NaN where the plant
        gives none), read only for those whose last read is :data:`CLEANLINESS_MAX_AGE_S` old."""
        values, read_at = self._clean_rows
        due = rows[now - read_at[rows] >= CLEANLINESS_MAX_AGE_S]
        bulk = getattr(self.plant, "cleanliness_many", None)  # the in-process simulated plant: one read
        if bulk is not None and due.size:
            values[due] = bulk(self._plant_index[due])
            read_at[due] = now
            due = due[:0]
        for r in due:
            try:
                value = self.plant.status(self.cfg.heliostat_index(self.ids[r])).cleanliness
            except PlantError:
                value = None
            values[r] = np.nan if value is None else value
            read_at[r] = now
        return values[rows]

    def _advance(self, hid: str, ctx: VisitContext, gen, stopping: bool = False) -> float:
        """Run a visit (or a stopped visit's way off the board) until it asks to wait; returns the
        wait [plant s]. Its requests on the way are served here: the store's writes and the refits
        happen in the runner, never inside the visit (:data:`~.controller.REQUESTS`). A request that
        fails is thrown into the visit, which decides (a failed record of a measurement ends the visit
        as a fault and the beam leaves the board). ``StopIteration`` carries the visit's outcome."""
        answer, error = None, None
        while True:
            request = gen.throw(error) if error is not None else gen.send(answer)
            answer, error = None, None
            if not isinstance(request, REQUESTS):
                return float(request)
            try:
                answer = self._serve(hid, ctx, request, stopping)
            except Exception as err:  # noqa: BLE001 - the visit decides; it must still leave the board
                error = err
                self.storage_fault(err)

    def _serve(self, hid: str, ctx: VisitContext, request, stopping: bool):
        if isinstance(request, Record):
            return self._record(request.observation, **request.frames)
        if isinstance(request, SaveFrame):
            return self.store.save_frame(request.data, campaign_id=self.campaign_id, heliostat_id=hid,
                                         visit_id=ctx.visit_id, iteration=request.iteration,
                                         capture_time_s=request.capture_time_s, kind=request.kind)
        if isinstance(request, Refit):
            return self._refit(hid, request.observation)
        if isinstance(request, Corrections):  # a stopped visit leaves with the corrections last written
            return self.corrections[hid] if stopping else self._corrections(hid, request.model)
        raise TypeError(f"{hid}: a visit asked for {type(request).__name__}")

    def _step(self, hid: str, now: float) -> None:
        v = self.active[hid]
        try:
            wait = self._advance(hid, v.ctx, v.gen)
        except StopIteration as stop:
            self._finish(hid, stop.value, now)
            return
        except Exception as err:  # noqa: BLE001 - a visit must never take the campaign down
            # the visit could not leave by itself: _finish sends it back to tracking (left is None),
            # keeping the plant's corrections
            self._finish(hid, VisitOutcome(status="fault", reason=f"error_{type(err).__name__}: {err}"), now)
            return
        v.wake_s = now + float(wait)

    def _finish(self, hid: str, out: VisitOutcome, now: float) -> None:
        v = self.active.pop(hid)
        target_id, ctx = v.target_id, v.ctx
        self.boards[target_id].leave(hid)
        self.stats.outcomes[out.status] = self.stats.outcomes.get(out.status, 0) + 1
        if out.valid_points:
            self.stats.valid_visits += 1
            self.stats.iterations.append(out.iterations)
        first = next((o for o in out.observations if o.valid and o.iteration == 0), None)
        if first is not None:
            # a placement is judged as the model's only if earlier visits gave the model valid points
            modelled = any(p.visit_id != ctx.visit_id for p in self.book.points(hid))
            self.stats.first_errors.append((first.capture_time_s, first.error_mrad, modelled))
        self._after_leaving(hid, out.left, now)  # the plant's side first: retries must not hang on a record
        self.store.end_visit(ctx.visit_id, ended_s=now, outcome=out.status, reason=out.reason,
                             iterations=out.iterations, first_error_mrad=out.first_error_mrad,
                             final_error_mrad=out.final_error_mrad)
        self.book.visited(hid, now, out)
        was = self.book.accepted(hid)
        self.ops.finished(hid, target_id, ctx.visit_id, first, was, now)
        verdict = policy.verdict(self.cfg, self.book, hid, self.nominal_of(hid), now, self.models[hid])
        self.store.record_verdict(campaign_id=self.campaign_id, heliostat_id=hid, time_s=now,
                                  accepted=verdict.accepted, n_points=verdict.n_points, rms_mrad=verdict.rms_mrad,
                                  reasons=list(verdict.reasons),
                                  details={"rising_ok": verdict.rising_ok, "setting_ok": verdict.setting_ok,
                                           "window_counts": list(verdict.window_counts)})
        self.book.set_verdict(hid, verdict)
        errs = "" if out.first_error_mrad is None else (
            f", {out.first_error_mrad:.2f} mrad" if out.iterations <= 1 else
            f", {out.first_error_mrad:.2f} -> {out.final_error_mrad:.2f} mrad in {out.iterations} placements")
        self.event("visit_end", f"{hid} off {target_id}: {out.status} ({out.reason}){errs}", hid, target_id,
                   time_s=now, data={"outcome": out.status, "iterations": out.iterations,
                                     "first_error_mrad": out.first_error_mrad, "final_error_mrad": out.final_error_mrad})
        if verdict.accepted and not was:
            self.ops.accepted_again(hid, now)
        if verdict.accepted != was:
            rms = "" if verdict.rms_mrad is None else f", acceptance error {verdict.rms_mrad:.2f} mrad"
            text = "accepted" if verdict.accepted else f"no longer accepted: {(verdict.reasons or ('',))[0]}"
            self.event("verdict", f"{hid} {text} ({verdict.n_points} points{rms})", hid, time_s=now,
                       data={"accepted": verdict.accepted, "n_points": verdict.n_points, "rms_mrad": verdict.rms_mrad})

    def _after_leaving(self, hid: str, left: Left | None, now: float) -> None:
        """What a heliostat's leaving the board did, recorded after the fact: the corrections the
        plant took (an event), or a failed return to tracking (retried until the plant confirms)."""
        if left is None:
            self._send_back(hid, self.corrections[hid], now, why="the visit ended without leaving the board")
        elif left.error is not None:  # the retry sends the corrections the plant did not take
            self.returning[hid] = self.returning.get(hid) or Returning(since_s=now, next_check_s=now + RETURN_RETRY_S)
            ret = self.returning[hid]
            ret.failed, ret.last_error = True, left.error
            ret.corrections_mm = left.corrections_mm if left.corrections_mm is not None else self.corrections[hid]
            ret.next_check_s = ret.retry_at(now)
            self.event("off_tracking", f"{hid}: {left.error}; retrying until the plant confirms it tracks", hid)
        else:
            self._written(hid, left.corrections_mm)
            self.returning[hid] = Returning(since_s=now, next_check_s=now + RETURN_CHECK_S,
                                            corrections_mm=self.corrections[hid])

    def _written(self, hid: str, corrections) -> None:
        """The plant took ``corrections`` with a track command: keep them, and say so when they are new."""
        if corrections is None or (self.corrections[hid] is not None and
                                   np.array_equal(corrections, self.corrections[hid])):
            return
        self.corrections[hid] = np.asarray(corrections, dtype=float)
        c = self.corrections[hid]
        self.event("tracking_written", f"{hid}: tracking corrections {c[0]:+.2f}, {c[1]:+.2f} mm", hid)

    def _corrections(self, hid: str, model: HeliostatModel) -> np.ndarray | None:
        """Tracking corrections to write as the visit ends; None keeps what the plant has."""
        now = self.now()
        if self.recheck or not self.book.points(hid):
            return self.corrections[hid]  # a re-check, or no fitted model yet: the plant keeps what it has
        sun_ahead = self.sun(now + policy.TRACKING_REFRESH_S / 2)[0]
        sun_later = self.sun(now + policy.TRACKING_REFRESH_S / 2 + APPROACH_LEAD_S)[0]
        corr = policy.tracking_corrections(self.cfg, self.nominal_of(hid), model, sun_ahead, sun_later)[0]
        if not np.all(np.isfinite(corr)):
            return self.corrections[hid]
        return corr  # recorded (and kept) once the plant has taken it: see _after_leaving

    def _refresh_tracking(self, now: float) -> None:
        """Rewrite the tracking corrections of every calibrated heliostat not in a visit.

        The plant's nominal tracking plus a constant offset follows a calibrated model only near
        the sun position the offset was computed for, so it is recomputed (vectorised over the
        field) every :data:`~helicalib.campaign.policy.TRACKING_REFRESH_S` for the sun half a
        period ahead. Not armed, stowed, at night or in a re-check: nothing is written.
        """
        self.last_refresh_s = now
        vec, _az, el, _r = self.sun(now + policy.TRACKING_REFRESH_S / 2)
        if not self.armed or self.recheck or self.stowed or el < self.cfg.acceptance.low_band_deg[0]:
            return
        ids = [hid for hid in self.ids if hid not in self.active and self.book.points(hid)]
        if not ids:
            return
        rows = [self._index[hid] for hid in ids]
        calibrated = self.nominal.subset(rows).with_params(np.vstack([self.models[h].params for h in ids]))
        later = self.sun(now + policy.TRACKING_REFRESH_S / 2 + APPROACH_LEAD_S)[0]
        corr = policy.tracking_corrections(self.cfg, self.nominal.subset(rows), calibrated, vec, later)
        failed = []
        bulk = getattr(self.plant, "track_many", None)  # the in-process simulated plant: one array write
        if bulk is not None:
            ok = np.flatnonzero(np.all(np.isfinite(corr), axis=1))
            bulk(self._plant_index[np.asarray(rows, dtype=np.int64)[ok]], corr[ok])
            for k in ok:
                self.corrections[ids[k]] = corr[k]
            ids, corr = [], corr[:0]
        for hid, c in zip(ids, corr):
            if self.stowed:  # the weather job stowed the field meanwhile (the plant client refuses the rest)
                break
            if not np.all(np.isfinite(c)):
                continue
            try:
                self.plant.track(self.cfg.heliostat_index(hid), c)
                self.corrections[hid] = c
            except FieldStowedError:
                break
            except PlantError as err:
                failed.append((hid, err))
        if failed:  # one line for a dead plant, not one per heliostat
            names = ", ".join(h for h, _e in failed[:5]) + (f" and {len(failed) - 5} more" if len(failed) > 5 else "")
            self.event("fault", f"tracking corrections not written for {len(failed)} heliostat(s) ({names}): "
                                f"{failed[0][1]}", failed[0][0] if len(failed) == 1 else None)

    def _refit(self, hid: str, obs) -> HeliostatModel:
        self.book.add(obs)
        if self.recheck:  # a re-check measures the heliostat as it is; one point is no calibration
            return self.models[hid]
        model, fit = policy.refit(self.nominal_of(hid), self.book.points(hid), self.models[hid],
                                  prior_mean=self.ops.prior_mean(hid), tilt_rate=self.ops.tilt_rate_of(hid),
                                  earlier=self.book.h[hid].earlier)
        self.models[hid] = model
        if fit is not None:
            self.book.h[hid].fit = fit
            self.store.record_fit(campaign_id=self.campaign_id, heliostat_id=hid, time_s=obs.capture_time_s,
                                  **policy.fit_record(fit))
        return model

    @property
    def drifts(self) -> list[dict]:
        """Confirmed drifts (this process and, from the store, earlier ones)."""
        return self.ops.drifts

    @property
    def checks(self) -> int:
        """Operation checks started by this process."""
        return self.ops.checks

    def prior_mean(self, hid: str) -> np.ndarray | None:
        """The centre of the priors of ``hid``'s fits (:meth:`.checks.OperationChecks.prior_mean`)."""
        return self.ops.prior_mean(hid)

    def rechecked(self) -> bool:
        """Re-check mode: every heliostat has been visited and no visit is under way."""
        return not self.active and all(self.book.h[hid].visits > 0 for hid in self.ids)

    def shutdown(self, now: float) -> list[str]:
        """Stop every visit under way; each heliostat leaves its board as a finished visit does:
        the beam to the board's standby point first (never across the receiver), then back to
        tracking with the corrections last written (the visits' legs run side by side on the
        clock; each move is bounded by ``settle_timeout_s``). Then every return to tracking not yet
        confirmed is checked once. Returns the heliostats left off tracking: each has an
        ``off_tracking`` event, and the next run on this database retries them first."""
        leaving = []
        for hid in list(self.active):
            v = self.active.pop(hid)
            v.gen.close()
            ctx, tid = v.ctx, v.target_id
            try:  # a database that cannot be written (the reason of some stops) must not keep a beam on a board
                self.store.end_visit(ctx.visit_id, ended_s=now, outcome="aborted", reason="campaign stopped")
            except Exception as err:  # noqa: BLE001
                if not self.storage_fault(err):
                    raise
            self.event("visit_end", f"{hid} off {tid}: aborted (campaign stopped), leaving via standby", hid, tid,
                       data={"outcome": "aborted"})
            leaving.append([now, hid, ctx, leave_board(ctx)])
        while leaving:
            leaving.sort(key=lambda item: item[0])
            wake, hid, ctx, leg = leaving.pop(0)
            try:  # (after a clock jump, the controller's own clock: the beams still leave via standby)
                t = self.now()
                if wake > t:
                    self.clock.sleep(wake - t)
                    t = self.now()
                leaving.append([t + self._advance(hid, ctx, leg, stopping=True), hid, ctx, leg])
            except StopIteration as done:
                if ctx.board is not None:
                    ctx.board.leave(hid)
                self._after_leaving(hid, done.value, self.safe_now()[0])
            except HelicalibError as err:  # no clock: straight back to tracking, as before a stop
                for _w, h, c, g in [[wake, hid, ctx, leg], *leaving]:
                    g.close()
                    self._send_back(h, self.corrections[h], self.safe_now()[0], why=f"stopping without a clock: {err}")
                leaving = []
        return self._confirm_returns_once()

    def _confirm_returns_once(self) -> list[str]:
        """At a stop: read each unconfirmed return once; a heliostat neither tracking nor on its way
        is recorded ``off_tracking`` (the next run retries it). Returns those heliostats."""
        if not self.armed:
            return []
        stranded = []
        for hid, ret in sorted(self.returning.items()):
            try:
                state = self.plant.status(self.cfg.heliostat_index(hid)).state
            except PlantError as err:
                state, ret.last_error = None, str(err)
            if state in (HeliostatState.TRACKING, HeliostatState.MOVING) or (
                    state == HeliostatState.STOWED and self.stowed):
                continue
            stranded.append(hid)
            what = ret.last_error if state is None else f"state {state.name.lower()}"
            self.event("off_tracking", f"{hid}: not confirmed back to tracking when the controller stopped "
                                       f"({what}); the next run retries it first", hid)
        self.returning.clear()
        return stranded

    # ------------------------------------------------------------------ what a view shows
    def snapshot(self, now: float) -> Snapshot:
        """The campaign's state at plant time ``now`` (read-only; call it where no tick runs)."""
        boards = []
        for t in self.cfg.targets:
            board = self.boards[t.id]
            on = ([board.measuring] if board.measuring in board.visitors else []) + \
                [h for h in board.visitors if h != board.measuring]
            if on:
                b = self._boards.get(t.id, BoardState(t.id, on[0]))
                b = b if b.heliostat_id in on else BoardState(t.id, on[0])
                boards.append(replace(b, others=tuple(h for h in on if h != b.heliostat_id)))
            else:
                boards.append(BoardState(t.id))
        el = self.sun(now)[2]
        # judged afresh from the reading shown (the tick judges it only when a board is free, so its
        # reason could quote an older reading than the wind and DNI beside it)
        gate = None if self._last_gate is None else self._judge_gate(now)
        w = self.last_weather
        accepted = sum(1 for hid in self.ids if self.book.accepted(hid))
        return Snapshot(
            time_s=now, campaign_id=self.campaign_id, armed=self.armed, rate=float(self.clock.rate),
            boards=tuple(boards), wind_ms=None if w is None else w.wind_ms, dni_wm2=None if w is None else w.dni_wm2,
            stowed=self.stowed, gate_open=None if gate is None else gate.open,
            gate_reason="" if gate is None else gate.reason, night=bool(gate is not None and gate.night),
            sun_elevation_deg=el, heliostats=len(self.ids), accepted=accepted, in_progress=len(self.active),
            waiting=len(self.ids) - accepted - len(self.active), visits=self.stats.visits,
            valid_visits=self.stats.valid_visits, next_band=self._next_band(now),
            off_tracking=tuple(sorted(h for h, r in self.returning.items() if r.failed or h in self._flagged)),
            plant_unreachable_since_s=self.plant_unreachable_since_s, weather_time_s=self.weather_time_s)

    def _unreachable_reason(self) -> str:
        from helicalib.campaign.events import iso_utc

        return f"plant unreachable since {iso_utc(self.plant_unreachable_since_s)}"

    def _next_band(self, now: float) -> str:
        """The rising or setting low band (the paper's scarce 5–15°): "rising band now (until 07:10 UTC)"
        or "setting band in 3.2 h"; recomputed at most once a plant minute."""
        if now - self._band_cache[0] < 60.0:
            return self._band_cache[1]
        lo, hi = self.cfg.acceptance.low_band_deg
        t = now
        inside = lambda el: lo <= el <= hi  # noqa: E731
        _v, _az, el, rising = self.sun(t)
        if inside(el):
            end = t
            while inside(self.sun(end)[2]) and end < now + 86400.0:
                end += 120.0
            text = f"{'rising' if rising else 'setting'} band now, {(end - now) / 3600.0:.1f} h left"
        else:
            text = "no band within 2 days"
            while t < now + 2 * 86400.0:
                t += 300.0
                _v, _az, el, rising = self.sun(t)
                if inside(el):
                    text = f"{'rising' if rising else 'setting'} band in {(t - now) / 3600.0:.1f} h"
                    break
        self._band_cache = (now, text)
        return text

    # ------------------------------------------------------------------ summary
    def accepted(self) -> list[str]:
        return [hid for hid in self.ids if self.book.accepted(hid)]

    def calibrated_model(self) -> HeliostatModel:
        params = np.vstack([self.models[hid].params for hid in self.ids])
        return self.nominal.with_params(params)


def _duration(seconds: float) -> str:
    """``42 s``, ``3.5 min``, ``2.1 h``."""
    seconds = float(seconds)
    if seconds < 120.0:
        return f"{seconds:.0f} s"
    if seconds < 7200.0:
        return f"{seconds / 60.0:.1f} min"
    return f"{seconds / 3600.0:.1f} h"
