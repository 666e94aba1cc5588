"""The tracking refresh on a plant that takes one track command per heliostat: a round sent a slice
of ``REFRESH_SLICE_S`` plant seconds per tick, a heliostat that began a visit skipped, a superseded
round's unwritten heliostats first in the next one.

The in-process simulated plant behind the plain plant protocol only (no bulk tracking), each track
command taking 0.5 plant seconds of its virtual clock, as a slow SCS would.
"""

from __future__ import annotations

import numpy as np

from campaign_helpers import inprocess_campaign
from helicalib.campaign.tracking import REFRESH_SLICE_S
from helicalib.config import load_field_config

TRACK_S = 0.5


class OneByOne:
    """The simulated plant through :class:`~helicalib.devices.protocols.Plant` alone; a track takes
    :data:`TRACK_S` plant seconds."""

    def __init__(self, sim):
        self.sim, self.clock, self.tracked = sim, None, []

    def __getattr__(self, name):
        if name in ("heliostat_count", "plant_time", "weather", "field_state", "field_command", "status", "move_to",
                    "stow"):
            return getattr(self.sim, name)
        raise AttributeError(name)

    def track(self, index, corrections_mm):
        self.tracked.append(int(index))
        self.clock.sleep(TRACK_S)
        return self.sim.track(index, corrections_mm)


def test_a_refresh_round_goes_out_a_slice_per_tick_and_a_superseded_one_first(demo_field_path, tmp_path):
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats[:20]]
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path, 10, 2, ids, plant=OneByOne)
    plant, st = runner.devices.plant, runner.state
    plant.clock = runner.devices.clock
    assert not runner.devices.abilities.bulk_tracking
    st.book.points = lambda hid: [hid]            # every heliostat calibrated: each one's corrections rewritten
    now = runner.devices.clock.now_s()
    runner.tracking.refresh(now)
    assert plant.tracked == [] and len(st.refresh_round.queue) == 20   # computed now, written after the visits
    per_slice = int(REFRESH_SLICE_S / TRACK_S)
    runner.tracking.write_round()
    assert plant.tracked == [cfg.heliostat_index(h) for h in ids[:per_slice]]
    for hid in ids[:per_slice]:                  # written into the plant's registers, kept by the campaign
        assert np.allclose(sim.corrections_mm[cfg.heliostat_index(hid)], st.corrections[hid])
    st.active[ids[per_slice]] = object()         # it began a visit: its visit writes its corrections
    runner.tracking.write_round()
    assert plant.tracked[per_slice:] == [cfg.heliostat_index(h) for h in ids[per_slice + 1:2 * per_slice + 1]]
    del st.active[ids[per_slice]]
    unwritten = [hid for hid, _c in st.refresh_round.queue]
    assert unwritten == ids[2 * per_slice + 1:]
    runner.tracking.refresh(runner.devices.clock.now_s())   # the next round is due before this one ended
    order = [hid for hid, _c in st.refresh_round.queue]
    assert order[:len(unwritten)] == unwritten and sorted(order) == sorted(ids)
    while st.refresh_round is not None:
        runner.tracking.write_round()
    assert len(plant.tracked) == 2 * per_slice + len(ids)
    assert not store.events(campaign_id=cid, kind="fault")
