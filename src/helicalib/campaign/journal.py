"""The campaign's journal: events, the store's writes, and the faults of plant, clock and storage.

Every event goes to the store when its kind lasts (:data:`~.events.STORED`) and then to each
listener; every observation and frame a visit makes is written here. A failed write that says the
storage cannot be written counts towards :data:`STORAGE_RETRIES` (a live run then stops); a plant
link that does not answer gives one ``plant_lost`` line per loss and one ``plant_back`` when it
answers again; a clock that jumped gives one fault line. Threads: the live weather job calls in
too, so the state both change is changed under :attr:`.state.CampaignState.lock`.
"""

from __future__ import annotations

from helicalib.campaign.events import STORED, BoardState, RunEvent, iso_utc
from helicalib.campaign.state import CampaignDevices, CampaignState, storage_error
from helicalib.devices.clock import ClockJumpError
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.errors import HelicalibError, PlantError, StorageError

STORAGE_RETRIES = 5
"""Failed writes to the database or its frames folder (full disk, read-only file or folder), with
no observation stored with its frames between them, after which a live run gives up: every beam leaves its board and goes back to
tracking, and the process exits with :data:`helicalib.app.session.EXIT_STORAGE`."""


class Journal:
    """Events, the store's writes and the fault state of one campaign (module docstring)."""

    def __init__(self, state: CampaignState, devices: CampaignDevices, listeners):
        self.state, self.devices = state, devices
        self.listeners: list = list(listeners)
        """Called with every :class:`RunEvent` after the fact (views, JSON lines); a listener that
        raises is dropped from the call, never allowed to stop the campaign."""

    # ------------------------------------------------------------------ time
    def now(self) -> float:
        """Plant time for the visits and a stop's legs: the plant clock's, or, once that clock jumped
        (the plant clock refuses every read after a jump), the controller's own extrapolation of it,
        so a beam on a board still leaves via its standby point."""
        clock = self.devices.clock
        if self.state.faults.clock_jump is None:
            try:
                return clock.now_s()
            except ClockJumpError as err:
                self.clock_jumped(err)
        return clock.estimate_s()

    def safe_now(self) -> tuple[float, str]:
        """(plant time, ``"plant"``), or the controller's own extrapolation of it and ``"controller"``
        when the plant's clock cannot be read (records made during an outage still get a time)."""
        try:
            return self.devices.clock.now_s(), "plant"
        except HelicalibError:
            return self.devices.clock.estimate_s(), "controller"

    # ------------------------------------------------------------------ events and records
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
            self.state.flagged.add(heliostat_id)
        elif kind == "back_to_tracking":
            self.state.flagged.discard(heliostat_id)
        if kind in STORED:
            try:
                self.devices.store.record_event(campaign_id=self.state.campaign_id, time_s=ev.time_s, kind=kind,
                                                reason=reason, heliostat_id=heliostat_id,
                                                data=dict(ev.data, clock=source) if source != "plant" else ev.data or None)
            except Exception as err:  # noqa: BLE001 - a full disk must not break the step that records (a stow)
                if not self.storage_fault(err):
                    raise
        for listener in list(self.listeners):
            try:
                listener(ev)
            except Exception:  # noqa: BLE001 - a broken view (a closed pipe) must not stop the campaign
                pass
        return ev

    def record(self, obs, **frames) -> int:
        """Store an observation (frames first), then tell the listeners. An observation stored with its
        after frames is the write that proves the storage works again (:attr:`.Faults.storage_errors`)."""
        obs_id = self.devices.store.record_observation(obs, **frames)
        if frames.get("after_frames"):
            self.state.faults.storage_errors = 0
        if obs.iteration >= 0:
            boards = self.state.board_states
            boards[obs.target_id] = BoardState(
                obs.target_id, obs.heliostat_id, obs.iteration, obs.error_mrad if obs.valid else None,
                boards.get(obs.target_id, BoardState(obs.target_id)).since_s)
        if self.listeners:
            text = f"{obs.error_mrad:.2f} mrad" if obs.valid and obs.error_mrad is not None else f"invalid: {obs.reason}"
            self.event("measurement", f"{obs.heliostat_id} on {obs.target_id}, placement {obs.iteration}: {text}",
                       obs.heliostat_id, obs.target_id, time_s=obs.capture_time_s,
                       data={"iteration": obs.iteration, "valid": obs.valid, "error_mrad": obs.error_mrad,
                             "observation": obs_id})
        return obs_id

    # ------------------------------------------------------------------ faults of the plant
    def plant_failed(self, err, link: str = "scs") -> bool:
        """The plant did not answer over ``link`` (``"scs"``: its clock, ``"weather"``): the first lost
        link gives ONE ``plant_lost`` event and sets the time the plant is unreachable since; returns
        whether this was news. (A plant that answered with a refusal is reachable: not this.)"""
        f = self.state.faults
        with self.state.lock:
            if link in f.lost_links:
                return False
            since = f.lost_links[link] = self.devices.clock.estimate_s()
            if f.plant_unreachable_since_s is not None:  # another link is lost already: said
                return False
            f.plant_unreachable_since_s = since
            self.event("plant_lost", f"plant not answering ({err}); no visit starts until it answers",
                       time_s=since, data={"since_s": since})
            return True

    def plant_answered(self, now: float, link: str = "scs") -> None:
        """A read over ``link`` succeeded: once no link is lost any more, ONE ``plant_back`` event with
        how long the plant was unreachable."""
        f = self.state.faults
        with self.state.lock:
            if f.lost_links.pop(link, None) is None or f.lost_links:
                return
            since = f.plant_unreachable_since_s
            f.plant_unreachable_since_s = None
            f.said_lost.clear()
            lost = max(0.0, now - since)
            # never stamped before its plant_lost: ``since`` is the controller's estimate, which may run a
            # little ahead of the time the plant gives when it answers again
            self.event("plant_back", f"plant answers again after {duration_text(lost)} unreachable",
                       time_s=max(now, since), data={"lost_s": lost})

    def job_failed(self, job: str, reason: str, time_s: float | None = None) -> None:
        """``job`` failed with ``reason`` (the plant refused, a device said no): a ``fault`` line,
        but only when the reason differs from the job's last one (a job that succeeds clears it),
        not one a tick."""
        with self.state.lock:
            if self.state.faults.job_fault.get(job) == reason:
                return
            self.state.faults.job_fault[job] = reason
        self.event("fault", reason, time_s=time_s)

    def probe_scs(self, now: float) -> None:
        """While the plant's SCS link is lost: one read of its field state; an answer ends the loss."""
        try:
            self.devices.plant.field_state()
        except PlantUnreachableError:
            return
        except PlantError:  # a refusal is an answer
            pass
        self.plant_answered(now, link="scs")

    def said_once(self, job: str) -> bool:
        """Whether ``job`` already said, during this loss of the plant, that the plant failed it
        (its next failures are silent until the plant answers again); marks it as said."""
        with self.state.lock:
            said = self.state.faults.said_lost
            if job in said:
                return True
            said.add(job)
            return False

    def unreachable_reason(self) -> str:
        return f"plant unreachable since {iso_utc(self.state.faults.plant_unreachable_since_s)}"

    # ------------------------------------------------------------------ faults of the storage and the clock
    def storage_fault(self, err: BaseException) -> bool:
        """Count ``err`` (:meth:`storage_failed`) if it says the storage cannot be written
        (:func:`.state.storage_error`); returns whether it did (anything else is the caller's to raise)."""
        if not storage_error(err):
            return False
        self.storage_failed(err)
        return True

    def storage_failed(self, err) -> None:
        """A write to the database failed (full disk, read-only): the first is one ``fault`` line,
        :data:`STORAGE_RETRIES` in a row set the storage lost (a live run then stops)."""
        with self.state.lock:
            f = self.state.faults
            if f.storage_fault_open:  # the fault line's own write failed: the same failure, counted once
                return
            f.storage_errors += 1
            where = str(err) if isinstance(err, StorageError) else \
                f"database {self.devices.store.path}: cannot be written ({type(err).__name__}: {err})"
            if f.storage_errors == 1:
                f.storage_fault_open = True
                try:
                    self.event("fault", f"{where}; trying again", data={"storage": True})
                finally:
                    f.storage_fault_open = False
            elif f.storage_errors >= STORAGE_RETRIES and f.storage_lost is None:
                f.storage_lost = f"{where} after {f.storage_errors} attempts"

    def clock_jumped(self, err) -> None:
        """The plant's clock jumped: ONE fault line; no visit starts (a live run stops)."""
        with self.state.lock:
            f = self.state.faults
            if f.clock_jump is not None:
                return
            f.clock_jump = (f"{err}: no visit starts; the run stops and every beam goes back to tracking. Check the "
                            f"plant's clock{f.clock_jump_hint}")
            self.event("fault", f.clock_jump, time_s=self.devices.clock.estimate_s())


def duration_text(seconds: float) -> str:
    """``42 s``, ``3.5 min``, ``2.1 h``."""
    seconds = float(seconds)
    if seconds < 120.0:
        return f"{seconds:.0f} s"
    if seconds < 7200.0:
        return f"{seconds / 60.0:.1f} min"
    return f"{seconds / 3600.0:.1f} h"
