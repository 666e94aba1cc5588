"""The campaign's book: what it knows of each heliostat, and which points its fits stand on.

:class:`Book` holds per heliostat the valid points, visits, verdict and cool-down
(:class:`HeliostatBook`), and keeps the planner's arrays (:class:`PlanTable`) current as it
changes. The rules that decide which points a heliostat's fits and verdicts stand on live here
too: :func:`located`, the cap on visits (:func:`visit_cap`, :func:`thin_visits`), and the points
from before a confirmed drift (:class:`Earlier`, :func:`earlier_points`). Pure: observations in,
lists and arrays out; the store's history enters through :func:`basis` as plain values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from helicalib.calibration import acceptance
from helicalib.calibration.sun_days import sun_days

FIELD_CURSOR = "*"
"""``Book.cursor`` key of the heliostat that last went on any board (field-wide round robin)."""
COOLDOWN_INVALID_S = 1800.0
"""After a visit without a valid point a heliostat waits this long [plant s] before its next try."""
COOLDOWN_INVALID_MAX_S = 14400.0
"""The wait after visits whose readings all failed (``invalid``) doubles with each such visit in a row
(:data:`COOLDOWN_INVALID_S`, twice that, ..., at most this long) until one gives a valid point: a
heliostat whose spot the board cannot measure at this time of day (a beam as large as the board, a
model pulled off by a bad point, a first beam that lands farther off than a search on the board can
reach) gives its board time to others, and is tried again as the sun moves. Faults and refusals (the
plant's, a camera's, the drive's range) neither add to the run nor end it. At a 30-minute wait, 419
of a 10⁴ field's heliostats took 7 890 visits that searched beyond a third placement in 4.35 days (a quarter
of all readings, 0.6 % of them valid), most of them from 121 heliostats never found at all."""
COOLDOWN_VALID_S = 1200.0
"""After a valid visit the heliostat waits this long (the next point should see another sun)."""
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
(``epoch`` of :class:`helicalib.calibration.fit.FitPoints`): a drift changes those, not
the heliostat's build, so the months of points before it keep informing the rest of the model. The
fits are then centred on the nominal heliostat (the earlier points carry what the model before the
drift knew) and keep the steady tilt rate, which the earlier epochs' points pin down. The acceptance
verdict and the drift tests still judge the visits since the drift. False: the points before the
newest drift are dropped, as until version 2026-11-27 (docs/operation.md)."""


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
    failed_in_row: int = 0                          # visits in a row whose readings all failed (back-off)

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
        b.cooldown_until_s = now_s + cooldown_s(b, outcome)
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


def cooldown_s(b: HeliostatBook, outcome) -> float:
    """The wait [plant s] after ``outcome``, one visit of the heliostat whose book is ``b`` (whose
    ``failed_in_row`` it updates): :data:`COOLDOWN_VALID_S` after a valid point, else
    :data:`COOLDOWN_INVALID_S` doubled for each ``invalid`` visit in a row, at most
    :data:`COOLDOWN_INVALID_MAX_S`."""
    if outcome.valid_points:
        b.failed_in_row = 0
        return COOLDOWN_VALID_S
    if outcome.status == "invalid":
        b.failed_in_row += 1
    return min(COOLDOWN_INVALID_S * 2.0 ** max(0, b.failed_in_row - 1), COOLDOWN_INVALID_MAX_S)


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
    arrays instead of walking the field (:func:`helicalib.campaign.choice.choose_next_vectorised`).
    Verdicts enter as the key of their needs (:func:`helicalib.calibration.acceptance.needs_key`):
    heliostats that lack the same things share one entry of :attr:`needs`, timed once per decision.

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
        self._blank: tuple | None = None    # ((days, evaluation day), (needs, accepted)): blank_needs
        targets = [t.id for t in cfg.targets]
        self.target_index = {t: k for k, t in enumerate(targets)}
        self.own = np.array([self.target_index[cfg.heliostat(h).target] for h in self.ids], dtype=np.int64)
        self.own_rows = {t: np.flatnonzero(self.own == k) for t, k in self.target_index.items()}
        self.guest_rows = {t: np.zeros(0, dtype=np.int64) for t in targets}
        self.guest_rank = {t: np.zeros(0, dtype=np.int64) for t in targets}

    def set_guests(self, guests: dict[str, dict[str, int]]) -> None:
        """The heliostats that may borrow each target and the board's rank for them
        (:func:`helicalib.campaign.choice.shared_targets`)."""
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

    def blank_needs(self, days, now_s: float, judge) -> tuple[tuple, bool]:
        """The needs and acceptance of a heliostat without a point, ``judge()`` its verdict now.

        Without points a verdict depends on the solar days and on the day that sets the number of
        high windows (:func:`helicalib.calibration.acceptance.evaluation_day`) alone, so it is
        judged again only when either changes, not at every decision."""
        key = (days, acceptance.evaluation_day(days, now_s))
        if self._blank is None or self._blank[0][0] is not days or self._blank[0][1] != key[1]:
            v = judge()
            self._blank = (key, (acceptance.needs(v, self.cfg.acceptance), bool(v.accepted)))
        return self._blank[1]

    def need_id(self, wanted: tuple) -> int:
        key = tuple((nd.kind, nd.window, nd.n_windows) for nd in wanted)
        k = self._need_ids.get(key)
        if k is None:
            k = self._need_ids[key] = len(self.needs)
            self.needs.append(wanted)
        return k



def basis(observations, epoch) -> tuple:
    """``(points, prior_mean, earlier)``: what a heliostat's fit stands on, from its stored
    ``observations`` (in the store's order) and what its drifts and repairs left (``epoch``, an
    :class:`helicalib.store.history.Epochs`): the points of :func:`book_points` since its epoch under
    its cap, the centre of the fit's prior (None: the nominal heliostat), and the points from
    before its newest drift (:func:`earlier_points`; None without)."""
    earlier = earlier_points(observations, epoch.floor_s, epoch.boundaries)
    points = book_points(observations, epoch.since_s, visit_cap(epoch.drifted))
    return points, (epoch.prior if earlier is None else None), earlier
