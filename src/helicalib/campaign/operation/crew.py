"""A crew's actions from the console, applied by the campaign runner once per decision.

The console (:mod:`helicalib.console`, only in a controller run with ``--arm``) records each
request in the store's ``operator_actions`` table with who asked and when; the runner's tick
calls :meth:`OperatorDesk.apply`, which applies the pending ones, marks each done with what it
did, and logs it as an ``operator`` event with its reason. The kinds:

=================  ====================================================================
``pause``          no new visit starts (visits under way end as usual); the gate is untouched
``resume``         visits start again
``recheck``        each listed heliostat goes next on its own board (before the planner's
                   choice), whatever its acceptance
``repaired``       the heliostat's model is reset to nominal: its points before the repair
                   no longer count, it waits for new ones (a new verdict row says so)
``out_of_service`` the heliostat is never sent to a board (until ``in_service``)
``in_service``     the heliostat is planned again
=================  ====================================================================

The state the actions leave (paused, out of service, repairs) lasts across restarts:
:func:`helicalib.store.history.replay` rebuilds it from the applied rows, and :meth:`OperatorDesk.restore` re-applies it
to a runner that was just built from the store. The desk works through the campaign's public
names only (:class:`CrewHost`).
"""

from __future__ import annotations

import math
from typing import Protocol

from helicalib.campaign.events import RunEvent
from helicalib.campaign.operation.checks import OperationChecks
from helicalib.campaign.state import CampaignDevices, CampaignState
from helicalib.errors import ConfigError
from helicalib.store.history import Standing, replay


class CrewHost(Protocol):
    """What the crew's desk reads and changes of a campaign (the campaign loop,
    :class:`~helicalib.campaign.loop.CampaignRunner`, implements it)."""

    state: CampaignState
    """Its book (points, cool-downs, verdicts), models, nominal models and visits under way."""
    devices: CampaignDevices
    """Its clock (plant time at a restore) and store (stored basis, verdict rows)."""
    ops: OperationChecks
    """Operation's checks: confirmed drifts, the fits' prior and tilt rate, forgetting a heliostat."""

    def reaches(self, hid: str, target_id: str, now: float) -> bool:
        """Whether ``hid``'s model reaches board ``target_id`` (standby and centre) now and a while later."""

    def event(self, kind: str, reason: str, heliostat_id: str | None = None, target_id: str | None = None,
              data: dict | None = None, time_s: float | None = None) -> RunEvent:
        """Record an event (:meth:`helicalib.campaign.journal.Journal.event`)."""


KINDS = {
    "pause": "pause calibration (no new visit; visits under way end as usual)",
    "resume": "resume calibration",
    "recheck": "re-check the listed heliostats next, each on its own board",
    "repaired": "the listed heliostats were repaired: reset their models to nominal",
    "out_of_service": "take the listed heliostats out of service (never sent to a board)",
    "in_service": "put the listed heliostats back in service",
}
"""Every action kind, with what it does (``docs/console.md`` lists them)."""
WITH_HELIOSTATS = frozenset({"recheck", "repaired", "out_of_service", "in_service"})
MAX_WHO_CHARS = 120


def check_request(kind: str, heliostat_ids, known, who: str) -> tuple[str, ...]:
    """The heliostat ids of a valid request; :class:`ConfigError` naming the problem otherwise."""
    if kind not in KINDS:
        raise ConfigError(f"action {kind!r}: unknown (one of {', '.join(KINDS)})")
    if not str(who).strip():
        raise ConfigError("action: 'who' is empty: give your name (it is recorded with the action)")
    if len(str(who)) > MAX_WHO_CHARS:
        raise ConfigError(f"action: 'who' is longer than {MAX_WHO_CHARS} characters")
    ids = tuple(dict.fromkeys(str(h).strip() for h in heliostat_ids or () if str(h).strip()))
    if kind in WITH_HELIOSTATS and not ids:
        raise ConfigError(f"action {kind}: no heliostat named")
    if kind not in WITH_HELIOSTATS and ids:
        raise ConfigError(f"action {kind}: takes no heliostat (got {', '.join(ids)})")
    unknown = [h for h in ids if h not in known]
    if unknown:
        raise ConfigError(f"action {kind}: heliostat {unknown[0]!r} is not in this campaign")
    return ids


class OperatorDesk:
    """The runner's side of the console's actions (one per runner; called from the tick only)."""

    def __init__(self, store, campaign_id: int):
        self.store, self.campaign_id = store, int(campaign_id)
        self.standing = Standing()
        self.queue: list[tuple[str, int]] = []
        """Re-checks not started yet: (heliostat id, action id), oldest first."""

    @property
    def paused(self) -> bool:
        return self.standing.paused

    # ------------------------------------------------------------------ start
    def restore(self, runner: CrewHost) -> None:
        """Re-apply what earlier actions left to a runner just built from the store: paused, out of
        service, and each repaired heliostat's points before its repair dropped (model refitted on
        the rest, or nominal)."""
        from helicalib.campaign import verdict as verdicts
        from helicalib.campaign.basis import stored_basis

        applied = self.store.actions(self.campaign_id, pending=False)
        self.standing = replay(applied)
        st, store, ops = runner.state, runner.devices.store, runner.ops
        now = runner.devices.clock.now_s()
        for hid, t in self.standing.repaired_s.items():
            if hid not in st.book.h:
                continue
            b = st.book.h[hid]
            # repaired after its drift: the nominal again (a drift confirmed after the repair keeps its prior)
            forgot = any(d["heliostat_id"] == hid and d["since_s"] < t for d in ops.drifts)
            b.drifted = b.drifted and not forgot
            ops.forget(hid, prior_too=forgot)
            # those after the repair (and, after a drift since, those between the repair and the drift)
            b.points, _prior, b.earlier = stored_basis(store, st.campaign_id, hid)
            b.fit, b.last_first_error_mrad = None, None
            st.models[hid] = st.nominal_of(hid)
            if b.points:
                st.models[hid], b.fit = verdicts.refit(st.nominal_of(hid), b.points, st.models[hid],
                                                     prior_mean=ops.prior_mean(hid),
                                                     tilt_rate=ops.tilt_rate_of(hid), earlier=b.earlier)
                b.verdict = verdicts.verdict(st.cfg, st.book, hid, st.nominal_of(hid), now, st.models[hid])
            else:
                b.verdict = None
        # re-checks applied (queued) whose visit never started, heliostat by heliostat (the start
        # event of each names it), and not out of service since: queued again
        started = {(int(e.data.get("action", -1)), e.heliostat_id)
                   for e in self.store.events(self.campaign_id, kind="operator")
                   if e.data.get("kind") == "recheck"
                   and (e.data.get("started") or ("(action " in e.reason and e.reason.endswith(" now")))}
        self.queue = [(h, a.id) for a in applied if a.kind == "recheck" for h in a.heliostat_ids
                      if (a.id, h) not in started and h not in self.standing.out_of_service]
        self._hold(runner)

    # ------------------------------------------------------------------ each decision
    def apply(self, runner: CrewHost, now: float) -> None:
        """Apply every pending action (a repair of a heliostat in a visit waits for the visit's end)."""
        pending = self.store.actions(self.campaign_id, pending=True)
        if pending:
            busy = set(runner.state.active)
            for a in pending:
                self._apply_one(runner, a, now, busy)
        self._hold(runner)

    def _apply_one(self, runner: CrewHost, a, now: float, busy: set[str]) -> None:
        ids = list(a.heliostat_ids)
        asked = f"asked by {a.who}"
        if a.kind == "pause":
            self.standing.paused = True
            text = f"calibration paused ({asked}): no new visit starts; visits under way end as usual"
        elif a.kind == "resume":
            self.standing.paused = False
            text = f"calibration resumed ({asked})"
        elif a.kind == "recheck":
            queued = [h for h in ids if h not in self.standing.out_of_service]
            self.queue.extend((h, a.id) for h in queued if (h, a.id) not in self.queue)
            skipped = [h for h in ids if h in self.standing.out_of_service]
            text = (f"re-check of {', '.join(queued) or 'nothing'} queued ({asked}): each goes next on its own board"
                    + (f"; out of service, not queued: {', '.join(skipped)}" if skipped else ""))
        elif a.kind == "repaired":
            if busy & set(ids):
                return  # applied once the visit ends
            for hid in ids:
                self._reset(runner, hid, now, a.who)
            text = (f"{', '.join(ids)} repaired ({asked}): model reset to nominal, earlier points no longer count; "
                    "the plant keeps its present tracking corrections until the next visit writes new ones")
            self.standing.repaired_s.update({h: now for h in ids})
        elif a.kind == "out_of_service":
            self.standing.out_of_service.update(ids)
            self.queue = [(h, i) for h, i in self.queue if h not in self.standing.out_of_service]
            text = (f"{', '.join(ids)} out of service ({asked}): never sent to a board"
                    + (f" (a visit under way ends as usual: {', '.join(sorted(busy & set(ids)))})" if busy & set(ids)
                       else ""))
        else:  # in_service
            self.standing.out_of_service.difference_update(ids)
            for hid in ids:
                runner.state.book.h[hid].cooldown_until_s = 0.0
            text = f"{', '.join(ids)} back in service ({asked})"
        self.store.finish_action(a.id, done_s=now, outcome=text)
        runner.event("operator", text, ids[0] if len(ids) == 1 else None, time_s=now,
                     data={"action": a.id, "kind": a.kind, "heliostats": ids, "who": a.who})

    def _reset(self, runner: CrewHost, hid: str, now: float, who: str) -> None:
        st = runner.state
        b = st.book.h[hid]
        b.points, b.drifted, b.earlier = [], False, None
        b.fit = b.verdict = b.last_first_error_mrad = None
        b.cooldown_until_s = 0.0
        runner.ops.forget(hid)  # a repaired heliostat starts from the nominal again, drift or not
        st.models[hid] = st.nominal_of(hid)
        runner.devices.store.record_verdict(campaign_id=st.campaign_id, heliostat_id=hid, time_s=now, accepted=False,
                                            n_points=0, rms_mrad=None, reasons=[f"repaired: model reset by {who}"],
                                            details={"repaired": True})

    def _hold(self, runner: CrewHost) -> None:
        """Out-of-service heliostats are never eligible (the planners skip a heliostat in cool-down)."""
        book = runner.state.book
        for hid in self.standing.out_of_service:
            if hid in book.h:
                book.h[hid].cooldown_until_s = math.inf

    def next_for(self, runner: CrewHost, target_id: str, now: float) -> str | None:
        """The queued re-check that goes on ``target_id`` now (its own board, not in a visit), or None."""
        busy = set(runner.state.active)
        for k, (hid, action_id) in enumerate(self.queue):
            if (runner.state.cfg.heliostat(hid).target == target_id and hid not in busy
                    and hid not in self.standing.out_of_service and runner.reaches(hid, target_id, now)):
                del self.queue[k]
                text = f"re-check of {hid} (action {action_id}): onto {target_id} now"
                self.store.finish_action(action_id, done_s=now, outcome=f"visit started: {hid} onto {target_id}")
                runner.event("operator", text, hid, target_id, time_s=now,
                             data={"action": action_id, "kind": "recheck", "heliostats": [hid], "started": True})
                return hid
        return None
