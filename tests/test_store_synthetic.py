"""The synthetic campaign database (helicalib.store.synthetic): its rows read back through the store."""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.store.sqlite import Store
from helicalib.store.synthetic import build_synthetic_campaign, open_for_synthesis

FIELD = "field_config/demo_north.yaml"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    cfg = load_field_config(FIELD)
    path = tmp_path_factory.mktemp("syn") / "syn.db"
    seen = []
    with open_for_synthesis(path) as store:
        summary = build_synthetic_campaign(store, cfg, days=6, per_day=10, frame_shape=(48, 64),
                                           progress=lambda d, n: seen.append((d, n)))
    return cfg, path, summary, seen


def test_counts_match_what_the_store_reads_back(built):
    cfg, path, s, seen = built
    with Store.open(path, readonly=True) as store:
        assert store.count_observations(s.campaign_id) == s.observations
        assert len(store.visits(s.campaign_id)) == s.visits
        assert len(store.fits(s.campaign_id)) == s.fits
        assert len(store.verdicts(s.campaign_id)) == s.verdicts
        assert len(store.events(s.campaign_id)) == s.events
        assert [h.heliostat_id for h in store.campaign_heliostats(s.campaign_id)] == [h.id for h in cfg.heliostats]
        assert store.campaign(s.campaign_id).status == "finished"
        frames = list((store.images_dir / f"c{s.campaign_id}").rglob("*.png"))
    assert len(frames) == s.frames == 2 * s.observations
    assert seen[-1] == (len(cfg.heliostats), len(cfg.heliostats))


def test_commissioning_follows_the_paper_s_bands(built):
    cfg, path, s, _ = built
    with Store.open(path, readonly=True) as store:
        obs = store.observations(s.campaign_id)
        verdicts = store.latest_verdicts(s.campaign_id)
    first = {}
    for o in obs:
        first.setdefault(o.heliostat_id, []).append(o)
    h0 = first[cfg.heliostats[0].id]
    elevations = [o.sun_elevation_deg for o in h0 if o.iteration == 0][:5]
    assert 5.0 <= elevations[0] <= 15.0 and h0[0].sun_rising  # the rising band first
    assert 5.0 <= elevations[4] <= 15.0                       # the setting band last
    assert all(e > 15.0 for e in elevations[1:4])
    assert 10 * 1 <= sum(v.accepted for v in verdicts.values()) <= len(cfg.heliostats)
    valid = np.array([o.valid for o in obs])
    assert 0.9 < valid.mean() < 1.0  # a few invalid readings, each with a reason
    assert {o.reason for o in obs if not o.valid} <= {"clipped", "no_spot", "low_contrast", "camera_timeout"}
