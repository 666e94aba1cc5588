"""Back to tracking: the corrections a heliostat leaves with, the returns the plant confirms, and
the periodic rewrite of every calibrated heliostat's tracking corrections.

A heliostat sent back to tracking stays in :attr:`.state.CampaignState.returning` until the plant
reports state 1 (tracking) or a stow of its own; a return the plant did not take is retried, the
wait doubling up to 10 min, and said once (``off_tracking``), its confirmation once
(``back_to_tracking``). The plant's nominal tracking plus a constant offset follows a calibrated
model only near the sun position the offset was computed for, so the corrections are recomputed
for the whole field every :data:`~helicalib.campaign.verdict.TRACKING_REFRESH_S`: one array write
on a plant that declares :class:`~helicalib.devices.protocols.BulkTracking`, else a round of track
commands sent a slice of :data:`REFRESH_SLICE_S` plant seconds per tick after the visits are
stepped, so a field of 10⁴ heliostats never holds a visit back for the whole round; a plant client
that declares :class:`~helicalib.devices.protocols.ParallelTracking` (Modbus) takes the round, in a
live run, in batches sent while the tick goes on, several commands in flight at once (the tick waits for a batch
only before a command of its own to one of its heliostats: :meth:`Tracking.land`).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from helicalib.campaign import verdict as verdicts
from helicalib.campaign.journal import Journal
from helicalib.campaign.moves import APPROACH_LEAD_S
from helicalib.campaign.state import (
    RETURN_CHECK_S,
    RETURN_RETRY_S,
    CampaignDevices,
    CampaignState,
    RefreshRound,
    Returning,
)
from helicalib.campaign.visit_types import Left
from helicalib.devices.protocols import FieldStowedError
from helicalib.devices.registers import HeliostatState
from helicalib.errors import PlantError
from helicalib.geometry.heliostat import HeliostatModel


REFRESH_SLICE_S = 2.0
"""Plant seconds a tick spends at most on a refresh round's track commands (one status poll's time)."""
REFRESH_BATCH = 96
"""Track commands handed at once to a plant that sends several at a time (``send_tracks``): they go
out while the tick steps the visits, and the next batch follows on the first tick that finds them
all answered."""


class Tracking:
    """The campaign's side of tracking (module docstring)."""

    def __init__(self, state: CampaignState, devices: CampaignDevices, journal: Journal):
        self.state, self.devices, self.journal = state, devices, journal
        self.batches = False
        """A live run on a plant that declares ``ParallelTracking``: rounds go out in batches while the
        ticks go on (:meth:`_write_batches`); else a slice per tick, as a virtual clock needs."""
        self._said_direct = False

    def sun(self, t_s: float):
        return self.state.sun_table.position(t_s)

    # ------------------------------------------------------------------ a visit's end
    def corrections_for(self, hid: str, model: HeliostatModel, now: float) -> np.ndarray | None:
        """Tracking corrections to write as the visit ends; None keeps what the plant has."""
        st = self.state
        if st.recheck or not st.book.points(hid):
            return st.corrections[hid]  # a re-check, or no fitted model yet: the plant keeps what it has
        sun_ahead = self.sun(now + verdicts.TRACKING_REFRESH_S / 2)[0]
        sun_later = self.sun(now + verdicts.TRACKING_REFRESH_S / 2 + APPROACH_LEAD_S)[0]
        corr = verdicts.tracking_corrections(st.cfg, st.nominal_of(hid), model, sun_ahead, sun_later)[0]
        if not np.all(np.isfinite(corr)):
            return st.corrections[hid]
        return corr  # recorded (and kept) once the plant has taken it: see after_leaving

    def after_leaving(self, hid: str, left: Left | None, now: float) -> None:
        """What a heliostat's leaving the board did, recorded after the fact: the corrections the
        plant took (an event), or a failed return to tracking (retried until the plant confirms)."""
        st = self.state
        if left is None:
            self.send_back(hid, st.corrections[hid], now, why="the visit ended without leaving the board")
        elif left.error is not None:  # the retry sends the corrections the plant did not take
            st.returning[hid] = st.returning.get(hid) or Returning(since_s=now, next_check_s=now + RETURN_RETRY_S)
            ret = st.returning[hid]
            ret.failed, ret.last_error = True, left.error
            ret.corrections_mm = left.corrections_mm if left.corrections_mm is not None else st.corrections[hid]
            ret.next_check_s = ret.retry_at(now)
            self.journal.event("off_tracking", f"{hid}: {left.error}; retrying until the plant confirms it tracks", hid)
        else:
            self.written(hid, left.corrections_mm)
            st.returning[hid] = Returning(since_s=now, next_check_s=now + RETURN_CHECK_S,
                                          corrections_mm=st.corrections[hid])

    def written(self, hid: str, corrections) -> None:
        """The plant took ``corrections`` with a track command: keep them, and say so when they are new."""
        st = self.state
        if corrections is None or (st.corrections[hid] is not None and np.array_equal(corrections, st.corrections[hid])):
            return
        st.corrections[hid] = np.asarray(corrections, dtype=float)
        c = st.corrections[hid]
        self.journal.event("tracking_written", f"{hid}: tracking corrections {c[0]:+.2f}, {c[1]:+.2f} mm", hid)

    # ------------------------------------------------------------------ returns the plant confirms
    def send_back(self, hid: str, corrections, now: float, why: str) -> None:
        """Send ``hid`` back to tracking and keep it in ``returning`` until the plant confirms."""
        st = self.state
        ret = st.returning.get(hid) or Returning(since_s=now, next_check_s=now)
        ret.corrections_mm = corrections
        try:
            self.devices.plant.track(st.cfg.heliostat_index(hid), corrections)
        except PlantError as err:
            ret.failed = True
            ret.last_error = str(err)
            ret.next_check_s = ret.retry_at(now)
            st.returning[hid] = ret
            if ret.attempts == 1:
                self.journal.event("off_tracking", f"{hid}: not back to tracking ({why}): {err}; retrying until the "
                                                   "plant confirms", hid)
            return
        self.written(hid, corrections)
        # the first command is checked soon; a repeated one (the plant took it but did not track: a
        # faulted or offline heliostat) waits longer each time, so no heliostat is commanded every 10 s
        ret.next_check_s = now + RETURN_CHECK_S if ret.attempts <= 1 else ret.retry_at(now)
        st.returning[hid] = ret

    def check_returns(self, now: float) -> None:
        """Confirm or retry every return to tracking that is due (state 1 read from the plant)."""
        st = self.state
        if st.stowed:  # the field's resume brings every heliostat back; no track command into a stow
            return
        busy = st.active
        for hid in [h for h, r in st.returning.items() if r.next_check_s <= now and h not in busy]:
            ret = st.returning[hid]
            try:
                state = self.devices.plant.status(st.cfg.heliostat_index(hid)).state
            except PlantError as err:
                ret.last_error, ret.next_check_s = str(err), ret.retry_at(now)
                continue
            if state in (HeliostatState.TRACKING, HeliostatState.STOWED):
                # stowed: the plant's own protection (wind, night) holds it safely; it tracks with the field
                del st.returning[hid]
                if ret.failed or hid in st.flagged:
                    how = ("tracking again" if state == HeliostatState.TRACKING else
                           "stowed by the plant's own logic (safe; it tracks again with the field)")
                    self.journal.event("back_to_tracking", f"{hid}: {how} (confirmed by the plant after "
                                                           f"{ret.attempts} attempt(s), {now - ret.since_s:.0f} s)", hid)
                continue
            if state == HeliostatState.MOVING:
                ret.next_check_s = now + RETURN_CHECK_S
                continue
            ret.attempts += 1
            if not ret.failed:
                ret.failed = True
                self.journal.event("off_tracking", f"{hid}: the plant reports state {state.name.lower()} after a "
                                                   "return to tracking; sending it again until it tracks", hid)
            self.send_back(hid, ret.corrections_mm, now, why=f"state {state.name.lower()}")

    def confirm_returns_once(self) -> list[str]:
        """At a stop: read each unconfirmed return once; a heliostat neither tracking nor on its way
        is recorded ``off_tracking`` (the next run retries it). Returns those heliostats."""
        st = self.state
        if not st.armed:
            return []
        stranded = []
        for hid, ret in sorted(st.returning.items()):
            try:
                state = self.devices.plant.status(st.cfg.heliostat_index(hid)).state
            except PlantError as err:
                state, ret.last_error = None, str(err)
            if state in (HeliostatState.TRACKING, HeliostatState.MOVING) or (
                    state == HeliostatState.STOWED and st.stowed):
                continue
            stranded.append(hid)
            what = ret.last_error if state is None else f"state {state.name.lower()}"
            self.journal.event("off_tracking", f"{hid}: not confirmed back to tracking when the controller stopped "
                                               f"({what}); the next run retries it first", hid)
        st.returning.clear()
        return stranded

    # ------------------------------------------------------------------ the field's corrections
    def refresh(self, now: float) -> None:
        """Recompute the tracking corrections of every calibrated heliostat not in a visit, for the sun
        half a refresh period ahead (module docstring). A plant with bulk tracking takes them in one
        write; any other gets them as a round that :meth:`write_round` sends a slice per tick (a round
        still going when the next is due is superseded, its unwritten heliostats first in the new
        one, so no heliostat waits more than one round behind). Not armed, stowed, at night or in a
        re-check: nothing is written."""
        st = self.state
        st.last_refresh_s = now
        vec, _az, el, _r = self.sun(now + verdicts.TRACKING_REFRESH_S / 2)
        if not st.armed or st.recheck or st.stowed or el < st.cfg.acceptance.low_band_deg[0]:
            return
        ids = [hid for hid in st.ids if hid not in st.active and st.book.points(hid)]
        if not ids:
            return
        rows = [st.index[hid] for hid in ids]
        nominal = st.nominal.subset(rows)  # (once: a subset of the whole field's rows is not free)
        calibrated = nominal.with_params(np.vstack([st.models[h].params for h in ids]))
        later = self.sun(now + verdicts.TRACKING_REFRESH_S / 2 + APPROACH_LEAD_S)[0]
        corr = verdicts.tracking_corrections(st.cfg, nominal, calibrated, vec, later)
        ok = np.flatnonzero(np.all(np.isfinite(corr), axis=1))
        if self.devices.abilities.bulk_tracking:  # the in-process simulated plant: one array write
            self.devices.plant.track_many(st.plant_index[np.asarray(rows, dtype=np.int64)[ok]], corr[ok])
            for k in ok:
                st.corrections[ids[k]] = corr[k]
            return
        items = [(ids[k], corr[k]) for k in ok]
        if st.refresh_round is not None:  # superseded: its heliostats not yet written go first, with these corrections
            self.land()  # (the answers of its batch on the way belong to it)
            late = {hid for hid, _c in st.refresh_round.queue}
            items.sort(key=lambda item: item[0] not in late)  # (stable: the field's order otherwise)
            self._round_done()
        st.refresh_round = RefreshRound(now, deque(items))

    def write_round(self) -> None:
        """Send the refresh round's next slice: track commands until :data:`REFRESH_SLICE_S` plant
        seconds have passed by the controller's own clock (a virtual clock: the whole round), or
        until the next visit's wake-up if sooner, so the visits are stepped again between slices. A
        heliostat that began a visit since the round was due is skipped (its visit ends with
        corrections of its own, newer than the round's); a stow ends the round. A plant that sends
        several at a time gets the round a batch at a time instead (:meth:`_write_batches`)."""
        st, plant, clock = self.state, self.devices.plant, self.devices.clock
        r = st.refresh_round
        if r is None:
            return
        if self.batches:
            self._write_batches(r)
            return
        # a slice ends at the next visit's wake-up if that comes first (its moves are polled on time);
        # one command at least goes out each tick, so a round always advances
        end = min([clock.estimate_s() + REFRESH_SLICE_S, *(v.wake_s for v in st.active.values())])
        while r.queue:
            if st.stowed:  # the weather job stowed the field meanwhile (the plant client refuses the rest)
                r.queue.clear()
                break
            hid, c = r.queue.popleft()
            if hid in st.active or hid in r.visited:  # a visit's own corrections are newer than the round's
                continue
            try:
                plant.track(st.cfg.heliostat_index(hid), c)
                st.corrections[hid] = c
            except FieldStowedError:
                r.queue.clear()
                break
            except PlantError as err:
                r.failed.append((hid, err))
            if clock.estimate_s() >= end:
                break
        if not r.queue:
            self._round_done()

    def _write_batches(self, r: RefreshRound) -> None:
        """:meth:`write_round` on a plant that sends track commands several at a time, while the tick
        goes on: the answers of the batch sent before, once all are in, then the next batch of up to
        :data:`REFRESH_BATCH` (the same skips; a stow ends the round). The round ends with its last
        batch's answers."""
        if r.sent is not None:
            if not r.sent.done():
                return
            self._landed(r)
        st = self.state
        if st.stowed:
            r.queue.clear()
        while r.queue and len(r.flight) < REFRESH_BATCH:
            hid, c = r.queue.popleft()
            if hid not in st.active and hid not in r.visited:
                r.flight.append((hid, c))
        if r.flight:
            r.sent = self.devices.plant.send_tracks([(st.cfg.heliostat_index(hid), c) for hid, c in r.flight])
        elif not r.queue:
            self._round_done()

    def _landed(self, r: RefreshRound) -> None:
        """The answers of ``r``'s batch (waited for): corrections kept, refusals noted, a stow ends the round."""
        st = self.state
        try:
            answers = r.sent.results()
        except Exception as err:  # noqa: BLE001 - never on a tick or a stop: the batch's commands count as failed
            answers = [PlantError(f"track command: {type(err).__name__}: {err}")] * len(r.flight)
        for (hid, c), err in zip(r.flight, answers):
            if err is None:
                st.corrections[hid] = c
            elif isinstance(err, FieldStowedError):
                r.queue.clear()
            else:
                r.failed.append((hid, err))
        why = r.sent.direct
        r.flight, r.sent = [], None
        if why and not self._said_direct:  # said once: the refresh goes slower from now on
            self._said_direct = True
            self.journal.event("note", f"the tracking refresh goes one command at a time on the SCS connection: {why}")

    def land(self, hids=None) -> None:
        """Wait for the refresh's batch on its way, if any (with ``hids``: only if it commands one of
        them), before the tick sends a command of its own to one of its heliostats (a visit's move,
        a return to tracking): never two commands to one heliostat at once."""
        r = self.state.refresh_round
        if r is None or r.sent is None:
            return
        if hids is not None and not any(hid in hids for hid, _c in r.flight):
            return
        self._landed(r)

    def _round_done(self) -> None:
        """End the refresh round: its failed writes said in one line (a dead plant is not one line per heliostat)."""
        failed = self.state.refresh_round.failed
        self.state.refresh_round = None
        if failed:
            names = ", ".join(h for h, _e in failed[:5]) + (f" and {len(failed) - 5} more" if len(failed) > 5 else "")
            self.journal.event("fault", f"tracking corrections not written for {len(failed)} heliostat(s) ({names}): "
                                        f"{failed[0][1]}", failed[0][0] if len(failed) == 1 else None)
