"""The visits' host: where a visit's writes and fits happen (:class:`~.visit_types.VisitHost`).

A visit holds no store and makes no fit. At the point of its procedure where it needs one, it
calls its host: store an observation with its frames (:meth:`Host.record`), store a frame
(:meth:`Host.save_frame`), add a valid point to the heliostat's book and refit its model
(:meth:`Host.refit`), or ask for the tracking corrections to leave with
(:meth:`Host.corrections`). These are the campaign's only writes of measurements and its only
fits, in this one place. A call that fails is counted as a storage fault when it is one
(:meth:`~.journal.Journal.storage_fault`) and raised into the visit, which ends as a fault and
still leaves the board via standby.
"""

from __future__ import annotations

from helicalib.campaign import verdict as verdicts
from helicalib.campaign.journal import Journal
from helicalib.campaign.operation.checks import OperationChecks
from helicalib.campaign.state import CampaignDevices, CampaignState
from helicalib.campaign.tracking import Tracking
from helicalib.campaign.visit_types import VisitContext
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.store.records import Observation


class Host:
    """The campaign loop's side of its visits (one per campaign)."""

    def __init__(self, state: CampaignState, devices: CampaignDevices, journal: Journal, tracking: Tracking,
                 ops: OperationChecks):
        self.state, self.devices, self.journal, self.tracking, self.ops = state, devices, journal, tracking, ops

    def _served(self, fn, *args, **kw):
        """A host call for a visit; a failure is counted if it is the storage's, and raised into the visit."""
        try:
            return fn(*args, **kw)
        except Exception as err:  # noqa: BLE001 - the visit decides; it must still leave the board
            self.journal.storage_fault(err)
            raise

    def record(self, ctx: VisitContext, observation: Observation, frames: dict) -> int:
        """Store ``observation`` (its frames first); returns its id."""
        return self._served(self.journal.record, observation, **frames)

    def save_frame(self, ctx: VisitContext, data: bytes, iteration: int, capture_time_s: float, kind: str) -> str:
        """Store one frame of the visit; returns its stored path."""
        return self._served(self.devices.store.save_frame, data, campaign_id=self.state.campaign_id,
                            heliostat_id=ctx.heliostat_id, visit_id=ctx.visit_id, iteration=iteration,
                            capture_time_s=capture_time_s, kind=kind)

    def refit(self, ctx: VisitContext, observation: Observation) -> HeliostatModel:
        """Add the valid ``observation`` to the heliostat's book and refit; returns the model the
        visit goes on with."""
        return self._served(self._refit, ctx.heliostat_id, observation)

    def corrections(self, ctx: VisitContext, model: HeliostatModel, stopping: bool):
        """The tracking corrections [mm] to leave with for ``model`` (None: the plant keeps its own);
        a stopped visit leaves with the corrections last written."""
        hid = ctx.heliostat_id
        if stopping:
            return self.state.corrections[hid]
        return self._served(lambda: self.tracking.corrections_for(hid, model, self.journal.now()))

    def _refit(self, hid: str, obs: Observation) -> HeliostatModel:
        st = self.state
        st.book.add(obs)
        if st.recheck:  # a re-check measures the heliostat as it is; one point is no calibration
            return st.models[hid]
        model, fit = verdicts.refit(st.nominal_of(hid), st.book.points(hid), st.models[hid],
                                    prior_mean=self.ops.prior_mean(hid), tilt_rate=self.ops.tilt_rate_of(hid),
                                    earlier=st.book.h[hid].earlier)
        st.models[hid] = model
        if fit is not None:
            st.book.h[hid].fit = fit
            self.devices.store.record_fit(campaign_id=st.campaign_id, heliostat_id=hid, time_s=obs.capture_time_s,
                                          **verdicts.fit_record(fit))
        return model
