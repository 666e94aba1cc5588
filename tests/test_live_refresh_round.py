"""The tracking refresh on a plant that takes one track command per heliostat: a round sent a slice
of ``REFRESH_SLICE_S`` plant seconds per tick (less when a visit wakes sooner), a heliostat that
began a visit skipped, a superseded round's unwritten heliostats first in the next one.

The in-process simulated plant behind the plain plant protocol only (no bulk tracking), each track
command taking 0.5 plant seconds of its virtual clock, as a slow SCS would.
"""

from __future__ import annotations

from types import SimpleNamespace

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
    later = runner.devices.clock.now_s() + 60.0
    st.active[ids[per_slice]] = SimpleNamespace(wake_s=later)   # it began a visit: its visit writes its corrections
    runner.tracking.write_round()
    assert plant.tracked[per_slice:] == [cfg.heliostat_index(h) for h in ids[per_slice + 1:2 * per_slice + 1]]
    # a visit that wants its next step sooner than a slice ends the slice there (one command at least)
    st.active[ids[per_slice]].wake_s = runner.devices.clock.now_s() + 0.75 * TRACK_S
    runner.tracking.write_round()
    assert plant.tracked[2 * per_slice:] == [cfg.heliostat_index(ids[2 * per_slice + 1])]
    st.active[ids[per_slice]].wake_s = runner.devices.clock.now_s() - 1.0   # overdue: still one command
    runner.tracking.write_round()
    assert plant.tracked[2 * per_slice + 1:] == [cfg.heliostat_index(ids[2 * per_slice + 2])]
    del st.active[ids[per_slice]]
    unwritten = [hid for hid, _c in st.refresh_round.queue]
    assert unwritten == ids[2 * per_slice + 3:]
    runner.tracking.refresh(runner.devices.clock.now_s())   # the next round is due before this one ended
    order = [hid for hid, _c in st.refresh_round.queue]
    assert order[:len(unwritten)] == unwritten and sorted(order) == sorted(ids)
    while st.refresh_round is not None:
        runner.tracking.write_round()
    assert len(plant.tracked) == 2 * per_slice + 2 + len(ids)
    assert not store.events(campaign_id=cid, kind="fault")


def test_a_heliostat_whose_visit_began_and_ended_during_a_round_keeps_its_visit_s_corrections(
        demo_field_path, tmp_path):
    """The round's corrections were computed before the visit: once its visit has written newer
    ones, the rest of the round must not put the older ones back (in the plant or in the campaign)."""
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats[:20]]
    runner, sim, store, cid, _cams = inprocess_campaign(cfg, tmp_path, 10, 2, ids, plant=OneByOne)
    plant, st = runner.devices.plant, runner.state
    plant.clock = runner.devices.clock
    st.book.points = lambda hid: [hid]
    runner.tracking.refresh(runner.devices.clock.now_s())
    runner.tracking.write_round()                 # the first slice: the last heliostat not reached
    late = ids[-1]
    assert late in [hid for hid, _c in st.refresh_round.queue]
    runner._choose = lambda target_id, now: (late, False, False)   # the planner puts it on its board now
    assert runner._start_visit(cfg.heliostat(late).target, runner.devices.clock.now_s())
    st.active.pop(late)                           # ... its visit ends and writes corrections of its own
    fresh = np.array([9.99, -9.99])
    runner.tracking.written(late, fresh)
    sim.track(cfg.heliostat_index(late), fresh)
    while st.refresh_round is not None:
        runner.tracking.write_round()
    assert np.allclose(st.corrections[late], fresh)
    assert np.allclose(sim.corrections_mm[cfg.heliostat_index(late)], fresh)
    assert cfg.heliostat_index(late) not in plant.tracked
