"""Campaign bookkeeping and the policy calls of the runner.

:class:`Book` holds what the runner knows of each heliostat (valid points, visits, verdict,
cool-down); the functions here turn it into the inputs of the pure policy modules
(:mod:`.gating`, :mod:`.planner`, :mod:`helicalib.calibration.acceptance`) and of the error-model
fit, and back.

Acceptance points and their errors (our reading of the paper's section 2.4, see docs/campaign.md):
a *point* is a valid visit (its last valid measurement: the heliostat's beam after the loop);
its *error* is how far the heliostat's model, fitted **without that visit**, puts the beam from
where it was seen (leave-one-visit-out): an honest, out-of-sample tracking error. In-sample
residuals of a 12-parameter fit to a handful of points would flatter every heliostat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from helicalib.calibration import acceptance
from helicalib.calibration.fit import fit_error_model, leave_out_params
from helicalib.calibration.sun_days import sun_days
from helicalib.campaign import gating as gating_mod
from helicalib.campaign import planner as planner_mod
from helicalib.geometry import error_model as em
from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel, tracking_approach

FIELD_CURSOR = "*"
"""``Book.cursor`` key of the heliostat that last went on any board (field-wide round robin)."""
COOLDOWN_INVALID_S = 1800.0
"""After a visit without a valid point a heliostat waits this long [plant s] before its next try."""
COOLDOWN_VALID_S = 1200.0
"""After a valid visit the heliostat waits this long (the next point should see another sun)."""
FIT_LOSS = "soft_l1"
MAX_VISIT_POINTS = 240
"""A heliostat's fits and verdicts stand on at most this many visits' points (the database keeps
every observation): a year of operation adds a check every few days, and memory and fit time must
not grow without end. Past it, the visit whose sun position lies nearest another's goes (the oldest
of a tie; never the newest): the spread of sun positions, which matters more to a fit than the
count or the age of its points, is kept. Measured over 210 days of operation (docs/benchmarks.md):
60 visits held the undrifted heliostats' sky-wide error at 0.66 mrad, 240 at 0.39."""
MAX_VISIT_POINTS_AFTER_DRIFT = 30
"""The cap of a heliostat's book since its confirmed drift (until a repair resets it); the points from
before the drift join its fits apart (:data:`EPOCHS_AFTER_DRIFT`). A drift may go on after it is
confirmed (a creep), and the fits' steady tilt rate cannot follow it, so the points of the moving
heliostat must leave the newest epoch. Under a small cap the thinning, which drops the older of
two visits at the same sun position, replaces them by newer ones. Measured over 210 days with four
creeps (docs/benchmarks.md): under 240 the creep's last days held the drifted models 2-8 mrad off
over the sky (field 1.47 mrad); 60 after a drift still left one at 6.9 (field 1.24); 30 gave
1.0-2.3 (field 0.67)."""
EPOCHS_AFTER_DRIFT = True
"""After a confirmed drift a heliostat's fits keep its points from before the drift (up to
:data:`MAX_VISIT_POINTS` less :data:`MAX_VISIT_POINTS_AFTER_DRIFT` visits, :class:`Earlier`), each
epoch between two confirmed drifts with its own pedestal tilts and actuator zero offsets
(``point_epoch`` of :func:`helicalib.calibration.fit.fit_error_model`): a drift changes those, not
the heliostat's build, so the months of points before it keep informing the rest of the model. The
fits are then centred on the nominal heliostat (the earlier points carry what the model before the
drift knew) and keep the steady tilt rate, which the earlier epochs' points pin down. The acceptance
verdict and the drift tests still judge the visits since the drift. False: the points before the
newest drift are dropped, as until version 2026-11-27 (docs/operation.md)."""
_BACKLASH = [em.index(n) for n in em.BACKLASH]


@dataclass
class HeliostatBook:
    points: list = field(default_factory=list)          # valid observations (all iterations)
    visits: int = 0
    cooldown_until_s: float = 0.0
    last_first_error_mrad: float | None = None
    verdict: acceptance.AcceptanceVerdict | None = None
    measured_cleanliness: float | None = None      # newest cleanliness measured from a spot
    measured_at_s: float = -math.inf
    fit: object | None = None                       # newest FitResult over ``points``; None before one
    last_visit_s: float = -math.inf                 # start of its newest visit (operation: time since a check)
    drifted: bool = False                           # since a confirmed drift (until a repair): the smaller cap
    earlier: Earlier | None = None                  # after a drift: the points before it, for the fits (epochs)

    def __setattr__(self, name: str, value) -> None:
        object.__setattr__(self, name, value)
        sink = self.__dict__.get("_sink")
        if sink is not None and name in PlanTable.TRACKED:  # keep the book's planning arrays current
            sink[0].update(sink[1], self)


class Book:
    """Per-heliostat campaign state, rebuilt from the store on resume."""

    def __init__(self, cfg, heliostat_ids):
        self.cfg = cfg
        self.h = {hid: HeliostatBook() for hid in heliostat_ids}
        self.cursor: dict[str, str | None] = {}
        self._days: tuple = ()
        self._days_span = (math.inf, -math.inf)
        self.table = PlanTable(cfg, list(self.h))
        for row, b in enumerate(self.h.values()):
            object.__setattr__(b, "_sink", (self.table, row))

    def add(self, obs) -> None:
        b = self.h[obs.heliostat_id]
        if located(obs):
            b.points = keep_point(b.points, obs, visit_cap(b.drifted))  # assigned: the planning arrays follow
        measured = getattr(obs, "cleanliness_measured", None)
        if measured is not None and obs.capture_time_s >= b.measured_at_s:
            b.measured_cleanliness, b.measured_at_s = float(measured), obs.capture_time_s

    def points(self, hid: str) -> list:
        return self.h[hid].points

    def visiting(self, hid: str, now_s: float) -> None:
        self.h[hid].visits += 1
        self.h[hid].last_visit_s = now_s
        self.cursor[self.cfg.heliostat(hid).target] = hid
        self.cursor[FIELD_CURSOR] = hid

    def visited(self, hid: str, now_s: float, outcome) -> None:
        b = self.h[hid]
        b.cooldown_until_s = now_s + (COOLDOWN_VALID_S if outcome.valid_points else COOLDOWN_INVALID_S)
        if outcome.first_error_mrad is not None and outcome.observations and outcome.observations[0].valid:
            b.last_first_error_mrad = outcome.first_error_mrad

    def set_verdict(self, hid: str, verdict) -> None:
        self.h[hid].verdict = verdict

    def accepted(self, hid: str) -> bool:
        v = self.h[hid].verdict
        return bool(v is not None and v.accepted)

    def days(self, now_s: float):
        """Solar days around ``now_s`` (cached; extended as the campaign goes on)."""
        lo, hi = self._days_span
        if not (lo + 86400.0 <= now_s <= hi - 2 * 86400.0):
            a = self.first_time(now_s) - 86400.0
            b = now_s + 5 * 86400.0
            acc = self.cfg.acceptance
            self._days = sun_days(self.cfg.site, a, b, acc.low_band_deg, acc.high_elevation_deg, step_s=120.0)
            self._days_span = (a, b)
        return self._days

    def first_time(self, default: float) -> float:
        times = [p.capture_time_s for b in self.h.values() for p in b.points]
        return min(times + [default])


def located(obs) -> bool:
    """Whether ``obs`` is a point for the fits: valid, with a finite spot on the board."""
    return bool(obs.valid and obs.spot_enu_m is not None and all(map(math.isfinite, obs.spot_enu_m)))


def visit_cap(drifted: bool) -> int:
    """The visits a heliostat's book keeps: :data:`MAX_VISIT_POINTS`, or since a confirmed drift
    :data:`MAX_VISIT_POINTS_AFTER_DRIFT`."""
    return MAX_VISIT_POINTS_AFTER_DRIFT if drifted else MAX_VISIT_POINTS


def keep_point(points: list, obs, cap: int | None = None) -> list:
    """``points`` (a heliostat's book) with the point ``obs`` added, thinned to ``cap`` visits
    (default :data:`MAX_VISIT_POINTS`; :func:`thin_visits`) when it makes one visit too many."""
    cap = MAX_VISIT_POINTS if cap is None else int(cap)
    points = points + [obs]
    if len({p.visit_id for p in points}) > cap:
        points = thin_visits(points, cap)
    return points


def book_points(observations, since_s: float = -math.inf, cap: int | None = None) -> list:
    """The points a campaign's book holds of one heliostat, from its stored ``observations`` (in
    the store's order, the order they came in): the located ones (:func:`located`) captured at or
    after ``since_s`` (the epoch of its newest confirmed drift or repair), each added as
    :meth:`Book.add` adds it under ``cap`` (:func:`visit_cap`), so thinned where the running book
    was thinned. The runner's book after a drift or a repair, the report's refit and ``helicalib
    check``'s drift test all stand on these."""
    points: list = []
    for o in observations:
        if o.capture_time_s >= since_s and located(o):
            points = keep_point(points, o, cap)
    return points


@dataclass(frozen=True)
class Epochs:
    """What a heliostat's confirmed drifts and operator repairs leave for its fits (:func:`stored_epochs`)."""

    since_s: float = -math.inf
    """The book's points count from here: the newest drift's epoch, or just after the newest repair."""
    prior: np.ndarray | None = None
    """The model from before the newest drift (P,) (None for the nominal heliostat, also when a repair
    came after the drift): the fits' prior centre when :data:`EPOCHS_AFTER_DRIFT` is off."""
    drifted: bool = False
    """Since a confirmed drift (until a repair): the book's smaller cap (:func:`visit_cap`)."""
    confirmed_s: float = -math.inf
    """The newest drift's confirmation (:func:`.operation.fits_tilt_rate`)."""
    floor_s: float = -math.inf
    """Just after the newest repair: no point before it counts."""
    boundaries: tuple = ()
    """The epochs (``since_s``) of the drifts confirmed after ``floor_s``, oldest first."""


NO_EPOCH = Epochs()
""":func:`stored_epochs`' entry of a heliostat without a confirmed drift or a repair."""


@dataclass(frozen=True)
class Earlier:
    """A drifted heliostat's points from before its newest confirmed drift (after its newest repair),
    thinned as they came in to :data:`MAX_VISIT_POINTS` less :data:`MAX_VISIT_POINTS_AFTER_DRIFT`
    visits, with the epoch of each (1: between the two newest drifts, 2: the one before, ...)."""

    points: list
    epoch: np.ndarray


def earlier_points(observations, floor_s: float, boundaries) -> Earlier | None:
    """:class:`Earlier` from a heliostat's stored ``observations`` (in the store's order): the located
    ones from ``floor_s`` up to the newest of ``boundaries`` (the confirmed drifts' epochs, oldest
    first). None without a boundary, without such a point, or with :data:`EPOCHS_AFTER_DRIFT` off."""
    if not EPOCHS_AFTER_DRIFT or not boundaries:
        return None
    bounds = np.sort(np.asarray(boundaries, dtype=float))
    points = book_points([o for o in observations if o.capture_time_s < bounds[-1]], floor_s,
                         MAX_VISIT_POINTS - MAX_VISIT_POINTS_AFTER_DRIFT)
    if not points:
        return None
    t = np.array([p.capture_time_s for p in points], dtype=float)
    return Earlier(points, (bounds[None, :] > t[:, None]).sum(axis=1).astype(int))


def fit_size(points: list, earlier: Earlier | None) -> int:
    """The observations a fit of ``points`` (and ``earlier``) stands on (a stored fit's ``n_points``)."""
    return len(points) + (len(earlier.points) if earlier is not None else 0)


def stored_epochs(store, campaign_id: int, until_s: float = math.inf) -> dict:
    """``{heliostat id: Epochs}`` for the heliostats of campaign ``campaign_id`` with a confirmed drift
    (its ``drift`` events) or an operator repair by ``until_s``, as the runner applies them on
    resume (:class:`Epochs`). Read once for a whole field."""
    from helicalib.campaign.operation.crew import replay

    drifts: dict[str, list] = {}
    for e in store.events(campaign_id=campaign_id, kind="drift"):
        if e.heliostat_id is not None and "since_s" in e.data and e.time_s <= until_s:
            drifts.setdefault(e.heliostat_id, []).append(dict(e.data, confirmed_s=e.time_s))
    out = {}
    for hid, ds in drifts.items():
        p = ds[-1].get("prior_params")
        out[hid] = Epochs(since_s=float(ds[-1]["since_s"]), prior=None if p is None else np.asarray(p, dtype=float),
                          drifted=True, confirmed_s=max(float(d["confirmed_s"]) for d in ds),
                          boundaries=tuple(sorted(float(d["since_s"]) for d in ds)))
    done = [a for a in store.actions(campaign_id, pending=False) if a.done_s <= until_s]
    for hid, repaired in replay(done).repaired_s.items():
        ep = out.get(hid, NO_EPOCH)
        prior, drifted = ep.prior, ep.drifted
        if any(float(d["since_s"]) < repaired for d in drifts.get(hid, ())):  # as OperatorDesk.restore
            prior, drifted = None, False
        floor = math.nextafter(float(repaired), math.inf)
        out[hid] = Epochs(since_s=max(ep.since_s, floor), prior=prior, drifted=drifted, confirmed_s=ep.confirmed_s,
                          floor_s=floor, boundaries=tuple(b for b in ep.boundaries if b >= floor))
    return out


def stored_basis(store, campaign_id: int, heliostat_id: str, until_s: float = math.inf, epochs: dict | None = None):
    """``(points, prior_mean, earlier)``: what the fit of ``heliostat_id`` that campaign ``campaign_id``
    made at ``until_s`` stood on, from the store, as the runner rebuilds it on resume: the points
    of :func:`book_points` since its epoch (:func:`stored_epochs`, pass them when asking for many
    heliostats) under its cap, the centre of the fit's prior (None: the nominal heliostat), and the
    points from before its newest drift (:func:`earlier_points`; None without)."""
    if epochs is None:
        epochs = stored_epochs(store, campaign_id, until_s)
    ep = epochs.get(heliostat_id, NO_EPOCH)
    obs = [o for o in store.observations(campaign_id=campaign_id, heliostat_id=heliostat_id)
           if o.capture_time_s <= until_s]
    earlier = earlier_points(obs, ep.floor_s, ep.boundaries)
    return book_points(obs, ep.since_s, visit_cap(ep.drifted)), (ep.prior if earlier is None else None), earlier


def thin_visits(points: list, keep: int) -> list:
    """``points`` without the visits that are most redundant in sun position, down to ``keep``
    visits (:func:`visit_cap`); the newest visit always stays."""
    by_visit: dict = {}
    for p in points:
        by_visit.setdefault(p.visit_id, []).append(p)
    visits = list(by_visit)
    if len(visits) <= keep:
        return list(points)
    last = [max(by_visit[v], key=lambda p: p.capture_time_s) for v in visits]
    sun = np.array([p.sun_enu for p in last], dtype=float)
    times = np.array([p.capture_time_s for p in last])
    alive = np.ones(len(visits), dtype=bool)
    cos = np.clip(sun @ sun.T, -1.0, 1.0)
    np.fill_diagonal(cos, -2.0)
    newest = int(np.argmax(times))
    while alive.sum() > keep:
        live = np.flatnonzero(alive)
        nearest = cos[np.ix_(live, live)].max(axis=1)  # the closest other visit's sun, as a cosine
        cand = [i for i in range(live.size) if live[i] != newest]
        j = max(cand, key=lambda i: (nearest[i], -times[live[i]]))
        alive[live[j]] = False
    kept = {visits[i] for i in np.flatnonzero(alive)}
    return [p for p in points if p.visit_id in kept]


class PlanTable:
    """The gaps planner's view of a campaign's heliostats as arrays, one row per heliostat.

    A :class:`Book` keeps it current: every write to a :class:`HeliostatBook` field in
    :data:`TRACKED` (and every point added) updates that heliostat's row, so a decision reads
    arrays instead of walking the field (:func:`choose_next_vectorised`). Verdicts enter as the
    key of their needs (:func:`helicalib.calibration.acceptance.needs_key`): heliostats that lack
    the same things share one entry of :attr:`needs`, timed once per decision.

    Rows without a verdict have need id ``BLANK`` (no point yet: every such heliostat lacks the
    same) or ``UNJUDGED`` (points but no verdict yet: judged one by one when they are candidates).
    """

    TRACKED = frozenset({"visits", "cooldown_until_s", "last_first_error_mrad", "verdict",
                         "measured_cleanliness", "points"})
    BLANK, UNJUDGED = -1, -2

    def __init__(self, cfg, ids: list[str]):
        self.cfg = cfg
        self.ids = list(ids)
        self.row = {h: i for i, h in enumerate(self.ids)}
        n = len(self.ids)
        self.visits = np.zeros(n, dtype=np.int64)
        self.cooldown_until_s = np.zeros(n)
        self.predicted_error_mrad = np.full(n, np.nan)   # NaN: no model yet
        self.accepted = np.zeros(n, dtype=bool)
        self.need = np.full(n, self.BLANK, dtype=np.int64)
        self.measured_cleanliness = np.full(n, np.nan)
        self.id_rank = np.argsort(np.argsort(np.array(self.ids, dtype=object)))  # ties broken by id
        self.needs: list[tuple] = []        # need id -> the needs (acceptance.Need) of that key
        self._need_ids: dict[tuple, int] = {}
        targets = [t.id for t in cfg.targets]
        self.target_index = {t: k for k, t in enumerate(targets)}
        self.own = np.array([self.target_index[cfg.heliostat(h).target] for h in self.ids], dtype=np.int64)
        self.own_rows = {t: np.flatnonzero(self.own == k) for t, k in self.target_index.items()}
        self.guest_rows = {t: np.zeros(0, dtype=np.int64) for t in targets}
        self.guest_rank = {t: np.zeros(0, dtype=np.int64) for t in targets}

    def set_guests(self, guests: dict[str, dict[str, int]]) -> None:
        """The heliostats that may borrow each target and the board's rank for them
        (:func:`shared_targets`)."""
        for t, by_hid in guests.items():
            rows = [self.row[h] for h in by_hid if h in self.row]
            self.guest_rows[t] = np.array(rows, dtype=np.int64)
            self.guest_rank[t] = np.array([by_hid[self.ids[r]] for r in rows], dtype=np.int64)

    def update(self, row: int, b: HeliostatBook) -> None:
        """Copy one heliostat's book into its row."""
        self.visits[row] = b.visits
        self.cooldown_until_s[row] = b.cooldown_until_s
        self.predicted_error_mrad[row] = np.nan if b.last_first_error_mrad is None else b.last_first_error_mrad
        self.measured_cleanliness[row] = np.nan if b.measured_cleanliness is None else b.measured_cleanliness
        v = b.verdict
        if v is None:
            self.accepted[row] = False
            self.need[row] = self.UNJUDGED if b.points else self.BLANK
        else:
            self.accepted[row] = bool(v.accepted)
            self.need[row] = self.need_id(acceptance.needs(v, self.cfg.acceptance))

    def need_id(self, wanted: tuple) -> int:
        key = tuple((nd.kind, nd.window, nd.n_windows) for nd in wanted)
        k = self._need_ids.get(key)
        if k is None:
            k = self._need_ids[key] = len(self.needs)
            self.needs.append(wanted)
        return k


# ---------------------------------------------------------------------------------- gate
@dataclass(frozen=True)
class Gate:
    open: bool
    night: bool
    stow: bool
    reason: str
    next_open_s: float


def field_gate(cfg, weather, elevation_deg: float, now_s: float, sun, stowed: bool = False,
               elevations=None) -> Gate:
    """Whether visits may start now: the sun above the low band's lower edge, wind and DNI allow.
    ``elevations(times)``: the elevations ``sun`` gives at many instants in one call (optional)."""
    lo = cfg.acceptance.low_band_deg[0]
    if elevation_deg < lo:
        return Gate(False, True, False, f"sun {elevation_deg:.1f}° below {lo:g}°",
                    _next_sun_above(sun, now_s, lo, elevations))
    if weather is None:
        return Gate(False, False, False, "no weather reading yet", now_s)
    g = gating_mod.gate_field(weather.wind_ms, weather.dni_wm2, cfg.gating, stowed=stowed)
    return Gate(g.calibrate, False, g.stow, g.reason, now_s)


def _next_sun_above(sun, now_s: float, level_deg: float, elevations=None) -> float:
    """10 min before the first of the next 144 ten-minute steps with the sun at ``level_deg`` or
    higher (``now_s`` + 1 day if none); ``elevations``: all steps in one call (the same answer)."""
    if elevations is not None:  # a night tick every minute: one array call, not 144 look-ups
        steps = now_s + 600.0 * np.arange(1, 24 * 6 + 1, dtype=float)
        hit = np.flatnonzero(np.asarray(elevations(steps)) >= level_deg)
        return float(steps[hit[0]] - 600.0) if hit.size else now_s + 86400.0
    for k in range(1, 24 * 6 + 1):
        t = now_s + 600.0 * k
        if sun(t)[2] >= level_deg:
            return t - 600.0
    return now_s + 86400.0


# ---------------------------------------------------------------------------------- planning
def choose_next(cfg, book: Book, candidates, now_s: float, cleanliness: dict, *, planner: str = "gaps",
                recheck: bool = False, busy_heliostats=(), refine: bool = False,
                spreads: dict | None = None, target_id: str | None = None, guests: dict | None = None,
                usable=None) -> str | None:
    """The heliostat to send to the (one) target of ``candidates`` now, or None.

    ``refine``: idle target time goes to heliostats with nothing open (unaccepted first, then
    accepted ones) whose model is most uncertain at this sun; ``spreads`` maps heliostat id to
    that uncertainty [mrad] (:func:`model_spreads`).

    ``guests`` (gaps planner): heliostats of other targets that may borrow ``target_id``, each
    with its rank among the boards it may borrow (:func:`shared_targets`); ``usable(hid)`` says
    whether a guest can go on it now (strokes in range); a guest it refuses is passed over.
    """
    days = book.days(now_s)
    spreads = spreads or {}
    guests = dict(guests or {}) if planner != "round-robin" else {}
    cands = []
    order = list(candidates) + [g for g in guests if g not in candidates]
    if planner == "round-robin-shared":  # one field-wide order
        order.sort(key=cfg.heliostat_index)
    blank = None  # a heliostat without a verdict or a point: its verdict and gaps are every such one's
    for hid in order:
        b = book.h[hid]
        if b.verdict is None and not book.points(hid):
            if blank is None:
                v = _verdict_of(cfg, book, hid, None, now_s)
                blank = (v, acceptance.gaps(v, cfg.acceptance, days, now_s))
            verdict, gaps = blank
        else:
            verdict = b.verdict or _verdict_of(cfg, book, hid, None, now_s)
            gaps = acceptance.gaps(verdict, cfg.acceptance, days, now_s)
        c = cleanliness.get(hid)
        if c is None or not math.isfinite(float(c)):  # the plant gives none: the spot's own measure
            c = b.measured_cleanliness
        borrowed = int(guests.get(hid, 0))
        cands.append(planner_mod.Candidate(
            heliostat_id=hid, target_id=target_id if borrowed else cfg.heliostat(hid).target,
            accepted=bool(verdict.accepted) and not recheck,
            gaps=gaps, predicted_error_mrad=b.last_first_error_mrad,
            cleanliness=float("nan") if c is None else float(c), visits=b.visits, cooldown_until_s=b.cooldown_until_s,
            spread_mrad=None if borrowed else spreads.get(hid), borrowed=borrowed))
    if recheck:
        cands = [c for c in cands if book.h[c.heliostat_id].visits == 0]
    if planner == "round-robin":
        out = planner_mod.round_robin(cands, now_s, cfg.gating, cursor=book.cursor, busy_heliostats=busy_heliostats)
        return out[0].heliostat_id if out else None
    if planner == "round-robin-shared":
        one = planner_mod.round_robin_shared(cands, now_s, cfg.gating, target_id=target_id,
                                             cursor=book.cursor.get(FIELD_CURSOR), busy_heliostats=busy_heliostats,
                                             usable=usable)
        return None if one is None else one.heliostat_id
    # a target stays idle rather than spend time on points no acceptance gap asks for
    busy = set(busy_heliostats)
    for _try in range(MAX_GUEST_TRIES + 1):
        out = planner_mod.plan(cands, now_s, cfg.gating, busy_heliostats=busy, include_accepted=recheck,
                               skip_extra=not (recheck or refine), refine=refine and not recheck)
        if not out:
            return None
        hid = out[0].heliostat_id
        if not guests.get(hid) or usable is None or usable(hid):
            return hid
        busy.add(hid)
        if _try == MAX_GUEST_TRIES - 1:  # give up on guests for this target now
            busy.update(guests)
    return None


def choose_next_vectorised(cfg, book: Book, target_id: str, now_s: float, cleanliness, *, recheck: bool = False,
                           busy_heliostats=(), refine: bool = False, spreads: dict | None = None,
                           active_targets=(), usable=None) -> str | None:
    """:func:`choose_next` for the gaps planner, over the book's arrays (:class:`PlanTable`).

    The same choice as ``choose_next(cfg, book, own heliostats of target_id, now_s, cleanliness,
    planner="gaps", guests=<the target's guests whose own board is in active_targets>, ...)``
    (tested), at a cost per decision that does not grow with the field's history: each distinct
    set of needs is timed once, the rest is array arithmetic over the target's candidates.

    ``cleanliness(rows)``: the plant's cleanliness of those table rows (NaN where it gives none);
    ``active_targets``: the boards with a visit under way (their heliostats may borrow this one).
    """
    tb = book.table
    rules = cfg.acceptance
    rows = tb.own_rows[target_id]
    borrowed = np.zeros(rows.size, dtype=np.int64)
    g_rows, g_rank = tb.guest_rows[target_id], tb.guest_rank[target_id]
    active = [tb.target_index[t] for t in active_targets if t in tb.target_index]
    if g_rows.size and active:
        on = np.zeros(len(tb.target_index), dtype=bool)
        on[active] = True
        keep = on[tb.own[g_rows]]
        rows, borrowed = np.concatenate([rows, g_rows[keep]]), np.concatenate([borrowed, g_rank[keep]])
    keep = tb.cooldown_until_s[rows] <= now_s
    if recheck:
        keep &= tb.visits[rows] == 0
    busy = [tb.row[h] for h in busy_heliostats if h in tb.row]
    if busy:
        keep &= ~np.isin(rows, busy)
    rows, borrowed = rows[keep], borrowed[keep]
    if not rows.size:
        return None
    plant = np.asarray(cleanliness(rows), dtype=float)
    clean = np.where(np.isfinite(plant), plant, tb.measured_cleanliness[rows])
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(clean) & (clean > cfg.gating.cleanliness_min)
    rows, borrowed, clean = rows[ok], borrowed[ok], clean[ok]
    if not rows.size:
        return None

    # each distinct set of needs, timed once: its tier and when the gap that sets it closes
    days = book.days(now_s)
    need = tb.need[rows].copy()
    accepted = tb.accepted[rows].copy()
    timed: dict[int, tuple[int, float]] = {}

    def tier_of(wanted) -> tuple[int, float]:
        gaps = acceptance.time_needs(wanted, days, now_s)
        return planner_mod.gap_tier([g for g in gaps if g.is_open(now_s)])

    blank = np.flatnonzero(need == PlanTable.BLANK)
    if blank.size:
        v = _verdict_of(cfg, book, tb.ids[rows[blank[0]]], None, now_s)
        timed[PlanTable.BLANK] = tier_of(acceptance.needs(v, rules))
        accepted[blank] = bool(v.accepted)
    for k in np.flatnonzero(need == PlanTable.UNJUDGED):  # points but no verdict yet: one by one
        v = _verdict_of(cfg, book, tb.ids[rows[k]], None, now_s)
        need[k] = tb.need_id(acceptance.needs(v, rules))
        accepted[k] = bool(v.accepted)
    for k in np.unique(need):
        if k not in timed:
            timed[int(k)] = tier_of(tb.needs[int(k)])
    keys = np.array(sorted(timed))
    pos = np.searchsorted(keys, need)
    tier = np.array([timed[int(k)][0] for k in keys], dtype=np.int64)[pos]
    closes = np.array([timed[int(k)][1] for k in keys], dtype=float)[pos]

    accepted &= not recheck
    pred = tb.predicted_error_mrad[rows]
    spread = np.full(rows.size, np.nan)
    if spreads:
        for k in np.flatnonzero(borrowed == 0):
            spread[k] = spreads.get(tb.ids[rows[k]], np.nan)
    go = ~accepted
    if refine:  # accepted heliostats whose model is uncertain at this sun
        refine_rows = accepted & (spread >= planner_mod.REFINE_MIN_SPREAD_MRAD)
        tier[refine_rows], closes[refine_rows] = planner_mod.TIER_REFINE, math.inf
        go |= refine_rows
    go &= (borrowed == 0) | np.isin(tier, planner_mod.BORROW_TIERS)
    if not (recheck or refine):  # a target stays idle rather than spend time on points no gap asks for
        go &= tier != planner_mod.TIER_EXTRA
    err = np.where(np.isnan(pred), np.inf, pred)
    by_spread = np.isin(tier, (planner_mod.TIER_EXTRA, planner_mod.TIER_REFINE)) & ~np.isnan(spread) & ~np.isnan(pred)
    err = np.where(by_spread, spread, err)
    not_preferred = ~(clean > cfg.gating.cleanliness_preferred)
    sel = np.flatnonzero(go)
    if not sel.size:
        return None
    order = sel[np.lexsort((tb.id_rank[rows[sel]], tb.visits[rows[sel]], -err[sel], not_preferred[sel],
                            borrowed[sel], closes[sel], tier[sel]))]
    refused = 0
    for k in order:
        hid = tb.ids[rows[k]]
        if not borrowed[k] or usable is None:
            return hid
        if refused >= MAX_GUEST_TRIES:  # given up on guests for this target now
            continue
        if usable(hid):
            return hid
        refused += 1
    return None


MAX_GUEST_TRIES = 8
"""Guests a target passes over (their strokes out of range now) before it takes only its own."""
MAX_SHARE_INCIDENCE_DEG = 70.0
"""A heliostat may borrow a board only if it sees the board at most this far off its normal."""


def shared_targets(cfg, hids, camera_targets) -> dict[str, dict[str, int]]:
    """For each target: the heliostats of ``hids`` (of other targets) that may borrow it, with the
    board's rank among those each may borrow (1 = nearest to its own board).

    A board is lent only to heliostats in front of it, seen at most
    :data:`MAX_SHARE_INCIDENCE_DEG` off its normal, and only if it has a camera
    (``camera_targets``). Whether the strokes reach it is checked at each assignment.
    """
    cams = set(camera_targets)
    out: dict[str, dict[str, int]] = {t.id: {} for t in cfg.targets}
    cos_max = math.cos(math.radians(MAX_SHARE_INCIDENCE_DEG))
    for hid in hids:
        h = cfg.heliostat(hid)
        home = np.asarray(cfg.target(h.target).center_enu_m, dtype=float)
        pos = np.asarray(h.position_enu_m, dtype=float)
        ok = []
        for t in cfg.targets:
            if t.id == h.target or t.id not in cams:
                continue
            centre = np.asarray(t.center_enu_m, dtype=float)
            if float(np.dot(optics.unit(pos - centre), np.asarray(t.normal_enu, dtype=float))) >= cos_max:
                ok.append((float(np.linalg.norm(centre - home)), t.id))
        for rank, (_d, tid) in enumerate(sorted(ok), start=1):
            out[tid][hid] = rank
    return out


def model_spreads(cfg, book: Book, models: dict, nominal_rows, hids, sun_enu, now_s: float) -> dict:
    """Each fitted heliostat's predicted beam uncertainty [mrad] at this sun for its board centre
    (:func:`helicalib.calibration.fit.beam_spread_mrad`), for those of ``hids`` off cool-down.

    ``nominal_rows(hids)`` gives the nominal :class:`HeliostatModel` of those heliostats."""
    from helicalib.calibration.fit import beam_spread_mrad

    ready = [h for h in hids if book.h[h].fit is not None and book.h[h].cooldown_until_s <= now_s]
    if not ready:
        return {}
    model = nominal_rows(ready).with_params(np.vstack([models[h].params for h in ready]))
    aims = np.array([cfg.target(cfg.heliostat(h).target).center_enu_m for h in ready], dtype=float)
    cov = np.stack([book.h[h].fit.covariance for h in ready])
    spread = beam_spread_mrad(model, cov, sun_enu, aims)
    return {h: float(v) for h, v in zip(ready, spread) if math.isfinite(v)}


# ---------------------------------------------------------------------------------- fit
def refit(nominal: HeliostatModel, points: list, current: HeliostatModel, method: str = "fast",
          prior_mean: np.ndarray | None = None, tilt_rate: bool = False, earlier: Earlier | None = None):
    """Refit one heliostat's error model to its valid points; returns (model, FitResult or None).

    The solver starts from ``current``'s parameters (the priors stay centred on the nominal
    heliostat, or on ``prior_mean`` (P,): after a confirmed drift, the model from before it), so a
    refit after one more point takes a few steps instead of a whole descent. ``method``: the fit's
    solver (:data:`helicalib.calibration.fit.FIT_METHODS`; the fast one by default, the same minimum
    as ``"reference"``). ``tilt_rate`` (year-round operation): the fit adds a steady pedestal tilt rate
    and fits each point with the tilts of its time (``point_age_days`` of
    :func:`helicalib.calibration.fit.fit_error_model`, ages counted from the newest point), so points
    of past seasons stay consistent with a settling foundation; the model returned is the heliostat
    as of the newest point. ``earlier`` (after a confirmed drift, :data:`EPOCHS_AFTER_DRIFT`): the
    points from before it join the fit after ``points``, each with its epoch's own tilts and zero
    offsets; the model returned is the heliostat of ``points``' epoch."""
    if not points:
        return current, None
    epoch = None
    if earlier is not None:
        epoch = np.concatenate([np.zeros(len(points), dtype=int), earlier.epoch])
        points = list(points) + list(earlier.points)
    strokes, sun, spot = _arrays(points)
    approach = _approaches(points)
    start = current if np.all(np.isfinite(current.params)) else nominal
    # parameters the fit leaves fixed (the dead bands when no approach is recorded) keep the start's values
    fixed_as_nominal = np.any(approach) or np.array_equal(start.params[:, _BACKLASH], nominal.params[:, _BACKLASH])
    model = nominal if fixed_as_nominal else nominal.with_params(start.params)
    age = None
    if tilt_rate:
        t = np.array([p.capture_time_s for p in points], dtype=float)
        age = (t.max() - t) / 86400.0
    fit = fit_error_model(model, strokes, sun, spot, loss=FIT_LOSS, n_suggestions=0, approach=approach,
                          start=start.params[0], method=method, prior_mean=prior_mean, point_age_days=age,
                          point_epoch=epoch)
    if not np.all(np.isfinite(fit.params)):
        return current, None
    return fit.model, fit


def _arrays(points):
    strokes = np.array([p.strokes_read_mm or p.strokes_cmd_mm for p in points], dtype=float)
    sun = np.array([p.sun_enu for p in points], dtype=float)
    spot = np.array([p.spot_enu_m for p in points], dtype=float)
    return strokes, sun, spot


def _approaches(points) -> np.ndarray:
    """Each point's approach directions (K, 2) (0 where not recorded, e.g. an older database)."""
    return np.array([p.approach if getattr(p, "approach", None) is not None else (0, 0) for p in points], dtype=float)


def fit_record(fit) -> dict:
    return dict(model="geometric-backlash-v2", params=em.as_dict(fit.params), sigma=em.as_dict(fit.sigma),
                rms_mrad=float(fit.rms_mrad), n_points=int(len(fit.residual_mrad)))


def model_from_fit(model: HeliostatModel, fit_row) -> HeliostatModel:
    return model.with_params(em.from_dict(fit_row.params)[None, :])


# ---------------------------------------------------------------------------------- acceptance
def _visit_points(points: list) -> list:
    """One acceptance point per valid visit: its last valid measurement."""
    last: dict = {}
    for p in points:
        last[p.visit_id] = p
    return list(last.values())


def loo_errors_mrad(cfg, nominal: HeliostatModel, points: list, visit_points: list,
                    start: HeliostatModel | None = None, exact: bool = False, full=None,
                    method: str = "fast", earlier: Earlier | None = None) -> np.ndarray:
    """Leave-one-visit-out prediction error [mrad] of each visit point (formula 1 on its board).

    The model without a visit comes from one Gauss-Newton step from the fit to all points
    (:func:`~helicalib.calibration.fit.leave_out_params`; ``full``: that fit when the caller has
    it, e.g. the refit after the visit's last point), or with ``exact`` from a full refit per
    visit. Refits start from ``start`` (default nominal) and use the fit's solver ``method``.
    ``earlier``: the points from before a confirmed drift, in every fit (:func:`refit`); only the
    visits of ``points`` are left out."""
    start = start if start is not None else nominal
    if not visit_points:
        return np.zeros(0)
    if not exact:
        if full is None or len(full.residual_mrad) != fit_size(points, earlier):
            _model, full = refit(nominal, points, start, method, earlier=earlier)
        if full is not None and full.linearisation is not None:
            groups = [[k for k, p in enumerate(points) if p.visit_id == vp.visit_id] for vp in visit_points]
            return _prediction_errors_mrad(cfg, nominal, leave_out_params(full, groups), visit_points)
    params = []
    for vp in visit_points:
        rest = [p for p in points if p.visit_id != vp.visit_id]
        model, _fit = refit(nominal, rest, start, method, earlier=earlier)
        params.append(model.params[0])
    return _prediction_errors_mrad(cfg, nominal, np.array(params), visit_points)


def _prediction_errors_mrad(cfg, nominal: HeliostatModel, params: np.ndarray, visit_points: list) -> np.ndarray:
    """:func:`prediction_error_mrad` of each visit point for its own parameter row of ``params``
    (G, P), in one vectorised call."""
    model = nominal.repeat(len(visit_points)).with_params(params)
    strokes, sun, spot = _arrays(visit_points)
    targets = [cfg.target(vp.target_id) for vp in visit_points]
    uv = model.spot_on_target(strokes, sun, targets, _approaches(visit_points))
    predicted = np.array([t.uvw_to_enu(uv[g]) for g, t in enumerate(targets)])
    return np.asarray(optics.tracking_error_exact_mrad(spot, predicted, model.pivots_enu), dtype=float)


def prediction_error_mrad(model: HeliostatModel, obs, target) -> float:
    """How far ``model`` puts the beam from where ``obs`` saw it [mrad]: the angle at the pivot
    between the observed spot and the model's spot on the same board plane.

    Not T/GRLM formula (1) (distance on the board / slant distance), which the visit loop records:
    on a board seen obliquely, formula (1) grows by up to 1/cos(incidence) along the oblique
    direction (2.9× at 70°), so heliostats that see their board at a grazing angle would fail
    acceptance for the board's obliquity, not their pointing (docs/running.md)."""
    strokes, sun, spot = _arrays([obs])
    predicted = target.uvw_to_enu(model.spot_on_target(strokes, sun[0], target, _approaches([obs]))[0])
    return float(optics.tracking_error_exact_mrad(spot[0], predicted, model.pivots_enu[0]))


def _verdict_of(cfg, book: Book, hid: str, nominal: HeliostatModel | None, now_s: float,
                start: HeliostatModel | None = None):
    points = book.points(hid)
    vps = _visit_points(points)
    days = book.days(now_s)
    first = np.array([p.error_mrad if p.error_mrad is not None else np.nan for p in vps], dtype=float)
    base = acceptance.evaluate_observations(vps, cfg.acceptance, days, now_s=now_s, errors_mrad=first)
    coverage_ok = all(r.startswith("RMS") for r in base.reasons)
    if nominal is None or not coverage_ok:
        return base
    # coverage met: judge the accuracy honestly, out of sample
    errs = loo_errors_mrad(cfg, nominal, points, vps, start, full=book.h[hid].fit, earlier=book.h[hid].earlier)
    return acceptance.evaluate_observations(vps, cfg.acceptance, days, now_s=now_s, errors_mrad=errs)


def verdict(cfg, book: Book, hid: str, nominal: HeliostatModel, now_s: float, start: HeliostatModel | None = None):
    """The heliostat's acceptance verdict now; ``start``: its current model (speeds up the
    leave-one-visit-out refits, which start there)."""
    return _verdict_of(cfg, book, hid, nominal, now_s, start)


# ---------------------------------------------------------------------------------- tracking
TRACKING_REFRESH_S = 900.0
"""Plant seconds between rewrites of the tracking corrections of calibrated heliostats."""


def tracking_corrections(cfg, nominal: HeliostatModel, calibrated: HeliostatModel, sun_enu,
                         sun_later_enu=None) -> np.ndarray:
    """Stroke corrections [mm] that make the plant's nominal tracking follow the calibrated models.

    The plant tracks the receiver with its nominal model plus one constant offset per actuator
    (PLANT_INTERFACE). The offset that makes it point like the calibrated model is the stroke
    difference for the receiver aim at the sun ``sun_enu`` (3,); it drifts slowly with the sun, so
    the runner rewrites it every :data:`TRACKING_REFRESH_S` for the sun half a period ahead.
    With ``sun_later_enu`` (the sun a few minutes after ``sun_enu``), the calibrated strokes
    include the models' dead bands for each actuator's tracking direction (the sign of the
    nominal strokes' change between the two suns), as the plant's tracking moves it.

    Returns
    -------
    ndarray, shape (N, 2)
        NaN rows where either model's strokes (or nominal + correction) leave the stroke range:
        write nothing for those heliostats.
    """
    aim = np.asarray(cfg.tower.receiver_aim_enu_m, dtype=float)
    nom = nominal.strokes_for_aim(sun_enu, aim)
    approach = (None if sun_later_enu is None
                else tracking_approach(nom.strokes_mm, nominal.strokes_for_aim(sun_later_enu, aim).strokes_mm))
    cal = calibrated.strokes_for_aim(sun_enu, aim, approach)
    corr = cal.strokes_mm - nom.strokes_mm
    d = nominal.drives
    tracked = nom.strokes_mm + corr
    ok = cal.in_range & nom.in_range & np.all((tracked >= d.stroke_min_mm) & (tracked <= d.stroke_max_mm), axis=1)
    return np.where(ok[:, None], corr, np.nan)
