"""Year-round operation inside a campaign run: which check goes on a board, and drift found and confirmed.

:class:`OperationChecks` holds the state of ``helicalib operate`` (and ``simulate --operate``) that
the campaign runner asks at each free board and at each visit's end: the heliostats suspected of
drift and their reference models, the recent checks' residuals (a creep), each board's check time
today against its share, each fitted heliostat's preferred time of day, and the confirmed drifts
with the prior each reopened fit is centred on. The rules themselves (the gain, the budget, the
thresholds) are in :mod:`.rules`; the statistics in :mod:`.drift`. It works on the campaign's
state (:class:`~helicalib.campaign.state.CampaignState`: book, models, nominal) and asks the rest
of a :class:`CheckHost`: whether a heliostat reaches a board, the plant's cleanliness, the sun,
events and the store.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Protocol

import numpy as np

from helicalib.calibration.uncertainty import beam_jacobians_mrad
from helicalib.campaign import book as books
from helicalib.campaign import choice as choices
from helicalib.campaign import verdict as verdicts
from helicalib.campaign.events import RunEvent
from helicalib.campaign.field import Field
from helicalib.campaign.operation import rules as op_rules
from helicalib.campaign.state import CampaignDevices, CampaignState
from helicalib.geometry import error_model as em
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.store import history

SPREAD_KEEP_S = 600.0
"""A model's predicted error at the present sun is reused for this long [plant s]."""


SPREAD_ROWS_PER_PASS = 200_000
"""At most this many model rows (heliostats × suns × (parameters + 1)) in one pass of
:func:`spreads_over_suns` (bounds its memory on a large field)."""


def spreads_over_suns(model: HeliostatModel, covariance: np.ndarray, suns_enu: np.ndarray,
                      aims_enu: np.ndarray) -> np.ndarray:
    """Predicted beam errors [mrad] (M, N) of N fitted models at M sun positions, NaN where the aim
    is out of reach: :func:`helicalib.calibration.fit.beam_spread_mrad` at each sun, the Jacobians of
    many suns in one pass (the day's preferred check times take a day's grid of suns at once)."""
    n, m = len(model), len(suns_enu)
    per = max(1, SPREAD_ROWS_PER_PASS // max(n * (em.P + 1), 1))
    out = np.full((m, n), np.nan)
    for k0 in range(0, m, per):
        jac, ok = beam_jacobians_mrad(model, suns_enu[k0:k0 + per], aims_enu)
        for j in range(jac.shape[1]):  # each sun's as beam_spread_mrad sums it (the same numbers)
            jm = np.ascontiguousarray(jac[:, j])
            var = np.einsum("nip,npq,niq->n", jm, covariance, jm)
            out[k0 + j] = np.where(ok[:, j], np.sqrt(np.maximum(var, 0.0)), np.nan)
    return np.where(np.isfinite(out), out, np.nan)


class CheckHost(Protocol):
    """What operation's checks ask of the campaign besides its state (the campaign loop,
    :class:`~helicalib.campaign.loop.CampaignRunner`, implements it)."""

    devices: CampaignDevices
    """Its ``store``: the stored drifts and observations are read, a reopened fit is written."""
    field: Field
    """The field's side: the plant's cleanliness of heliostats by row (:meth:`.Field.cleanliness_of_rows`)."""

    def reaches(self, hid: str, target_id: str, now: float) -> bool:
        """Whether ``hid``'s model reaches board ``target_id`` (standby and centre) now and a while later."""

    def sun(self, t_s: float) -> tuple[np.ndarray, float, float, bool]:
        """(vector_enu, azimuth_deg, elevation_deg, rising) at plant time ``t_s``."""

    def event(self, kind: str, reason: str, heliostat_id: str | None = None, target_id: str | None = None,
              data: dict | None = None, time_s: float | None = None) -> RunEvent:
        """Record an event (:meth:`helicalib.campaign.journal.Journal.event`)."""


class OperationChecks:
    """Operation's checks and drift detection for one campaign.

    Parameters
    ----------
    state : CampaignState
    host : CheckHost
    mode : {"ranked", "rota"} or None
        None: a campaign (no checks; :meth:`prior_mean` and the drifts of a resumed operation
        still apply).
    rota_days : float
        ``rota``: days between checks of each heliostat.
    """

    def __init__(self, state: CampaignState, host: CheckHost, mode: str | None, rota_days: float = 14.0):
        self.state, self.host = state, host
        self.mode = mode
        self.rota_days = float(rota_days)
        # operation (either rule): the fits model a settling pedestal; a campaign's points are days apart
        self.tilt_rate = bool(mode) and op_rules.TILT_RATE_IN_FITS
        self.suspects: dict[str, list[float]] = {}  # capture times of the checks outside their band, in a row
        self._suspect_ref: dict[str, tuple] = {}  # a suspect's model and time before its first suspicious check
        self._recent: dict[str, deque] = {}  # (time, model, whitened residual) of each heliostat's last checks
        self._prior: dict[str, np.ndarray] = {}  # after a confirmed drift: the fits' prior centre (P,)
        self._visit_model: dict[str, HeliostatModel] = {}  # the model each visit under way started with
        self.drifts: list[dict] = []  # confirmed drifts (this process and, from the store, earlier ones)
        self.checks = 0  # operation checks started
        self._spread_cache: dict[str, tuple] = {}  # hid -> (plant time, fit, spread)
        self._day: int | None = None  # the solar day of the grid and preferences below
        self._day_grid = np.array([])  # that day's times with the sun above the low band (PREFERRED_STEP_S)
        self._preferred: dict[str, float] = {}  # hid -> that day's time at which its model is least sure
        self._board_check_s: dict[str, tuple[int, float]] = {}  # target -> (solar day, seconds of checks)
        self._check_visits: dict[int, float] = {}  # visit id -> start of each operation check under way

    # ------------------------------------------------------------------ the visits' life
    def started(self, hid: str, visit_id: int, model: HeliostatModel, now: float, check: bool) -> None:
        """A visit of ``hid`` started with ``model`` (``check``: an operation check)."""
        self._visit_model[hid] = model
        self.checks += int(check)
        if check:
            self._check_visits[visit_id] = now

    def finished(self, hid: str, target_id: str, visit_id: int, first, was_accepted: bool, now: float) -> None:
        """A visit ended: the board time a check took, then its first placement tested for drift
        (an accepted heliostat's, or a suspect's)."""
        started = self._check_visits.pop(visit_id, None)
        if started is not None:  # the board time this check took, against its board's share of the day
            day = self.day(now)
            prev_day, used = self._board_check_s.get(target_id, (day, 0.0))
            self._board_check_s[target_id] = (day, (used if prev_day == day else 0.0) + max(0.0, now - started))
        started_with = self._visit_model.pop(hid, None)
        if self.mode is not None and (was_accepted or hid in self.suspects) and first is not None \
                and started_with is not None:
            self._drift_test(hid, visit_id, first, started_with, now)

    def accepted_again(self, hid: str, now: float) -> None:
        """``hid`` is accepted again: each of its open drifts is fixed now."""
        for d in self.drifts:
            if d["heliostat_id"] == hid and d.get("fixed_s") is None:
                d["fixed_s"] = now

    def forget(self, hid: str, prior_too: bool = True) -> None:
        """A repaired or replaced heliostat: no suspicion, no creep record, and (``prior_too``) its
        fits centred on the nominal again, without the points from before its drifts."""
        if prior_too:
            self._prior.pop(hid, None)
            self.state.book.h[hid].earlier = None
        self.suspects.pop(hid, None)
        self._suspect_ref.pop(hid, None)
        self._recent.pop(hid, None)

    def load_drifts(self) -> dict[str, float]:
        """Confirmed drifts of this campaign (its ``drift`` events): each heliostat's book counts from
        its newest one (the points before it join the fits in epochs of their own,
        :data:`helicalib.campaign.book.EPOCHS_AFTER_DRIFT`; with those off the fit is centred on the model from before
        it). Returns the epochs (plant time from which the book's points count) by heliostat."""
        epochs: dict[str, float] = {}
        for e in self.host.devices.store.events(campaign_id=self.state.campaign_id, kind="drift"):
            hid = e.heliostat_id
            if hid not in self.state.index or "since_s" not in e.data:
                continue
            epochs[hid] = float(e.data["since_s"])
            prior = e.data.get("prior_params")
            if prior is not None:
                self._prior[hid] = np.asarray(prior, dtype=float)
            self.drifts.append(dict(e.data, heliostat_id=hid, confirmed_s=e.time_s))
        return epochs

    def tilt_rate_of(self, hid: str, points: list | None = None) -> bool:
        """Whether ``hid``'s fit of ``points`` (default its book's) has the steady tilt rate
        (:func:`.rules.fits_tilt_rate`: in operation, but not from a confirmed drift until
        the points reach :data:`.rules.STILL_DAYS_AFTER_DRIFT` past the newest confirmation)."""
        b = self.state.book.h[hid]
        points = b.points if points is None else points
        newest = max((p.capture_time_s for p in points), default=-math.inf)
        confirmed = max((d["confirmed_s"] for d in self.drifts if d["heliostat_id"] == hid), default=-math.inf)
        return op_rules.fits_tilt_rate(bool(self.mode), b.drifted, newest, confirmed, epochs=b.earlier is not None)

    def prior_mean(self, hid: str) -> np.ndarray | None:
        """The centre of the priors of ``hid``'s fits (error parameters (P,)): None for the nominal
        heliostat, also after a confirmed drift whose fits carry the points from before it
        (:data:`helicalib.campaign.book.EPOCHS_AFTER_DRIFT`), else after a drift the model from before it (:mod:`.rules`)."""
        return None if self.state.book.h[hid].earlier is not None else self._prior.get(hid)

    # ------------------------------------------------------------------ choosing a check
    def eligible(self, hids, now: float, busy) -> list[str]:
        """Of ``hids``: fitted, not in a visit, off cool-down, mirror clean enough (the heliostats an
        operation check may take; whether the strokes reach the board is asked of the one chosen).

        Fitted, not only accepted: a heliostat that lost its verdict on accuracy alone (its band
        coverage complete) is asked for nothing by the gaps planner, and without checks its model
        would fall behind the heliostat for good."""
        free = [h for h in hids if h not in busy and self.state.book.h[h].cooldown_until_s <= now
                and self.state.book.h[h].fit is not None]
        if not free:
            return []
        plant = self.host.field.cleanliness_of_rows(np.array([self.state.index[h] for h in free], dtype=np.int64), now)
        out = []
        for hid, c in zip(free, plant):
            if float(c) == -math.inf:  # a live run's first read of it not in yet (Field.cleanliness_of_rows)
                continue
            if not math.isfinite(float(c)):  # the plant gives none: the spot's own measure
                c = self.state.book.h[hid].measured_cleanliness
            if c is not None and math.isfinite(float(c)) and c <= self.state.cfg.gating.cleanliness_min:
                continue
            out.append(hid)
        return out

    def suspect_for(self, target_id: str, now: float, busy) -> str | None:
        """A heliostat of this board suspected of drift, off cool-down: checked again before anything else."""
        for hid in self.state.home[target_id]:
            if hid in self.suspects and hid not in busy and self.state.book.h[hid].cooldown_until_s <= now \
                    and self.host.reaches(hid, target_id, now):
                return hid
        return None

    def day(self, now: float) -> int:
        """The solar day of ``now``; on a new one, the day's sun grid and each fitted heliostat's
        preferred check time (the hour of the day's sun at which its model is least sure) are made."""
        day = int((now + self.state.cfg.site.longitude_deg / 15.0 * 3600.0) // 86400.0)
        if self._day != day:
            self._day = day
            t0 = day * 86400.0 - self.state.cfg.site.longitude_deg / 15.0 * 3600.0
            times = np.arange(t0, t0 + 86400.0, op_rules.PREFERRED_STEP_S)
            el = np.degrees(np.arcsin(np.clip(self.state.sun_table.vector_enu(times)[:, 2], -1.0, 1.0)))
            times = times[el >= self.state.cfg.acceptance.low_band_deg[0]]
            self._day_grid = times
            self._preferred = {}
            fitted = [h for h in self.state.ids if self.state.book.h[h].fit is not None]
            if fitted and times.size:
                model = self.state.nominal_rows(fitted).with_params(np.vstack([self.state.models[h].params
                                                                               for h in fitted]))
                aims = np.array([self.state.cfg.target(self.state.cfg.heliostat(h).target).center_enu_m
                                 for h in fitted], dtype=float)
                suns = np.array([self.state.sun_table.vector_enu(t) for t in times])
                spread = spreads_over_suns(model, np.stack([self.state.book.h[h].fit.covariance for h in fitted]),
                                           suns, aims)
                for j, h in enumerate(fitted):
                    if np.isfinite(spread[:, j]).any():
                        self._preferred[h] = float(times[int(np.nanargmax(spread[:, j]))])
        return day

    def spreads(self, hids: list[str], now: float) -> dict[str, float]:
        """Each model's predicted beam error at the present sun [mrad], kept for
        :data:`SPREAD_KEEP_S` of plant time (the sun moves about 2.5° in 10 min) or until a refit."""
        out, todo = {}, []
        for h in hids:
            kept = self._spread_cache.get(h)
            if kept is not None and now - kept[0] < SPREAD_KEEP_S and kept[1] is self.state.book.h[h].fit:
                out[h] = kept[2]
            else:
                todo.append(h)
        if todo:
            fresh = choices.model_spreads(self.state.cfg, self.state.book, self.state.models, self.state.nominal_rows, todo,
                                         self.host.sun(now)[0], now)
            for h in todo:
                out[h] = fresh.get(h, math.nan)
                self._spread_cache[h] = (now, self.state.book.h[h].fit, out[h])
        return out

    def check_for(self, target_id: str, now: float, busy) -> str | None:
        """The accepted heliostat of this board most worth a check now (:func:`.rules.choose_check`)."""
        # only heliostats a check may take at all (unchecked long enough) are weighed: cheap tests first
        wait = self.rota_days * 86400.0 if self.mode == "rota" else op_rules.MIN_CHECK_INTERVAL_S
        books_h = self.state.book.h
        cands = [h for h in self.state.home[target_id] if now - books_h[h].last_visit_s >= wait]
        if self.mode == "ranked" and cands:
            day = self.day(now)
            used_day, used_s = self._board_check_s.get(target_id, (day, 0.0))
            if used_day == day and used_s >= op_rules.check_budget_s(self._day_grid, now):
                return None  # this board's checks are ahead of their share of the day's sun so far
            overdue = (op_rules.MAX_DAYS_UNCHECKED + 1.0) * 86400.0
            cands = [h for h in cands if now >= self._preferred.get(h, -math.inf)
                     or now - books_h[h].last_visit_s >= overdue]
        cands = self.eligible(cands, now, busy)
        if not cands:
            return None
        last = [books_h[h].last_visit_s for h in cands]
        spreads = self.spreads(cands, now) if self.mode == "ranked" else {}
        for _try in range(3):  # a heliostat whose strokes do not reach the board now is passed over
            hid = op_rules.choose_check(cands, [spreads.get(h, np.nan) for h in cands], last, now,
                                        mode=self.mode, rota_days=self.rota_days)
            if hid is None or self.host.reaches(hid, target_id, now):
                return hid
            k = cands.index(hid)
            del cands[k], last[k]
        return None

    def _drift_test(self, hid: str, visit_id: int, first, started_with: HeliostatModel, now: float) -> None:
        """A check of an accepted heliostat: its first placement against the fit the visit started
        with (:func:`.drift.drift_evidence`); :data:`.rules.CONFIRM_CHECKS` in a row outside the
        band confirm a drift and reopen the calibration (:mod:`.rules`)."""
        from helicalib.campaign.operation.drift import drift_evidence, trend_p_value

        suspect = self.suspects.get(hid)
        if suspect:  # tested against the fit from before the first suspicious check, not one it entered
            started_with, since = self._suspect_ref[hid]
            before = [p for p in self.state.book.points(hid) if p.capture_time_s < since]
            evidence = drift_evidence(self.state.nominal_of(hid), started_with, before, first,
                                      alpha=op_rules.CONFIRM_ALPHA, prior_mean=self.prior_mean(hid),
                                      tilt_rate=self.tilt_rate_of(hid, before), earlier=self.state.book.h[hid].earlier)
        else:
            before = [p for p in self.state.book.points(hid) if p.visit_id != visit_id]
            evidence = drift_evidence(self.state.nominal_of(hid), started_with, before, first,
                                      prior_mean=self.prior_mean(hid), tilt_rate=self.tilt_rate_of(hid, before),
                                      earlier=self.state.book.h[hid].earlier)
        if evidence is None:
            return
        lean = None
        if not suspect:  # a slow creep: checks each inside the band but leaning the same way
            recent = self._recent.setdefault(hid, deque(maxlen=op_rules.TREND_CHECKS))
            recent.append((first.capture_time_s, started_with, evidence["whitened"]))
            if not evidence["drift"] and len(recent) == recent.maxlen:
                p_trend = trend_p_value([w for _t, _m, w in recent])
                if p_trend < op_rules.TREND_ALPHA:
                    lean = (recent[0], p_trend)
        if not evidence["drift"] and lean is None:
            if self.suspects.pop(hid, None):
                self._suspect_ref.pop(hid, None)
                self.host.event("note", f"{hid}: check inside its band again ({evidence['residual_mrad']:.2f} mrad, "
                                   f"band {evidence['band_mrad']:.2f}, p {evidence['p_value']:.2g}); "
                                   "drift not confirmed", hid, data={"drift": evidence}, time_s=now)
            return
        flagged = self.suspects.setdefault(hid, [])
        if not flagged:  # the reference of the confirming check: the fit from before the first sign
            since, model0 = (lean[0][0], lean[0][1]) if lean is not None else (first.capture_time_s, started_with)
            self._suspect_ref[hid] = (model0, since)
            flagged.append(since)
        else:
            flagged.append(first.capture_time_s)
        text = (f"{hid}: check {evidence['residual_mrad']:.2f} mrad off its model, band {evidence['band_mrad']:.2f} "
                f"mrad, p {evidence['p_value']:.2g}"
                + (f"; its last {op_rules.TREND_CHECKS} checks lean the same way (p {lean[1]:.2g})" if lean else ""))
        if len(flagged) < op_rules.CONFIRM_CHECKS:
            self.host.event("note", text + "; suspected drift, checking again", hid, data={"drift": evidence}, time_s=now)
            return
        # confirmed: the points from the first suspicious check on count; the fit centres on the model before
        since = flagged[0]
        del self.suspects[hid]
        self._recent.pop(hid, None)
        started_with = self._suspect_ref.pop(hid)[0]
        b = self.state.book.h[hid]
        earlier = [p for p in b.points if p.capture_time_s < since]
        nominal = self.state.nominal_of(hid)
        prior_model = (verdicts.refit(nominal, earlier, started_with, prior_mean=self.prior_mean(hid),
                                    tilt_rate=self.tilt_rate_of(hid, earlier), earlier=b.earlier)[0]
                       if earlier else started_with)
        # the points since, from the store: as a resumed runner and the report rebuild them (a point the
        # cap thinned away while the earlier points filled the book comes back); and those before it, in
        # epochs of their own (books.EPOCHS_AFTER_DRIFT), from the newest repair on
        stored = self.host.devices.store.observations(campaign_id=self.state.campaign_id, heliostat_id=hid)
        ep = history.stored_epochs(self.host.devices.store, self.state.campaign_id).get(hid, history.NO_EPOCH)
        b.drifted = True  # the smaller cap from now on (books.MAX_VISIT_POINTS_AFTER_DRIFT)
        b.points = books.book_points(stored, since, books.visit_cap(True))
        b.earlier = books.earlier_points(stored, ep.floor_s, ep.boundaries + (since,))
        self._prior[hid] = np.asarray(prior_model.params, dtype=float)[0].copy()
        kept_before = 0 if b.earlier is None else len(b.earlier.points)
        record = {"since_s": since, "confirmed_s": now, "checks": op_rules.CONFIRM_CHECKS, "evidence": evidence,
                  "points_dropped": len(earlier) if b.earlier is None else 0, "points_kept": len(b.points),
                  "points_before_kept": kept_before,
                  "prior_params": [float(x) for x in np.asarray(prior_model.params)[0]]}
        self.drifts.append(dict(record, heliostat_id=hid))  # before the refit: its tilt rate counts from now
        self.state.models[hid], fit = verdicts.refit(nominal, b.points, prior_model, prior_mean=self.prior_mean(hid),
                                             tilt_rate=self.tilt_rate_of(hid), earlier=b.earlier)
        b.fit = fit
        kept = (f"{len(earlier)} earlier points left out" if b.earlier is None else
                f"{kept_before} points from before it kept in epochs of their own")
        self.host.event("drift", text + f"; drift confirmed by {op_rules.CONFIRM_CHECKS} checks: calibration reopened "
                   f"({kept}, {len(b.points)} since)", hid, data=record, time_s=now)
        if fit is not None:
            self.host.devices.store.record_fit(campaign_id=self.state.campaign_id, heliostat_id=hid, time_s=now,
                                               **verdicts.fit_record(fit))
