"""The campaign loop: tick, start a visit, step it, finish it; the campaign's one entry point.

One :class:`CampaignRunner` drives the same campaign core in every place it runs:

* in-process on a virtual clock (``helicalib simulate``): :meth:`~CampaignRunner.run_until` jumps
  plant time from event to event, so days pass in seconds;
* against a plant over Modbus TCP + HTTP (``helicalib simulate --over-network``, ``helicalib run``):
  the same :meth:`~CampaignRunner.tick` is called by APScheduler jobs on the plant clock
  (:mod:`helicalib.app.live`).

The runner is a shell over a :class:`~.state.CampaignState`: the field's side (weather, stow,
gate, cleanliness: :mod:`.field`), tracking and returns (:mod:`.tracking`), the journal of events,
writes and faults (:mod:`.journal`), operation's checks (:mod:`.operation.checks`). Visits are
generators (:func:`~.visit.run_visit`) that yield the plant seconds they want to wait; the loop
steps each when its wake-up time comes. What a visit writes and the refits it asks for happen in
its host (:mod:`.host`), in one place. A board serves up to ``spots_per_board`` visits at once, whose
beams take turns on it (:mod:`.board`). Every observation goes to the store as soon as it is made.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from helicalib.campaign import book as books
from helicalib.campaign import choice as choices
from helicalib.campaign import verdict as verdicts
from helicalib.campaign.events import BoardState, RunEvent, Snapshot
from helicalib.campaign.field import WEATHER_POLL_S, Field
from helicalib.campaign.frames import FrameWait
from helicalib.campaign.host import Host
from helicalib.campaign.journal import Journal
from helicalib.campaign.moves import leave_board
from helicalib.campaign.operation.checks import OperationChecks
from helicalib.campaign.resume import resume_from_store
from helicalib.campaign.sensor import camera_sensors
from helicalib.campaign.state import CampaignDevices, CampaignOptions, RunningVisit, build_state
from helicalib.campaign.tracking import REFRESH_SLICE_S, Tracking
from helicalib.campaign.visit import run_visit
from helicalib.campaign.visit_types import VisitContext, VisitOutcome
from helicalib.devices.protocols import SpotSensor, abilities_of
from helicalib.errors import HelicalibError
from helicalib.geometry.heliostat import HeliostatModel

PLANNER_TICK_S = 30.0
"""Plant seconds between planner ticks while a target is free."""
SHARE_REACH_S = 1800.0
"""A borrowed board must be within the heliostat's stroke range now and this much later [plant s]."""
STEADY_TICK_S = 300.0
"""Plant seconds between planner ticks in operation while every heliostat is accepted (checks only)."""


class CampaignRunner:
    """Run a calibration campaign on a plant.

    Parameters
    ----------
    cfg : FieldConfig
    plant : Plant protocol implementation (its optional abilities are read once, here)
    cameras : dict target id → Camera or SpotSensor
        Each board's camera (measured with :class:`~helicalib.campaign.sensor.CameraSensor`: the
        vision), or a spot sensor of its own (the measurement seam).
    clock : Clock protocol (``now_s``, ``sleep``)
    store : helicalib.store.Store
    campaign_id : int
        The campaign (new or resumed) in ``store``.
    heliostat_ids : list of str, optional
        Heliostats to calibrate (default all).
    **options
        The fields of :class:`~.state.CampaignOptions` (planner, recheck, model, armed, refine,
        listeners, operation, rota_days, spots_per_board, flux).

    Attributes
    ----------
    state : CampaignState
        Everything the campaign knows and holds (book, models, boards, visits under way, faults).
    devices : CampaignDevices
        Plant (and its declared abilities), spot sensors, clock, store.
    journal, field, tracking, ops, host
        The parts over the state: events, writes and faults (:mod:`.journal`); weather, stow,
        gate, cleanliness (:mod:`.field`); corrections and returns (:mod:`.tracking`);
        operation's checks and drifts (:mod:`.operation.checks`); the visits' writes and fits
        (:mod:`.host`).

    Its public methods: :meth:`run_until`, :meth:`tick`, :meth:`shutdown`, :meth:`snapshot`,
    :meth:`now`, :meth:`sun`, :meth:`event`, :meth:`reaches`, :meth:`accepted`,
    :meth:`calibrated_model`, :meth:`rechecked`; it is the host of operation's checks
    (:class:`~.operation.checks.CheckHost`) and of the crew's desk
    (:class:`~.operation.crew.CrewHost`).
    """

    def __init__(self, cfg, plant, cameras, clock, store, campaign_id, heliostat_ids=None, **options):
        opts = CampaignOptions(**options)
        # the measurement seam: each board's spot sensor (a camera is wrapped in the camera + vision sensor)
        wrapped = camera_sensors(cfg, {t: c for t, c in cameras.items() if not isinstance(c, SpotSensor)}, opts.flux)
        sensors = {t: (c if isinstance(c, SpotSensor) else wrapped[t]) for t, c in cameras.items()}
        self.cfg, self.campaign_id = cfg, campaign_id
        self.devices = CampaignDevices(plant, sensors, clock, store, abilities_of(plant))
        self.state = st = build_state(cfg, campaign_id, heliostat_ids, opts, list(cameras))
        self.journal = Journal(st, self.devices, opts.listeners)
        self.field = Field(st, self.devices, self.journal)
        self.tracking = Tracking(st, self.devices, self.journal)
        self.ops = OperationChecks(st, self, st.operation, opts.rota_days)
        """Operation's checks and drift detection (:mod:`.operation.checks`)."""
        self.host = Host(st, self.devices, self.journal, self.tracking, self.ops)
        """The visits' host: their writes and fits (:mod:`.host`)."""
        self.frame_passes = 0
        """A live run (:func:`~helicalib.app.live.run_live`): how many times a tick steps again the
        visits waiting for a frame on its way (0: simulations, each visit once a tick)."""
        resume_from_store(self)

    # ------------------------------------------------------------------ time, sun, events
    def now(self) -> float:
        """Plant time now [s] (the controller's estimate while the plant does not answer)."""
        return self.journal.now()

    def sun(self, t_s: float):
        """(vector_enu, azimuth_deg, elevation_deg, rising) at plant time ``t_s`` (SPA, tabulated)."""
        return self.state.sun_table.position(t_s)

    def event(self, kind: str, reason: str, heliostat_id: str | None = None, target_id: str | None = None,
              data: dict | None = None, time_s: float | None = None) -> RunEvent:
        """Record an event and tell the listeners (:meth:`.journal.Journal.event`)."""
        return self.journal.event(kind, reason, heliostat_id, target_id, data=data, time_s=time_s)

    # ------------------------------------------------------------------ the loop
    def run_until(self, end_s: float, progress=None) -> None:
        """Advance plant time to ``end_s`` (virtual or real clock), running the campaign."""
        clock = self.devices.clock
        while True:
            now = clock.now_s()
            if now >= end_s:
                break
            wake = self.tick(now)
            if progress is not None:
                progress(now)
            nxt = min(wake, end_s)
            if nxt > now:
                clock.sleep(nxt - now)

    def tick(self, now: float) -> float:
        """Do everything due at plant time ``now``; returns the plant time of the next thing due."""
        st, field = self.state, self.field
        if st.refresh_round is not None and st.refresh_round.sent is not None:
            # the refresh's batch on its way must be answered before this tick commands one of its heliostats
            self.tracking.land({*st.active, *(h for h, r in st.returning.items() if r.next_check_s <= now)})
        if "scs" in st.faults.lost_links:  # does the plant's SCS answer again?
            self.journal.probe_scs(now)
        if st.operator is not None:  # operator actions (campaign/operation/crew.py): the crew's requests first
            st.operator.apply(self, now)
        if st.stowed and st.active:  # stowed by the weather job while this tick's thread waited on a device
            field.abort_visits(now, "field stowed for wind")
        if now - st.last_poll_s >= WEATHER_POLL_S:
            field.poll_weather(now)
        if now - st.last_refresh_s >= verdicts.TRACKING_REFRESH_S and st.faults.plant_unreachable_since_s is None:
            self.tracking.refresh(now)  # (not into a plant that does not answer: once it answers again)
        if st.retention is not None:
            field.nightly_retention(now)
        if st.returning and st.armed:
            self.tracking.check_returns(now)
        # a live tick steps first the visits waiting for a frame (their reading may be in: on to the
        # next command before the other boards' polls); in simulations none waits so, the order is by wake-up
        due = sorted((not v.frame, v.wake_s, hid) for hid, v in st.active.items() if v.wake_s <= now)
        for _frame, _wake, hid in due:
            v = st.active.get(hid)
            # (a live tick: a visit that _frames_in stepped meanwhile is due again only after its new wait)
            if v is not None and not (self.frame_passes and v.wake_s > now):
                self._step(hid, now)
                if self.frame_passes:       # a live tick: a reading in meanwhile goes on now,
                    self._frames_in(now, 1)  # not after the other boards' polls
        if self.frame_passes:  # a live tick: the visits whose frames came in meanwhile go on now
            self._frames_in(now)
        if st.refresh_round is not None and st.faults.plant_unreachable_since_s is None:
            self.tracking.write_round()  # a slice, after the visits: they never wait for a whole round
        free = self._free_targets()
        gate = None
        if free and not st.stowed:
            gate = field.gate(now)
            if gate.open and st.faults.clock_jump is None and not (st.operator is not None and st.operator.paused):
                for tid in free:
                    while self._start_visit(tid, now):  # a board fills its places (--spots-per-board)
                        pass
        if field.spread_cleanliness and st.faults.plant_unreachable_since_s is None:
            # a live run: a few per tick, never a board's candidates at once; after the choices, so
            # that a read asked now is not on its way while this tick's choices look at its heliostats
            field.refresh_cleanliness(now)
        wakes = [v.wake_s for v in st.active.values()]
        wakes.append(st.last_poll_s + WEATHER_POLL_S)
        if st.refresh_round is not None:
            wakes.append(now + REFRESH_SLICE_S)
        if st.armed and not st.stowed:  # (while stowed, or for a heliostat in a visit, no check is due)
            wakes.extend(r.next_check_s for h, r in st.returning.items() if h not in st.active)
        if self._free_targets() and not st.stowed:
            if gate is not None and not gate.open and gate.night:
                wakes.append(max(now + PLANNER_TICK_S, gate.next_open_s))
            elif self._steady():  # operation with every heliostat accepted: the next check can wait minutes
                wakes.append(now + STEADY_TICK_S)
            else:
                wakes.append(now + PLANNER_TICK_S)
        nxt = min(wakes)
        field.account(now, nxt, gate)
        return max(nxt, now + 1e-3)

    def _frames_in(self, now: float, passes: int | None = None) -> None:
        """Step again, up to :attr:`frame_passes` times (or ``passes``), the visits waiting for a frame
        on its way (:class:`~.frames.FrameWait`): one whose frame came in while the tick stepped the
        others goes on in this tick, not the next (a step of one still waiting costs nothing)."""
        for _ in range(self.frame_passes if passes is None else passes):
            waiting = [hid for hid, v in self.state.active.items() if v.frame]
            if not waiting:
                return
            t = max(now, self.devices.clock.estimate_s())
            for hid in waiting:
                if hid in self.state.active:
                    self._step(hid, t)

    def _steady(self) -> bool:
        """Operation with nothing but checks to plan: every heliostat accepted, none suspected of drift,
        no crew request waiting."""
        st = self.state
        if st.operation is None or self.ops.suspects or (st.operator is not None and st.operator.queue):
            return False
        return bool(np.all(st.book.table.accepted))

    # ------------------------------------------------------------------ starting a visit
    def _free_targets(self) -> list[str]:
        """Boards that can take a visit now."""
        boards = self.state.boards
        return [t.id for t in self.cfg.targets if boards[t.id].has_room]

    def _busy_targets(self) -> list[str]:
        """Boards with a visit under way."""
        return sorted({v.target_id for v in self.state.active.values()})

    def _choose(self, target_id: str, now: float) -> tuple[str | None, bool, bool]:
        """The heliostat that goes on ``target_id`` now (the crew's re-check, a suspected drift's
        check, the planner's choice, an operation check), and whether its visit is a check."""
        st, cfg = self.state, self.cfg
        cands = st.home[target_id]
        busy = list(st.active)
        if st.refresh_round is not None and st.refresh_round.flight:  # its track command on its way: not now
            busy += [hid for hid, _c in st.refresh_round.flight]
        spreads = None
        if st.refine:
            spreads = choices.model_spreads(cfg, st.book, st.models, st.nominal_rows,
                                           [h for h in cands if h not in busy], self.sun(now)[0], now)
        usable = lambda hid: self.reaches(hid, target_id, now)  # noqa: E731
        # operator actions (campaign/operation/crew.py): a queued re-check goes before the planner's choice
        choice = st.operator.next_for(self, target_id, now) if st.operator is not None else None
        crew, check = choice is not None, False
        if choice is None and st.operation is not None:  # a suspected drift is checked again first
            choice = self.ops.suspect_for(target_id, now, busy)
            check = choice is not None
        if choice is None and st.planner_kind == "gaps":
            # a board is lent only to heliostats whose own board is busy (a free own board takes them)
            choice = choices.choose_next_vectorised(
                cfg, st.book, target_id, now, lambda rows: self.field.cleanliness_of_rows(rows, now),
                recheck=st.recheck, busy_heliostats=busy, refine=st.refine, spreads=spreads,
                active_targets=self._busy_targets(), usable=usable)
            if choice is None and st.operation is not None:
                choice = self.ops.check_for(target_id, now, busy)
                check = choice is not None
        elif choice is None:
            busy_boards = set(self._busy_targets())  # once, not per guest
            guests = {h: r for h, r in st.guests.get(target_id, {}).items()
                      if cfg.heliostat(h).target in busy_boards}
            cleanliness = {hid: self.field.cleanliness(hid, now) for hid in [*cands, *guests]}
            choice = choices.choose_next(cfg, st.book, cands, now, cleanliness, planner=st.planner_kind,
                                        recheck=st.recheck, busy_heliostats=busy, target_id=target_id,
                                        guests=guests, usable=usable)
        return choice, check, crew

    def _start_visit(self, target_id: str, now: float) -> bool:
        """Start the visit the planner (or the crew, or a drift check) puts on ``target_id`` now.
        Returns whether one started."""
        st, cfg = self.state, self.cfg
        board = st.boards[target_id]
        if not board.has_room:
            return False
        hid, check, crew = self._choose(target_id, now)
        if hid is None:
            return False
        if not st.armed:
            self.event("note", f"not armed: would send {hid} to {target_id}", hid, target_id, time_s=now)
            st.book.visiting(hid, now)
            st.book.h[hid].cooldown_until_s = now + books.COOLDOWN_VALID_S
            return False
        visit_id = self.devices.store.begin_visit(self.campaign_id, hid, target_id, now)
        shared = not board.empty
        board.join(hid)
        ctx = VisitContext(
            campaign_id=self.campaign_id, visit_id=visit_id, heliostat_id=hid,
            index=cfg.heliostat_index(hid), target=cfg.target(target_id), board=board,
            sensor=self.devices.sensors[target_id], plant=self.devices.plant, now=self.now, sun=self.sun,
            model=st.models[hid],
            # a drift check or a crew's re-check runs its whole correction loop, in the low band too
            settings=st.check_settings if check else replace(st.settings, band_deg=None) if crew else st.settings,
            time_slack_s=lambda: float(self.devices.clock.uncertainty_s), host=self.host,
        )
        st.book.visiting(hid, now)
        self.ops.started(hid, visit_id, st.models[hid], now, check)
        st.returning.pop(hid, None)  # the visit commands it now; it ends with its own return
        st.board_states[target_id] = BoardState(target_id, hid, None, None, now)
        st.active[hid] = RunningVisit(hid, target_id, run_visit(ctx), ctx, now)
        if st.refresh_round is not None:  # the round's corrections for it are older than its visit's
            st.refresh_round.visited.add(hid)
        st.stats.visits += 1
        st.stats.shared_visits += int(shared)
        st.stats.peak_on_board = max(st.stats.peak_on_board, len(board.visitors))
        why = "" if cfg.heliostat(hid).target == target_id else \
            f" (lent; its own board {cfg.heliostat(hid).target} is busy)"
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

    def reaches(self, hid: str, target_id: str, now: float) -> bool:
        """Whether ``hid``'s model puts both the standby point and the centre of ``target_id``
        inside its stroke range now and :data:`SHARE_REACH_S` later (a borrowed board)."""
        target = self.cfg.target(target_id)
        aims = np.array([target.uvw_to_enu(np.asarray(target.standby_uvw_m)), target.center_enu_m], dtype=float)
        model = self.state.models[hid]
        for t in (now, now + SHARE_REACH_S):
            sun = self.sun(t)[0]
            if not all(bool(model.strokes_for_aim(sun, aim).in_range[0]) for aim in aims):
                return False
        return True

    # ------------------------------------------------------------------ stepping and finishing a visit
    def _step(self, hid: str, now: float) -> None:
        v = self.state.active[hid]
        try:
            wait = v.gen.send(None)
        except StopIteration as stop:
            self._finish(hid, stop.value, now)
            return
        except Exception as err:  # noqa: BLE001 - a visit must never take the campaign down
            # the visit could not leave by itself: _finish sends it back to tracking (left is None),
            # keeping the plant's corrections
            self._finish(hid, VisitOutcome(status="fault", reason=f"error_{type(err).__name__}: {err}"), now)
            return
        v.wake_s = now + float(wait)
        v.frame = isinstance(wait, FrameWait)

    def _finish(self, hid: str, out: VisitOutcome, now: float) -> None:
        st, store = self.state, self.devices.store
        v = st.active.pop(hid)
        target_id, ctx = v.target_id, v.ctx
        st.boards[target_id].leave(hid)
        st.stats.outcomes[out.status] = st.stats.outcomes.get(out.status, 0) + 1
        if out.valid_points:
            st.stats.valid_visits += 1
            st.stats.iterations.append(out.iterations)
        first = next((o for o in out.observations if o.valid and o.iteration == 0), None)
        if first is not None:
            # a placement is judged as the model's only if earlier visits gave the model valid points
            modelled = any(p.visit_id != ctx.visit_id for p in st.book.points(hid))
            st.stats.first_errors.append((first.capture_time_s, first.error_mrad, modelled))
        self.tracking.after_leaving(hid, out.left, now)  # the plant's side first: retries must not hang on a record
        store.end_visit(ctx.visit_id, ended_s=now, outcome=out.status, reason=out.reason,
                        iterations=out.iterations, first_error_mrad=out.first_error_mrad,
                        final_error_mrad=out.final_error_mrad)
        st.book.visited(hid, now, out)
        was = st.book.accepted(hid)
        self.ops.finished(hid, target_id, ctx.visit_id, first, was, now)
        verdict = verdicts.verdict(self.cfg, st.book, hid, st.nominal_of(hid), now, st.models[hid])
        store.record_verdict(campaign_id=self.campaign_id, heliostat_id=hid, time_s=now,
                             accepted=verdict.accepted, n_points=verdict.n_points, rms_mrad=verdict.rms_mrad,
                             reasons=list(verdict.reasons),
                             details={"rising_ok": verdict.rising_ok, "setting_ok": verdict.setting_ok,
                                      "window_counts": list(verdict.window_counts)})
        st.book.set_verdict(hid, verdict)
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

    # ------------------------------------------------------------------ summary
    def rechecked(self) -> bool:
        """Re-check mode: every heliostat has been visited and no visit is under way."""
        st = self.state
        return not st.active and all(st.book.h[hid].visits > 0 for hid in st.ids)

    def accepted(self) -> list[str]:
        """The campaign's heliostats whose verdict is accepted, in the campaign's order."""
        st = self.state
        return [hid for hid in st.ids if st.book.accepted(hid)]

    def calibrated_model(self) -> HeliostatModel:
        """The campaign's heliostats' present models, one row each in the campaign's order."""
        st = self.state
        params = np.vstack([st.models[hid].params for hid in st.ids])
        return st.nominal.with_params(params)

    # ------------------------------------------------------------------ stopping
    def shutdown(self, now: float) -> list[str]:
        """Stop every visit under way; each heliostat leaves its board as a finished visit does:
        the beam to the board's standby point first (never across the receiver), then back to
        tracking with the corrections last written (the visits' legs run side by side on the
        clock; each move is bounded by ``settle_timeout_s``). Then every return to tracking not yet
        confirmed is checked once. Returns the heliostats left off tracking: each has an
        ``off_tracking`` event, and the next run on this database retries them first."""
        st, clock = self.state, self.devices.clock
        self.tracking.land()  # the refresh's batch on its way: answered before the beams leave
        leaving = []
        for hid in list(st.active):
            v = st.active.pop(hid)
            v.gen.close()
            ctx, tid = v.ctx, v.target_id
            try:  # a database that cannot be written (the reason of some stops) must not keep a beam on a board
                self.devices.store.end_visit(ctx.visit_id, ended_s=now, outcome="aborted", reason="campaign stopped")
            except Exception as err:  # noqa: BLE001
                if not self.journal.storage_fault(err):
                    raise
            self.event("visit_end", f"{hid} off {tid}: aborted (campaign stopped), leaving via standby", hid, tid,
                       data={"outcome": "aborted"})
            leaving.append([now, hid, ctx, leave_board(ctx, stopping=True)])
        while leaving:
            leaving.sort(key=lambda item: item[0])
            wake, hid, ctx, leg = leaving.pop(0)
            try:  # (after a clock jump, the controller's own clock: the beams still leave via standby)
                t = self.now()
                if wake > t:
                    clock.sleep(wake - t)
                    t = self.now()
                leaving.append([t + float(leg.send(None)), hid, ctx, leg])
            except StopIteration as done:
                if ctx.board is not None:
                    ctx.board.leave(hid)
                self.tracking.after_leaving(hid, done.value, self.journal.safe_now()[0])
            except HelicalibError as err:  # no clock: straight back to tracking, as before a stop
                for _w, h, _c, g in [[wake, hid, ctx, leg], *leaving]:
                    g.close()
                    self.tracking.send_back(h, st.corrections[h], self.journal.safe_now()[0],
                                            why=f"stopping without a clock: {err}")
                leaving = []
        return self.tracking.confirm_returns_once()

    def snapshot(self, now: float) -> Snapshot:
        """The campaign's state at plant time ``now`` (read-only; call it where no tick runs)."""
        return self.field.snapshot(now, self.devices.clock.rate)
