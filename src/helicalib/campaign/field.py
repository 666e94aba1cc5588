"""The field around the visits: weather, stow and resume, the gate, cleanliness reads, nightly
frame retention, the hours counted, and the snapshot a view draws.

The weather is polled every :data:`WEATHER_POLL_S`; a wind above the stow limit stows the whole
field (armed) and ends the visits under way, a calm that holds resumes it. The gate (wind, DNI,
sun, a plant that answers, a fresh weather reading) decides whether a visit may start. A plant
that declares :class:`~helicalib.devices.protocols.BulkCleanliness` gives the cleanliness of many
heliostats in one read.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from helicalib.campaign import choice as choices
from helicalib.campaign import gating as gating_mod
from helicalib.campaign.events import BoardState, Snapshot
from helicalib.campaign.journal import Journal, duration_text
from helicalib.campaign.state import CampaignDevices, CampaignState
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.devices.registers import FieldCommand
from helicalib.errors import HelicalibError, PlantError

WEATHER_POLL_S = 60.0
"""Plant seconds between weather polls (a stow follows within one poll)."""
WEATHER_MAX_AGE_S = 3 * WEATHER_POLL_S
"""A weather reading older than this [plant s] opens no gate: calibration waits for a fresh one."""
CLEANLINESS_MAX_AGE_S = 1800.0
"""The gaps planner re-reads a heliostat's cleanliness register when its last read is this old
[plant s]. Soiling changes over days; a washed mirror counts as clean within half an hour. Re-read
every minute, a 10⁴-heliostat field would cost 10⁴ register reads a minute."""
CLEANLINESS_WARM_ROWS = 128
"""Heliostats never read whose cleanliness a live tick asks at once on the field's reader thread (a
10⁴ field's first reads in about 80 ticks, while a choice would read a board's borrowed candidates)."""
CLEANLINESS_TURN_ROWS = 16
"""Heliostats the field's reader thread reads between pauses (:func:`_in_turns`): about 4 requests."""
CLEANLINESS_TURN_PAUSE_S = 0.002
"""Real seconds the field's reader thread pauses between its turns on the plant's connection."""
CLEANLINESS_SPREAD_ROWS = 16
"""Heliostats whose cleanliness a live tick re-reads at most (:meth:`Field.refresh_cleanliness`): about
4 requests; 10⁴ heliostats every 30 plant minutes at a tick every 2 plant seconds need 11."""


class Field:
    """The campaign's side of the field (module docstring)."""

    def __init__(self, state: CampaignState, devices: CampaignDevices, journal: Journal):
        self.state, self.devices, self.journal = state, devices, journal
        self.spread_cleanliness = False
        """A live run: the gaps planner's cleanliness reads spread over ticks (:meth:`refresh_cleanliness`)."""
        self._clean_reader: ThreadPoolExecutor | None = None
        self._clean_pending: tuple[np.ndarray, Future] | None = None
        self._clean_wanted: np.ndarray | None = None  # rows never read that a choice asked for: read first

    def sun(self, t_s: float):
        return self.state.sun_table.position(t_s)

    # ------------------------------------------------------------------ weather, stow, resume
    def poll_weather(self, now: float, preempt: bool = False) -> None:
        """Read the weather; stow or resume. ``preempt``: from the weather job while a tick waits on a
        slow device (:mod:`helicalib.app.live`): it reads and stows, but leaves the visits and a
        resume to the tick."""
        lock = self.state.weather_lock
        if not lock.acquire(blocking=not preempt):
            return  # the tick's own poll is under way
        try:
            self._weather_now(now, preempt)
        finally:
            lock.release()

    def _weather_now(self, now: float, preempt: bool) -> None:
        st, journal = self.state, self.journal
        with st.lock:
            st.last_poll_s = now
        try:
            w = self.devices.plant.weather()
        except PlantUnreachableError as err:
            journal.plant_failed(f"weather: {err}", link="weather")  # one line for the loss, not one per poll
            return
        except PlantError as err:  # the weather station answered with a refusal: reachable, one line a change
            journal.plant_answered(now, link="weather")
            journal.job_failed("weather station", f"weather: {err}", now)
            return
        st.faults.job_fault.pop("weather station", None)
        with st.lock:
            st.last_weather, st.weather_time_s = w, now
        journal.plant_answered(now, link="weather")
        g = gating_mod.gate_field(w.wind_ms, w.dni_wm2, st.cfg.gating, stowed=st.stowed)
        if g.stow and not st.stowed:
            if preempt:
                self.stow_field(now, g.reason)
            elif self.stow_field(now, g.reason) and st.armed:
                self.abort_visits(now, "field stowed for wind")
        elif st.stowed and not g.stow and not preempt:
            try:
                if st.armed:
                    self.devices.plant.field_command(FieldCommand.RESUME_TRACKING)
                with st.lock:
                    st.stowed = False
                    journal.event("resume", g.reason)
            except PlantError as err:
                journal.event("fault", f"resume: {err}")

    def stow_field(self, now: float, reason: str) -> bool:
        """Stow the whole field (armed) or say what a dry run would do; returns whether it is stowed."""
        st = self.state
        if not st.armed:  # reads and plans only: say what it would do
            with st.lock:
                st.stowed = True
                self.journal.event("note", f"not armed: would stow the field ({reason})", time_s=now)
            return True
        try:
            self.devices.plant.field_command(FieldCommand.STOW_ALL)
        except PlantError as err:
            self.journal.event("fault", f"stow: {err}")
            return False
        with st.lock:
            st.stowed = True
            self.journal.event("stow", reason)
        return True

    def abort_visits(self, now: float, why: str) -> None:
        """End every visit under way as aborted (the field is stowed: no command follows)."""
        st = self.state
        for hid in list(st.active):
            v = st.active.pop(hid)
            v.gen.close()
            st.boards[v.target_id].leave(hid)
            self.devices.store.end_visit(v.ctx.visit_id, ended_s=now, outcome="aborted", reason=why)
            self.journal.event("visit_end", f"{hid} off {v.target_id}: aborted ({why})", hid,
                               v.target_id, data={"outcome": "aborted"})

    # ------------------------------------------------------------------ the gate
    def gate(self, now: float):
        """Judge the gate now (:meth:`judge_gate`); log ``gated``/``ungated`` when it changes."""
        st = self.state
        gate = self.judge_gate(now)
        lost = st.faults.plant_unreachable_since_s is not None
        if st.gate_said != (gate.open, gate.night):
            if not gate.night and not (lost and not gate.open):
                self.journal.event("ungated" if gate.open else "gated", gate.reason, time_s=now)
            st.gate_said = (gate.open, gate.night)
        st.last_gate = gate
        return gate

    def judge_gate(self, now: float):
        """The field's gate from the newest weather reading, the sun and the plant's state (no event)."""
        st = self.state
        _vec, _az, el, _rising = self.sun(now)
        gate = choices.field_gate(st.cfg, st.last_weather, el, now, self.sun, stowed=st.stowed,
                                 elevations=st.sun_table.position_elevations_deg)
        lost = st.faults.plant_unreachable_since_s is not None
        if gate.open and lost:  # (plant_lost said it: no gated line of its own)
            gate = replace(gate, open=False, reason=self.journal.unreachable_reason())
        elif gate.open and (st.weather_time_s is None or now - st.weather_time_s > WEATHER_MAX_AGE_S):
            age = "none yet" if st.weather_time_s is None else f"{duration_text(now - st.weather_time_s)} old"
            gate = replace(gate, open=False, reason=f"no fresh weather reading ({age})")
        return gate

    # ------------------------------------------------------------------ cleanliness
    def cleanliness(self, hid: str, now: float) -> float | None:
        """The plant's cleanliness register of a heliostat, read at most once per weather poll
        (soiling changes over days; a crowded board would otherwise cost a read per candidate per visit)."""
        st = self.state
        hit = st.clean_cache.get(hid)
        if hit is not None and now - hit[0] < WEATHER_POLL_S:
            return hit[1]
        try:
            value = self.devices.plant.status(st.cfg.heliostat_index(hid)).cleanliness
        except PlantError:
            value = None
        st.clean_cache[hid] = (now, value)
        return value

    def cleanliness_of_rows(self, rows: np.ndarray, now: float) -> np.ndarray:
        """:meth:`cleanliness` of the heliostats at ``rows`` of the campaign's ids (NaN where the plant
        gives none), read only for those whose last read is :data:`CLEANLINESS_MAX_AGE_S` old; with
        :attr:`spread_cleanliness` (a live run) only for those never read (the others are re-read a
        few per tick: :meth:`refresh_cleanliness`), and with a plant's bulk reads not even those: they
        are read first on the field's reader thread, and are −inf until they are in (not chosen: NaN
        would say the plant gives none, and the spot's own measure would stand in for it). A
        board's first choice would otherwise read its candidates on the tick's thread (1250 at 10⁴:
        3.5 real seconds during which no other board's visit is stepped)."""
        values, read_at = self.state.clean_rows
        due = now - read_at[rows] >= CLEANLINESS_MAX_AGE_S
        if self.spread_cleanliness:
            due &= ~np.isfinite(read_at[rows])
            self._land()  # a background read that came in since the tick looked: its values count now
            if self.devices.abilities.bulk_cleanliness:
                out = values[rows]
                if due.any():
                    if self._clean_wanted is None:
                        self._clean_wanted = np.zeros(read_at.size, dtype=bool)
                    self._clean_wanted[rows[due]] = True
                    out[due] = -np.inf
                if self._clean_pending is not None:  # a first read on its way: not in yet either
                    out[np.isin(rows, self._clean_pending[0]) & np.isnan(out)] = -np.inf
                return out
        self._read_cleanliness(rows[due], now)
        return values[rows]

    def refresh_cleanliness(self, now: float) -> None:
        """A live tick's share of the cleanliness reads: up to :data:`CLEANLINESS_SPREAD_ROWS` of the
        heliostats read before, the oldest first, once their read is half :data:`CLEANLINESS_MAX_AGE_S`
        old, so that a choice never waits for a board's candidates (1250 at 10⁴: 2.3 s real a choice).
        A plant with bulk reads is read on a thread of the field's while the tick goes on (the values
        taken on the first tick that finds them in, stamped with the plant time they were asked), and
        first the heliostats never read, :data:`CLEANLINESS_WARM_ROWS` at a time, those a choice
        asked for (:meth:`cleanliness_of_rows`) before the others."""
        read_at = self.state.clean_rows[1]
        if not self._land():
            return
        bulk = self.devices.abilities.bulk_cleanliness
        never = np.flatnonzero(~np.isfinite(read_at)) if bulk else read_at[:0].astype(np.int64)
        stale = np.flatnonzero(np.isfinite(read_at) & (now - read_at >= CLEANLINESS_MAX_AGE_S / 2))
        if never.size:  # the field's first reads, in the background, those a choice asked for first
            if self._clean_wanted is not None:
                first = self._clean_wanted[never]
                never = np.concatenate([never[first], never[~first]])
            rows = never[:CLEANLINESS_WARM_ROWS]
        elif stale.size:
            rows = stale[np.argsort(read_at[stale], kind="stable")[:CLEANLINESS_SPREAD_ROWS]]
        else:
            return
        if not bulk:
            self._read_cleanliness(rows, now)
            return
        if self._clean_reader is None:
            self._clean_reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="helicalib-cleanliness")
        read_at[rows] = now
        self._clean_pending = (rows, self._clean_reader.submit(_in_turns, self.devices.plant.cleanliness_many,
                                                               self.state.plant_index[rows]))

    def _land(self) -> bool:
        """Take the values of the background read if it is in; False while it is still on its way."""
        if self._clean_pending is None:
            return True
        rows, fut = self._clean_pending
        if not fut.done():
            return False
        self._clean_pending = None
        values = self.state.clean_rows[0]
        try:
            values[rows] = fut.result()
        except PlantError:
            values[rows] = np.nan
        return True

    def close(self) -> None:
        """The cleanliness reader's thread ends (a live run's end): a read not begun is dropped, one on
        its way is waited for (the plant's connections are closed next)."""
        if self._clean_reader is not None:
            self._clean_reader.shutdown(wait=True, cancel_futures=True)
            self._clean_reader, self._clean_pending = None, None

    def _read_cleanliness(self, due: np.ndarray, now: float) -> None:
        """Read the cleanliness of the heliostats at rows ``due`` into the campaign's table (NaN: none)."""
        st, plant = self.state, self.devices.plant
        values, read_at = st.clean_rows
        if self.devices.abilities.bulk_cleanliness and due.size:  # the in-process simulated plant: one read
            values[due] = plant.cleanliness_many(st.plant_index[due])
            read_at[due] = now
            due = due[:0]
        for r in due:
            try:
                value = plant.status(st.cfg.heliostat_index(st.ids[r])).cleanliness
            except PlantError:
                value = None
            values[r] = np.nan if value is None else value
            read_at[r] = now

    # ------------------------------------------------------------------ nights and hours
    def nightly_retention(self, now: float) -> None:
        """Once a solar day, at night (sun below the low band) with no visit under way, prune the frames."""
        st = self.state
        day = int((now + st.cfg.site.longitude_deg / 15.0 * 3600.0) // 86400.0)
        if st.retained_day is None:
            st.retained_day = day - 1  # a service started at night prunes that night
        if day == st.retained_day or st.active or self.sun(now)[2] >= st.cfg.acceptance.low_band_deg[0]:
            return
        from helicalib.store.retention import retain_frames

        st.retained_day = day
        keep, keep_invalid = st.retention
        try:
            r = retain_frames(self.devices.store, keep, keep_invalid=keep_invalid)
        except HelicalibError as err:
            self.journal.event("fault", f"frame retention: {err}", time_s=now)
            return
        if r.files:
            self.journal.event(
                "note", f"frame retention: {r.files} frame file(s) of {r.observations} observation(s) deleted "
                        f"({r.bytes / 1e6:.1f} MB; frames of the newest {keep} per heliostat"
                        + (" and of every rejected one" if keep_invalid else "") + f" kept, {r.kept_files} files)",
                time_s=now, data=r.as_dict())

    def account(self, now: float, nxt: float, gate) -> None:
        """Count the plant seconds until ``nxt`` as stowed, night or gated hours."""
        st = self.state
        dt = max(0.0, nxt - now)
        if st.stowed:  # stowed hours count in daylight only (the sun above the low band), as gated ones
            if self.sun(now)[2] >= st.cfg.acceptance.low_band_deg[0]:
                st.stats.stowed_s += dt
            else:
                st.stats.night_s += dt
        elif gate is not None and not gate.open and not st.active:
            if gate.night:
                st.stats.night_s += dt
            else:
                st.stats.gated_s += dt

    # ------------------------------------------------------------------ what a view shows
    def snapshot(self, now: float, rate: float) -> Snapshot:
        """The campaign's state at plant time ``now`` (read-only; call it where no tick runs)."""
        st = self.state
        boards = []
        for t in st.cfg.targets:
            board = st.boards[t.id]
            on = ([board.measuring] if board.measuring in board.visitors else []) + \
                [h for h in board.visitors if h != board.measuring]
            if on:
                b = st.board_states.get(t.id, BoardState(t.id, on[0]))
                b = b if b.heliostat_id in on else BoardState(t.id, on[0])
                boards.append(replace(b, others=tuple(h for h in on if h != b.heliostat_id)))
            else:
                boards.append(BoardState(t.id))
        el = self.sun(now)[2]
        # judged afresh from the reading shown (the tick judges it only when a board is free, so its
        # reason could quote an older reading than the wind and DNI beside it)
        gate = None if st.last_gate is None else self.judge_gate(now)
        w = st.last_weather
        accepted = sum(1 for hid in st.ids if st.book.accepted(hid))
        return Snapshot(
            time_s=now, campaign_id=st.campaign_id, armed=st.armed, rate=float(rate),
            boards=tuple(boards), wind_ms=None if w is None else w.wind_ms, dni_wm2=None if w is None else w.dni_wm2,
            stowed=st.stowed, gate_open=None if gate is None else gate.open,
            gate_reason="" if gate is None else gate.reason, night=bool(gate is not None and gate.night),
            sun_elevation_deg=el, heliostats=len(st.ids), accepted=accepted, in_progress=len(st.active),
            waiting=len(st.ids) - accepted - len(st.active), visits=st.stats.visits,
            valid_visits=st.stats.valid_visits, next_band=self.next_band(now),
            off_tracking=tuple(sorted(h for h, r in st.returning.items() if r.failed or h in st.flagged)),
            plant_unreachable_since_s=st.faults.plant_unreachable_since_s, weather_time_s=st.weather_time_s)

    def next_band(self, now: float) -> str:
        """The rising or setting low band (the paper's scarce 5–15°): "rising band now (until 07:10 UTC)"
        or "setting band in 3.2 h"; recomputed at most once a plant minute."""
        st = self.state
        if now - st.band_cache[0] < 60.0:
            return st.band_cache[1]
        lo, hi = st.cfg.acceptance.low_band_deg
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
        st.band_cache = (now, text)
        return text


def _in_turns(read_many, indices: np.ndarray) -> np.ndarray:
    """``read_many(indices)`` a few heliostats (:data:`CLEANLINESS_TURN_ROWS`) at a time, pausing
    between: the reader shares the plant's connection with the tick, and a thread that takes the
    connection's lock again straight after letting it go mostly keeps it (Python's locks are not
    fair): 128 heliostats read at once (some 32 requests) could hold the tick's requests until the
    whole read was done."""
    out = np.empty(len(indices))
    for k in range(0, len(indices), CLEANLINESS_TURN_ROWS):
        if k:
            time.sleep(CLEANLINESS_TURN_PAUSE_S)
        out[k:k + CLEANLINESS_TURN_ROWS] = read_many(indices[k:k + CLEANLINESS_TURN_ROWS])
    return out
