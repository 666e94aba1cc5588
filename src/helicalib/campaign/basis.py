"""What a heliostat's fit stood on, rebuilt from the store.

The campaign's book read back from a stored campaign: its history (:mod:`helicalib.store.history`:
confirmed drifts, repairs) and the book's rules for which points count (:func:`.book.basis`). The
runner's resume, the crew's repairs, the report's refit and ``helicalib check`` stand on these.
"""

from __future__ import annotations

import math

from helicalib.campaign.book import basis
from helicalib.store.history import NO_EPOCH, stored_epochs


def stored_basis(store, campaign_id: int, heliostat_id: str, until_s: float = math.inf, epochs: dict | None = None):
    """``(points, prior_mean, earlier)``: what the fit of ``heliostat_id`` that campaign ``campaign_id``
    made at ``until_s`` stood on, from the store, as the runner rebuilds it on resume
    (:func:`helicalib.campaign.book.basis`); ``epochs``: :func:`helicalib.store.history.stored_epochs`
    (pass them when asking for many heliostats)."""
    if epochs is None:
        epochs = stored_epochs(store, campaign_id, until_s)
    obs = [o for o in store.observations(campaign_id=campaign_id, heliostat_id=heliostat_id)
           if o.capture_time_s <= until_s]
    return basis(obs, epochs.get(heliostat_id, NO_EPOCH))
