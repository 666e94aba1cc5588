"""Who goes on which target next: the gap-filling planner and the paper's plain round robin.

One heliostat per target at a time; targets are planned independently (in parallel). The
gap-filling planner (:func:`plan`) ranks each free target's candidates in tiers:

0. an acceptance gap in the rising or setting low band that is open now (short, scarce: about an
   hour a day each, and missed until tomorrow);
1. a high-elevation window gap open now, the window closing soonest first;
2. other unaccepted heliostats with a gap open now (more points, RMS too high);
3. unaccepted heliostats with nothing open now (extra points sharpen their model);
4. accepted heliostats, only when ``include_accepted`` (a re-check);
5. accepted heliostats whose model is still uncertain at this sun, only when ``refine`` (asked
   for: idle target time spent on points that sharpen year-round accuracy).

Within a tier: the gap that closes soonest; in the low band, the heliostats closest to acceptance
(fewest needs besides, :func:`band_needs`: a band point that completes a heliostat before one
that still lacks the other band), then mirrors of preferred cleanliness, then the
largest predicted error (a new heliostat, with no model yet, counts as infinite; in tiers 3 and 5
the model's own uncertainty at the present sun, ``spread_mrad``, where it is known), then the
fewest visits, then the id. A heliostat on a borrowed target (``borrowed`` > 0: another board
that faces it, lent while its own is busy; ``calibration.share_targets``) goes only for a gap open
now (tiers 0-2) or a re-check, and after the target's own heliostats of the same tier and closing
time. Gated mirrors (cleanliness ≤ min) and heliostats cooling down after an invalid visit are
skipped. :func:`round_robin` is the paper's "in turn" order, the benchmark baseline;
:func:`round_robin_shared` goes in turn over the whole field with shared boards (a second
baseline). All three are pure: state in, frozen assignments out.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from helicalib.calibration.acceptance import Gap

TIER_LOW_BAND, TIER_WINDOW, TIER_OPEN, TIER_EXTRA, TIER_RECHECK, TIER_REFINE = range(6)
TIER_NAMES = ("low band", "high window", "more points", "extra points", "re-check", "refine")
REFINE_MIN_SPREAD_MRAD = 0.15
"""Refinement visits only for models whose predicted beam uncertainty at the present sun is at least this."""


@dataclass(frozen=True)
class Candidate:
    """A heliostat's planning state.

    Attributes
    ----------
    heliostat_id, target_id : str
    accepted : bool
        Its latest verdict accepts it.
    gaps : tuple of Gap
        What acceptance still lacks (:func:`helicalib.calibration.acceptance.gaps`).
    predicted_error_mrad : float or None
        The expected error of its next first placement [mrad] (None: no model yet).
    cleanliness : float
        Mirror cleanliness, 0..1 (NaN unknown).
    visits : int
        Visits so far in this campaign.
    cooldown_until_s : float
        Not before this plant time [UTC s] (e.g. after an invalid visit); 0 = no wait.
    spread_mrad : float or None
        The model's predicted 1-σ beam uncertainty at the present sun [mrad] (from the fit's
        covariance; None: not computed).
    borrowed : int
        0: ``target_id`` is the heliostat's own target; k > 0: a borrowed one, the k-th nearest
        other board to its own.
    """

    heliostat_id: str
    target_id: str
    accepted: bool = False
    gaps: tuple[Gap, ...] = ()
    predicted_error_mrad: float | None = None
    cleanliness: float = 1.0
    visits: int = 0
    cooldown_until_s: float = 0.0
    spread_mrad: float | None = None
    borrowed: int = 0


BORROW_TIERS = (TIER_LOW_BAND, TIER_WINDOW, TIER_OPEN, TIER_RECHECK)
"""Tiers for which a heliostat may go on a borrowed target."""


@dataclass(frozen=True)
class Assignment:
    """Send ``heliostat_id`` to ``target_id`` now; ``tier`` and ``reason`` say why it was chosen."""

    target_id: str
    heliostat_id: str
    tier: int
    reason: str


def _eligible(c: Candidate, now_s: float, gating) -> bool:
    clean = c.cleanliness
    return c.cooldown_until_s <= now_s and math.isfinite(clean) and clean > gating.cleanliness_min


def gap_tier(open_gaps: Sequence[Gap]) -> tuple[int, float]:
    """The tier of an unaccepted heliostat whose gaps open now are ``open_gaps``, and when the
    gap that sets it closes [UTC s] (inf when that does not matter)."""
    band = [g.next_end_s for g in open_gaps if g.kind in ("rising", "setting")]
    window = [g.next_end_s for g in open_gaps if g.kind == "window"]
    if band:
        return TIER_LOW_BAND, min(band)
    if window:
        return TIER_WINDOW, min(window)
    if open_gaps:
        return TIER_OPEN, math.inf
    return TIER_EXTRA, math.inf


def rank(c: Candidate, now_s: float, gating, include_accepted: bool = False, refine: bool = False) -> tuple | None:
    """The sort key of a candidate at ``now_s`` (smaller goes first), or None when it should not go.

    The key is ``(tier, closes_s, borrowed, band_needs, not_preferred, -predicted_error, visits, id)``.
    """
    if c.accepted and not (include_accepted or refine):
        return None
    open_gaps = [g for g in c.gaps if g.is_open(now_s)]
    if c.accepted and include_accepted:
        tier, closes = TIER_RECHECK, math.inf
    elif c.accepted:
        if c.spread_mrad is None or not c.spread_mrad >= REFINE_MIN_SPREAD_MRAD:
            return None
        tier, closes = TIER_REFINE, math.inf
    else:
        tier, closes = gap_tier(open_gaps)
    if c.borrowed and tier not in BORROW_TIERS:
        return None
    err = math.inf if c.predicted_error_mrad is None else float(c.predicted_error_mrad)
    if tier in (TIER_EXTRA, TIER_REFINE) and c.spread_mrad is not None and c.predicted_error_mrad is not None:
        err = float(c.spread_mrad)
    not_preferred = not (c.cleanliness > gating.cleanliness_preferred)
    return (tier, closes, int(c.borrowed), band_needs(tier, len(c.gaps)), not_preferred, -err, c.visits,
            c.heliostat_id)


def band_needs(tier: int, needs: int) -> int:
    """The order within a tier after its closing time: in the low band (scarce, about an hour a day
    each way) a heliostat's count of acceptance needs (this band's point among them), so the band
    point that completes a heliostat goes first; 0 in every other tier (no order by need there)."""
    return needs if tier == TIER_LOW_BAND else 0


def _reason(c: Candidate, key: tuple, now_s: float) -> str:
    tier = key[0]
    open_gaps = [g.description for g in c.gaps if g.is_open(now_s)]
    what = f": {open_gaps[0]}" if open_gaps and tier <= TIER_OPEN else ""
    err = "no model yet" if c.predicted_error_mrad is None else f"predicted error {c.predicted_error_mrad:.1f} mrad"
    if tier in (TIER_EXTRA, TIER_REFINE) and c.spread_mrad is not None and c.predicted_error_mrad is not None:
        err = f"model uncertain by {c.spread_mrad:.2f} mrad at this sun"
    lent = ", on a borrowed target" if c.borrowed else ""
    return f"{TIER_NAMES[tier]}{what} ({err}{lent})"


def plan(candidates: Iterable[Candidate], now_s: float, gating, *, busy_targets: Iterable[str] = (),
         busy_heliostats: Iterable[str] = (), include_accepted: bool = False,
         skip_extra: bool = False, refine: bool = False) -> tuple[Assignment, ...]:
    """One assignment per free target: the best-ranked eligible heliostat of that target.

    Parameters
    ----------
    candidates : iterable of Candidate
        Every heliostat of the campaign.
    now_s : float
        Plant time [UTC s].
    gating : helicalib.config.Gating
        For the cleanliness limits.
    busy_targets, busy_heliostats : iterable of str
        Targets with a visit under way, and heliostats in one (or otherwise unavailable).
    include_accepted : bool
        Consider accepted heliostats too (re-check mode).
    skip_extra : bool
        Leave a target idle rather than spend it on tier 3 (nothing open now).
    refine : bool
        Spend otherwise idle target time on accepted heliostats whose model is still uncertain at
        the present sun (tier 5, ``spread_mrad`` ≥ :data:`REFINE_MIN_SPREAD_MRAD`).

    Returns
    -------
    tuple of Assignment
        Sorted by target id. The field gate (wind, DNI) is the caller's: do not call it when
        :func:`helicalib.campaign.gating.gate_field` says no calibration.
    """
    busy_t, busy_h = set(busy_targets), set(busy_heliostats)
    best: dict[str, tuple[tuple, Candidate]] = {}
    for c in candidates:
        if c.target_id in busy_t or c.heliostat_id in busy_h or not _eligible(c, now_s, gating):
            continue
        key = rank(c, now_s, gating, include_accepted, refine)
        if key is None or (skip_extra and key[0] == TIER_EXTRA):
            continue
        if c.target_id not in best or key < best[c.target_id][0]:
            best[c.target_id] = (key, c)
    return tuple(Assignment(t, c.heliostat_id, key[0], _reason(c, key, now_s))
                 for t, (key, c) in sorted(best.items()))


def round_robin(candidates: Sequence[Candidate], now_s: float, gating, *, cursor: Mapping[str, str | None],
                busy_targets: Iterable[str] = (), busy_heliostats: Iterable[str] = (),
                include_accepted: bool = False) -> tuple[Assignment, ...]:
    """The paper's order: each target takes its heliostats in turn (the order of ``candidates``).

    ``cursor[target]`` is the heliostat that last went on that target (None or absent: start at
    the first). The next eligible, unaccepted one after it goes, wrapping around. The caller
    stores each assignment's heliostat as the new cursor.
    """
    busy_t, busy_h = set(busy_targets), set(busy_heliostats)
    by_target: dict[str, list[Candidate]] = {}
    for c in candidates:
        by_target.setdefault(c.target_id, []).append(c)
    out = []
    for target in sorted(by_target):
        if target in busy_t:
            continue
        queue = by_target[target]
        ids = [c.heliostat_id for c in queue]
        last = cursor.get(target)
        start = ids.index(last) + 1 if last in ids else 0
        for step in range(len(queue)):
            c = queue[(start + step) % len(queue)]
            if c.heliostat_id in busy_h or not _eligible(c, now_s, gating):
                continue
            if c.accepted and not include_accepted:
                continue
            out.append(Assignment(target, c.heliostat_id, TIER_EXTRA, "in turn"))
            break
    return tuple(out)


def round_robin_shared(candidates: Sequence[Candidate], now_s: float, gating, *, target_id: str,
                       cursor: str | None, busy_heliostats: Iterable[str] = (), usable=None) -> Assignment | None:
    """Round robin over the whole field with shared boards (a benchmark baseline): the free
    ``target_id`` takes the next eligible, unaccepted heliostat in the order of ``candidates``
    (its own and those that may borrow it, in one field-wide order) after ``cursor`` (the one
    that last went on any board), wrapping around; a borrowed one only if ``usable(id)``."""
    busy = set(busy_heliostats)
    ids = [c.heliostat_id for c in candidates]
    start = ids.index(cursor) + 1 if cursor in ids else 0
    for step in range(len(candidates)):
        c = candidates[(start + step) % len(candidates)]
        if c.heliostat_id in busy or c.accepted or not _eligible(c, now_s, gating):
            continue
        if c.borrowed and usable is not None and not usable(c.heliostat_id):
            continue
        return Assignment(target_id, c.heliostat_id, TIER_EXTRA, "in turn (shared boards)")
    return None
