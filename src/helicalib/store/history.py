"""The reading of a campaign's stored history: confirmed drifts, the crew's actions, operation.

What a campaign's ``drift`` events and applied ``operator_actions`` leave for each heliostat's fits
(:class:`Epochs`, :func:`stored_epochs`), the standing state the crew's actions leave
(:class:`Standing`, :func:`replay`), and whether a campaign went into year-round operation
(:func:`was_operated`). Read once for a whole field; plain values out, for the campaign's book
(:func:`helicalib.campaign.book.basis`), its resume, the report and ``helicalib check``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Standing:
    """What the applied actions leave: paused or not, heliostats out of service, repair times."""

    paused: bool = False
    out_of_service: set[str] = field(default_factory=set)
    repaired_s: dict[str, float] = field(default_factory=dict)
    """Heliostat id → plant time of its newest repair (points before it no longer count)."""


def replay(actions) -> Standing:
    """The standing state after the applied ``actions`` (store rows, oldest first)."""
    st = Standing()
    for a in actions:
        if a.done_s is None:
            continue
        if a.kind in ("pause", "resume"):
            st.paused = a.kind == "pause"
        elif a.kind == "out_of_service":
            st.out_of_service.update(a.heliostat_ids)
        elif a.kind == "in_service":
            st.out_of_service.difference_update(a.heliostat_ids)
        elif a.kind == "repaired":
            st.repaired_s.update({h: float(a.done_s) for h in a.heliostat_ids})
    return st


@dataclass(frozen=True)
class Epochs:
    """What a heliostat's confirmed drifts and operator repairs leave for its fits (:func:`stored_epochs`)."""

    since_s: float = -math.inf
    """The book's points count from here: the newest drift's epoch, or just after the newest repair."""
    prior: np.ndarray | None = None
    """The model from before the newest drift (P,) (None for the nominal heliostat, also when a repair
    came after the drift): the fits' prior centre when
    :data:`helicalib.campaign.book.EPOCHS_AFTER_DRIFT` is off."""
    drifted: bool = False
    """Since a confirmed drift (until a repair): the book's smaller cap
    (:func:`helicalib.campaign.book.visit_cap`)."""
    confirmed_s: float = -math.inf
    """The newest drift's confirmation (:func:`helicalib.campaign.operation.rules.fits_tilt_rate`)."""
    floor_s: float = -math.inf
    """Just after the newest repair: no point before it counts."""
    boundaries: tuple = ()
    """The epochs (``since_s``) of the drifts confirmed after ``floor_s``, oldest first."""


NO_EPOCH = Epochs()
""":func:`stored_epochs`' entry of a heliostat without a confirmed drift or a repair."""


def stored_epochs(store, campaign_id: int, until_s: float = math.inf) -> dict:
    """``{heliostat id: Epochs}`` for the heliostats of campaign ``campaign_id`` with a confirmed drift
    (its ``drift`` events) or an operator repair by ``until_s``, as the runner applies them on
    resume (:class:`Epochs`). Read once for a whole field."""
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


def was_operated(store, campaign_id: int) -> bool:
    """Whether a stored campaign went into year-round operation, so that its fits are operation's
    (:data:`helicalib.campaign.operation.rules.TILT_RATE_IN_FITS`): ``simulate --operate`` (its
    settings) or ``helicalib operate`` (the command its ``campaign`` event records)."""
    if (store.campaign(campaign_id).settings or {}).get("operation"):
        return True
    return any((e.data or {}).get("operation") for e in store.events(campaign_id=campaign_id, kind="campaign"))
