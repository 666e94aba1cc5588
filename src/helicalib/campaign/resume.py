"""A campaign's state rebuilt from its store after a restart (also after kill -9).

Valid points, visit counts, fits and verdicts come from the store (a heliostat without a fit in
this campaign starts from its newest fit of any earlier one); visits a killed process left open
are closed as 'interrupted' and their heliostats sent back to tracking; a field the campaign
stowed for wind stays stowed until the wind allows a resume.
"""

from __future__ import annotations

import math

from helicalib.campaign import book as books
from helicalib.campaign import verdict as verdicts
from helicalib.campaign.state import Returning
from helicalib.store import history
from helicalib.store.records import off_tracking


def resume_from_store(runner) -> None:
    """Fill ``runner``'s new state (:class:`~.loop.CampaignRunner`) from its store (module docstring)."""
    st, store, cid, ops = runner.state, runner.devices.store, runner.campaign_id, runner.ops
    now = runner.devices.clock.now_s()
    epochs = ops.load_drifts()
    stored = history.stored_epochs(store, cid) if epochs else {}
    for hid in st.ids:
        b = st.book.h[hid]
        b.drifted = hid in epochs  # its book under the cap after a drift
        observations = store.observations(campaign_id=cid, heliostat_id=hid)
        for obs in observations:
            if obs.capture_time_s >= epochs.get(hid, -math.inf):
                st.book.add(obs)
        if hid in epochs:  # the points before its drifts (after its newest repair), for the fits
            ep = stored.get(hid, history.NO_EPOCH)
            b.earlier = books.earlier_points(observations, ep.floor_s, ep.boundaries)
        visits = store.visits(campaign_id=cid, heliostat_id=hid)
        b.visits = len(visits)
        if visits:
            b.last_visit_s = max(v.started_s for v in visits)
        fit = store.latest_fit(hid, campaign_id=cid) or store.latest_fit(hid)
        if fit is not None:
            st.models[hid] = verdicts.model_from_fit(st.models[hid], fit)
        if st.book.points(hid):  # the fit's covariance (planner) and linearisation (verdict)
            _model, b.fit = verdicts.refit(st.nominal_of(hid), st.book.points(hid), st.models[hid],
                                         prior_mean=ops.prior_mean(hid), tilt_rate=ops.tilt_rate_of(hid),
                                         earlier=b.earlier)
        if visits:
            st.book.set_verdict(hid, verdicts.verdict(st.cfg, st.book, hid, st.nominal_of(hid), now, st.models[hid]))
    # stowed by THIS campaign for wind (its newest stow/resume event is a stow): stay stowed until
    # the wind allows; a plant stowed by its own logic (night, its own wind protection) is left alone
    marks = [e.kind for e in store.events(campaign_id=cid) if e.kind in ("stow", "resume")]
    st.stowed = bool(marks) and marks[-1] == "stow"
    # heliostats a previous process left off tracking, in any campaign of the database (a run, a
    # check, a campaign left for --new-campaign): a visit it was killed in, or a return the plant
    # never confirmed (its newest off_tracking event has no back_to_tracking after it)
    known = {h.id for h in st.cfg.heliostats}
    running = {v.heliostat_id for v in store.visits() if v.outcome == "running"}
    store.close_interrupted_visits(None, now)
    st.flagged = set(off_tracking(store.events())) & known
    if st.armed:
        for hid in sorted((running & known) | st.flagged):
            if st.stowed:  # never a track command into a wind stow: checked once the field resumes
                st.returning[hid] = Returning(since_s=now, next_check_s=now, failed=True)
            else:
                runner.tracking.send_back(hid, None, now, why="left off tracking by the previous run")
