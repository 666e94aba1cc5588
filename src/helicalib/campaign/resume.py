"""A campaign's state rebuilt from its store after a restart (also after kill -9).

Valid points, visit counts, cool-downs, fits and verdicts come from the store (a heliostat without
a fit in this campaign starts from its newest fit of any earlier one); visits a killed process left open
are closed as 'interrupted' and their heliostats sent back to tracking; a field the campaign
stowed for wind stays stowed until the wind allows a resume.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from types import SimpleNamespace

from helicalib.campaign import book as books
from helicalib.campaign import verdict as verdicts
from helicalib.campaign.state import Returning
from helicalib.store import history
from helicalib.store.records import off_tracking

READ_CHUNK = 500
"""Heliostats whose observations, visits and fits are read back in one query each: a 10⁴ field
in 20 reads of each table instead of 10⁴, and never the whole campaign in memory at once."""
NOT_FINISHED = frozenset({"running", "aborted", "interrupted"})
"""Visit outcomes the loop never judged (cut by a stow, a stop or a killed process): no cool-down."""
PROGRESS_EVERY_S = 5.0
"""Wall seconds between the ``opening`` events that say how far the reading back has come."""


def resume_from_store(runner) -> None:
    """Fill ``runner``'s new state (:class:`~.loop.CampaignRunner`) from its store (module docstring)."""
    st, store, cid, ops = runner.state, runner.devices.store, runner.campaign_id, runner.ops
    now = runner.devices.clock.now_s()
    epochs = ops.load_drifts()
    stored = history.stored_epochs(store, cid) if epochs else {}
    said = time.monotonic()
    for lo in range(0, len(st.ids), READ_CHUNK):
        chunk = st.ids[lo:lo + READ_CHUNK]
        observations_of, visits_of = store.observations_of(cid, chunk), store.visits_of(cid, chunk)
        fits = store.latest_fits(chunk, campaign_id=cid)
        fits.update(store.latest_fits([h for h in chunk if h not in fits]))  # else its newest of any campaign
        for hid in chunk:
            _resume_one(runner, hid, observations_of.get(hid, []), visits_of.get(hid, []), fits.get(hid),
                        epochs, stored, now)
        if time.monotonic() - said >= PROGRESS_EVERY_S and lo + len(chunk) < len(st.ids):
            said = time.monotonic()
            runner.journal.event("opening", f"reading the campaign back: {lo + len(chunk)} of {len(st.ids)} "
                                 "heliostats (points, fits, verdicts)", time_s=now)
    # stowed by THIS campaign for wind (its newest stow/resume event is a stow): stay stowed until
    # the wind allows; a plant stowed by its own logic (night, its own wind protection) is left alone
    marks = [e.kind for e in store.events(campaign_id=cid) if e.kind in ("stow", "resume")]
    st.stowed = bool(marks) and marks[-1] == "stow"
    # heliostats a previous process left off tracking, in any campaign of the database (a run, a
    # check, a campaign left for --new-campaign): a visit it was killed in, or a return the plant
    # never confirmed (its newest off_tracking event has no back_to_tracking after it)
    known = {h.id for h in st.cfg.heliostats}
    running = {v.heliostat_id for v in store.visits(outcome="running")}
    store.close_interrupted_visits(None, now)
    st.flagged = set(off_tracking(store.events())) & known
    if st.armed:
        for hid in sorted((running & known) | st.flagged):
            if st.stowed:  # never a track command into a wind stow: checked once the field resumes
                st.returning[hid] = Returning(since_s=now, next_check_s=now, failed=True)
            else:
                runner.tracking.send_back(hid, None, now, why="left off tracking by the previous run")


def restore_cooldown(b, visits: list, observations: list) -> None:
    """Set the book ``b``'s cool-down and back-off run as :meth:`~.book.Book.visited` left them at
    the end of each of its ``visits`` the loop judged (its valid points from ``observations``)."""
    valid = Counter(o.visit_id for o in observations if o.valid)
    for v in visits:
        if v.outcome not in NOT_FINISHED:
            ended = SimpleNamespace(status=v.outcome, valid_points=valid[v.id])
            b.cooldown_until_s = (v.started_s if v.ended_s is None else v.ended_s) + books.cooldown_s(b, ended)


def _resume_one(runner, hid: str, observations: list, visits: list, fit, epochs: dict, stored: dict,
                now: float) -> None:
    """One heliostat's book, model, fit and verdict from its stored ``observations``, ``visits`` and
    newest ``fit`` (None: none in any campaign)."""
    st, ops = runner.state, runner.ops
    b = st.book.h[hid]
    b.drifted = hid in epochs  # its book under the cap after a drift
    for obs in observations:
        if obs.capture_time_s >= epochs.get(hid, -math.inf):
            st.book.add(obs)
    if hid in epochs:  # the points before its drifts (after its newest repair), for the fits
        ep = stored.get(hid, history.NO_EPOCH)
        b.earlier = books.earlier_points(observations, ep.floor_s, ep.boundaries)
    b.visits = len(visits)
    if visits:
        b.last_visit_s = max(v.started_s for v in visits)
    restore_cooldown(b, visits, observations)
    if fit is not None:
        st.models[hid] = verdicts.model_from_fit(st.models[hid], fit)
    if st.book.points(hid):  # the fit's covariance (planner) and linearisation (verdict)
        _model, b.fit = verdicts.refit(st.nominal_of(hid), st.book.points(hid), st.models[hid],
                                     prior_mean=ops.prior_mean(hid), tilt_rate=ops.tilt_rate_of(hid),
                                     earlier=b.earlier)
    if visits:
        st.book.set_verdict(hid, verdicts.verdict(st.cfg, st.book, hid, st.nominal_of(hid), now, st.models[hid]))
