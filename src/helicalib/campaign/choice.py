"""The choice of the next visit: whether visits may start, and who goes on a free target now.

:func:`field_gate` says whether the field may calibrate (sun, wind, DNI); :func:`choose_next`
turns the book into the planner's candidates (:mod:`.planner`) and picks one for a target, and
:func:`choose_next_vectorised` makes the gaps planner's same choice over the book's arrays
(:class:`.book.PlanTable`). :func:`shared_targets` says which boards each heliostat may borrow;
:func:`model_spreads` how uncertain each fitted model is at the present sun. Pure: the book and
the plant's readings in, a heliostat id out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from helicalib.calibration import acceptance
from helicalib.calibration.fit import beam_spread_mrad
from helicalib.campaign import gating as gating_mod
from helicalib.campaign import planner as planner_mod
from helicalib.campaign import verdict as verdicts
from helicalib.campaign.book import FIELD_CURSOR, Book, PlanTable
from helicalib.geometry import optics


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
                v = verdicts.verdict(cfg, book, hid, None, now_s)
                blank = (v, acceptance.gaps(v, cfg.acceptance, days, now_s))
            verdict, gaps = blank
        else:
            verdict = b.verdict or verdicts.verdict(cfg, book, hid, None, now_s)
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
    """:func:`choose_next` for the gaps planner, over the book's arrays (:class:`.book.PlanTable`).

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
    # NaN: the plant gives none (the spot's own measure stands in); −inf: a live run's read not in yet
    clean = np.where(np.isfinite(plant) | np.isneginf(plant), plant, tb.measured_cleanliness[rows])
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(clean) & (clean > cfg.gating.cleanliness_min)
    rows, borrowed, clean = rows[ok], borrowed[ok], clean[ok]
    if not rows.size:
        return None

    # each distinct set of needs, timed once: its tier and when the gap that sets it closes
    days = book.days(now_s)
    need = tb.need[rows].copy()
    accepted = tb.accepted[rows].copy()
    timed: dict[int, tuple[int, float, int]] = {}

    def tier_of(wanted) -> tuple[int, float, int]:
        gaps = acceptance.time_needs(wanted, days, now_s)
        tier, closes = planner_mod.gap_tier([g for g in gaps if g.is_open(now_s)])
        return tier, closes, planner_mod.band_needs(tier, len(gaps))

    blank = np.flatnonzero(need == PlanTable.BLANK)
    if blank.size:
        wanted, blank_accepted = tb.blank_needs(days, now_s, lambda: verdicts.verdict(
            cfg, book, tb.ids[rows[blank[0]]], None, now_s))
        timed[PlanTable.BLANK] = tier_of(wanted)
        accepted[blank] = blank_accepted
    for k in np.flatnonzero(need == PlanTable.UNJUDGED):  # points but no verdict yet: one by one
        v = verdicts.verdict(cfg, book, tb.ids[rows[k]], None, now_s)
        need[k] = tb.need_id(acceptance.needs(v, rules))
        accepted[k] = bool(v.accepted)
    for k in np.flatnonzero(np.bincount(need - PlanTable.UNJUDGED)) + PlanTable.UNJUDGED:  # np.unique's, cheaper
        if k not in timed:
            timed[int(k)] = tier_of(tb.needs[int(k)])
    keys = np.array(sorted(timed))
    pos = np.searchsorted(keys, need)
    tier = np.array([timed[int(k)][0] for k in keys], dtype=np.int64)[pos]
    closes = np.array([timed[int(k)][1] for k in keys], dtype=float)[pos]
    needs = np.array([timed[int(k)][2] for k in keys], dtype=np.int64)[pos]

    accepted &= not recheck
    pred = tb.predicted_error_mrad[rows]
    spread = np.full(rows.size, np.nan)
    if spreads:
        for k in np.flatnonzero(borrowed == 0):
            spread[k] = spreads.get(tb.ids[rows[k]], np.nan)
    go = ~accepted
    if refine:  # accepted heliostats whose model is uncertain at this sun
        refine_rows = accepted & (spread >= planner_mod.REFINE_MIN_SPREAD_MRAD)
        tier[refine_rows], closes[refine_rows], needs[refine_rows] = planner_mod.TIER_REFINE, math.inf, 0
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
    sort_keys = (tier, closes, borrowed, needs, not_preferred, -err, tb.visits[rows], tb.id_rank[rows])  # first key first
    first = _lexicographic_first(sel, sort_keys)
    if not borrowed[first] or usable is None or usable(tb.ids[rows[first]]):
        return tb.ids[rows[first]]  # the usual decision: no sort of the whole target's candidates
    order = sel[np.lexsort(tuple(k[sel] for k in reversed(sort_keys)))]  # order[0] is first, a guest refused
    refused = 1
    for k in order[1:]:
        hid = tb.ids[rows[k]]
        if not borrowed[k] or usable is None:
            return hid
        if refused >= MAX_GUEST_TRIES:  # given up on guests for this target now
            continue
        if usable(hid):
            return hid
        refused += 1
    return None


def _lexicographic_first(sel: np.ndarray, keys) -> int:
    """The element of ``sel`` that ``np.lexsort`` over ``keys`` (first key first, NaN last) puts
    first, by narrowing key by key: O(len(sel)) a key instead of a sort."""
    for key in keys:
        v = key[sel]
        if v.dtype.kind == "f":
            finite = ~np.isnan(v)
            if not finite.all():
                if not finite.any():
                    continue
                sel, v = sel[finite], v[finite]
        sel = sel[v == v.min()]
        if sel.size == 1:
            break
    return int(sel[0])


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
    hids = list(hids)
    if not hids:
        return out
    # one array operation a board over all heliostats (10⁴ heliostats × boards in Python took seconds)
    helios = [cfg.heliostat(h) for h in hids]
    pos = np.array([h.position_enu_m for h in helios], dtype=float)
    centres = np.array([t.center_enu_m for t in cfg.targets], dtype=float)
    tindex = {t.id: k for k, t in enumerate(cfg.targets)}
    home = np.array([tindex[h.target] for h in helios], dtype=np.int64)
    lent = np.zeros((len(hids), len(cfg.targets)), dtype=bool)
    for k, t in enumerate(cfg.targets):
        if t.id in cams:
            u = optics.unit(pos - centres[k])
            n = np.asarray(t.normal_enu, dtype=float)
            lent[:, k] = (u[:, 0] * n[0] + u[:, 1] * n[1] + u[:, 2] * n[2] >= cos_max) & (home != k)
    # a board's rank depends on the heliostat's own board and the boards it may borrow: ordered once per home
    dist = [[float(np.linalg.norm(b - a)) for b in centres] for a in centres]  # [home][board]
    for i in np.flatnonzero(lent.any(axis=1)):
        ok = sorted((dist[home[i]][k], cfg.targets[k].id) for k in np.flatnonzero(lent[i]))
        for rank, (_d, tid) in enumerate(ok, start=1):
            out[tid][hids[i]] = rank
    return out


def model_spreads(cfg, book: Book, models: dict, nominal_rows, hids, sun_enu, now_s: float) -> dict:
    """Each fitted heliostat's predicted beam uncertainty [mrad] at this sun for its board centre
    (:func:`helicalib.calibration.fit.beam_spread_mrad`), for those of ``hids`` off cool-down.

    ``nominal_rows(hids)`` gives the nominal :class:`HeliostatModel` of those heliostats."""
    ready = [h for h in hids if book.h[h].fit is not None and book.h[h].cooldown_until_s <= now_s]
    if not ready:
        return {}
    model = nominal_rows(ready).with_params(np.vstack([models[h].params for h in ready]))
    aims = np.array([cfg.target(cfg.heliostat(h).target).center_enu_m for h in ready], dtype=float)
    cov = np.stack([book.h[h].fit.covariance for h in ready])
    spread = beam_spread_mrad(model, cov, sun_enu, aims)
    return {h: float(v) for h, v in zip(ready, spread) if math.isfinite(v)}

