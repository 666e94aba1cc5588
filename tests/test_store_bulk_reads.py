"""The store's reads of many heliostats at once (a campaign read back on resume) against its reads of
one heliostat at a time, on a real SQLite file of two synthetic campaigns."""

from __future__ import annotations

import pytest

from helicalib.config import load_field_config
from helicalib.store.sqlite import Store
from helicalib.store.synthetic import build_synthetic_campaign, open_for_synthesis


@pytest.fixture(scope="module")
def two_campaigns(tmp_path_factory, demo_field_path):
    """A demo field's campaign of 3 days, then a second one of its first 25 heliostats."""
    cfg = load_field_config(demo_field_path)
    path = tmp_path_factory.mktemp("bulk") / "bulk.db"
    ids = [h.id for h in cfg.heliostats]
    with open_for_synthesis(path) as store:
        first = build_synthetic_campaign(store, cfg, days=3, per_day=15, seed=3)
        second = build_synthetic_campaign(store, cfg, days=2, per_day=10, seed=4, heliostat_ids=ids[:25],
                                          start="2026-10-01T00:00:00Z")
    return path, ids, first.campaign_id, second.campaign_id


def test_bulk_reads_equal_one_heliostat_at_a_time(two_campaigns):
    path, ids, c1, c2 = two_campaigns
    asked = ids + ["H-NOT-IN-FIELD"]
    with Store.open(path) as store:
        for cid in (c1, c2):
            obs, visits = store.observations_of(cid, asked), store.visits_of(cid, asked)
            fits = store.latest_fits(asked, campaign_id=cid)
            for hid in asked:
                assert obs.get(hid, []) == store.observations(campaign_id=cid, heliostat_id=hid)
                assert visits.get(hid, []) == store.visits(campaign_id=cid, heliostat_id=hid)
                assert fits.get(hid) == store.latest_fit(hid, campaign_id=cid)
        anywhere = store.latest_fits(asked)
        for hid in asked:
            assert anywhere.get(hid) == store.latest_fit(hid)
        # the second campaign holds only the first 25: the others' newest fit is the first campaign's
        assert anywhere[ids[30]].campaign_id == c1 and anywhere[ids[0]].campaign_id == c2
        assert sum(len(v) for v in store.observations_of(c2, ids).values()) == len(store.observations(campaign_id=c2))
        assert store.observations_of(c1, []) == {} and store.visits_of(c1, []) == {} and store.latest_fits([]) == {}
