"""A live run's cleanliness reads spread over ticks (campaign/field.py): a choice reads none itself
(those never read are read first on the field's reader thread); those read before are re-read a few per tick, the oldest first, once half
their maximum age (those never read first), on a thread of the field's while the ticks go on;
without the spread
(simulations) a choice reads what is due, as it always did.

The in-process simulated plant, its bulk cleanliness read logged.
"""

from __future__ import annotations

import threading

import numpy as np

from campaign_helpers import inprocess_campaign
from helicalib.campaign.field import CLEANLINESS_MAX_AGE_S, CLEANLINESS_SPREAD_ROWS, CLEANLINESS_TURN_ROWS
from helicalib.config import load_field_config


class Logged:
    """The simulated plant, each bulk cleanliness read's heliostat indices logged."""

    def __init__(self, sim):
        self.sim, self.reads = sim, []

    def __getattr__(self, name):
        return getattr(self.sim, name)

    def cleanliness_many(self, indices):
        self.reads.append([int(i) for i in indices])
        return self.sim.cleanliness_many(indices)


def test_a_live_choice_reads_none_itself_the_never_read_first_and_the_ticks_refresh_the_rest(demo_field_path, tmp_path):
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats]
    runner, sim, _store, _cid, _cams = inprocess_campaign(cfg, tmp_path, 10, 2, ids, plant=Logged)
    plant, field = runner.devices.plant, runner.field
    assert runner.devices.abilities.bulk_cleanliness
    rows = np.arange(len(ids))
    now = runner.devices.clock.now_s()
    field.spread_cleanliness = True
    wanted = rows[10:40]
    first = field.cleanliness_of_rows(wanted, now)                 # never read: asked, not read on the tick
    assert plant.reads == [] and np.all(np.isneginf(first))   # not read yet: not chosen (NaN: the plant gives none)
    field.refresh_cleanliness(now)                                 # read on the field's reader thread, those first
    field._clean_pending[1].result()
    index = [int(i) for i in runner.state.plant_index]
    asked = [i for r in plant.reads for i in r]                    # in turns of CLEANLINESS_TURN_ROWS
    assert all(len(r) <= CLEANLINESS_TURN_ROWS for r in plant.reads) and len(plant.reads) > 1
    assert asked[:30] == [index[r] for r in wanted]
    assert sorted(asked[30:]) == sorted(index[r] for r in rows if r not in wanted)[:len(asked) - 30]
    n = len(plant.reads)
    first = field.cleanliness_of_rows(wanted, now + 1.0)           # in: taken at once, no read of its own
    assert np.array_equal(first, sim.cleanliness_many(runner.state.plant_index[wanted])) and len(plant.reads) == n
    field.refresh_cleanliness(now + 2.0)                            # the rest of the field's first reads
    if field._clean_pending is not None:
        field._clean_pending[1].result()
        field.refresh_cleanliness(now + 3.0)
    assert np.all(np.isfinite(field.state.clean_rows[1])) and field._clean_pending is None
    plant.reads.clear()
    later = now + 2 * CLEANLINESS_MAX_AGE_S                         # all of them stale now
    again = field.cleanliness_of_rows(wanted, later)               # read before: served as read, none read
    assert plant.reads == [] and np.array_equal(again, first)
    values, read_at = field.state.clean_rows
    read_at[30:] = later                                           # read again just now: not stale
    read_at[:30] = now + np.arange(30)[::-1]                       # read at different times: row 29 the oldest
    values[:30] = -1.0
    field.refresh_cleanliness(later)                               # asked on the field's reader thread
    field._clean_pending[1].result()
    oldest = rows[:30][::-1][:CLEANLINESS_SPREAD_ROWS]
    assert sorted(plant.reads[0]) == sorted(int(runner.state.plant_index[r]) for r in oldest)
    assert np.all(read_at[oldest] == later) and np.all(values[oldest] == -1.0)   # in on the next tick
    field.refresh_cleanliness(later + 1.0)                          # the next tick: taken in, the rest asked
    assert np.array_equal(values[oldest], sim.cleanliness_many(runner.state.plant_index[oldest]))
    field._clean_pending[1].result()
    assert len(plant.reads[1]) == 30 - CLEANLINESS_SPREAD_ROWS
    field.refresh_cleanliness(later + 2.0)                          # taken in; none stale: nothing asked
    assert field._clean_pending is None and len(plant.reads) == 2 and np.all(values[:30] >= 0.0)
    read_at[5:8] = -np.inf                                         # never read: asked first, before any stale one
    read_at[20:30] = later - CLEANLINESS_MAX_AGE_S
    field.refresh_cleanliness(later + 3.0)
    field._clean_pending[1].result()
    assert plant.reads[2] == [int(runner.state.plant_index[r]) for r in (5, 6, 7)]
    field.close()


def test_without_the_spread_a_choice_reads_every_due_candidate(demo_field_path, tmp_path):
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats]
    runner, _sim, _store, _cid, _cams = inprocess_campaign(cfg, tmp_path, 10, 2, ids, plant=Logged)
    plant, field = runner.devices.plant, runner.field
    rows = np.arange(len(ids))
    now = runner.devices.clock.now_s()
    field.cleanliness_of_rows(rows[:30], now)
    field.cleanliness_of_rows(rows[:30], now + CLEANLINESS_MAX_AGE_S - 1.0)   # fresh: nothing read
    field.cleanliness_of_rows(rows[:30], now + CLEANLINESS_MAX_AGE_S)         # due: all 30 again
    assert [len(r) for r in plant.reads] == [30, 30]


def test_a_first_read_that_came_in_counts_for_the_next_choice_at_once(demo_field_path, tmp_path):
    """A heliostat whose first read was asked in the background and came in while the tick went on
    is seen by a choice with its value, not skipped until the next tick takes the read in."""
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats]
    runner, sim, _store, _cid, _cams = inprocess_campaign(cfg, tmp_path, 10, 2, ids, plant=Logged)
    plant, field = runner.devices.plant, runner.field
    field.spread_cleanliness = True
    now = runner.devices.clock.now_s()
    field.refresh_cleanliness(now)                                  # the field's first reads, in the background
    asked = np.asarray(sorted(field._clean_pending[0]))
    field._clean_pending[1].result()                                # in, not yet taken by a tick
    n = len(plant.reads)
    seen = field.cleanliness_of_rows(asked, now + 1.0)
    assert len(plant.reads) == n                                    # no second read of them
    assert np.array_equal(seen, sim.cleanliness_many(runner.state.plant_index[asked]))
    assert np.all(np.isfinite(seen)) and field._clean_pending is None
    field.close()


def test_a_heliostat_whose_first_read_is_not_in_is_not_chosen_on_its_spot_measured_cleanliness(
        demo_field_path, tmp_path):
    """Resumed or in operation, a heliostat has a cleanliness its spots measured; until the plant's
    first read of it is in, a live choice does not take that measure for the plant's (which may now be
    under the limit): no heliostat is chosen; once the reads are in, one is."""
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats]
    runner, _sim, _store, _cid, _cams = inprocess_campaign(cfg, tmp_path, 10, 2, ids, plant=Logged)
    field = runner.field
    field.spread_cleanliness = True
    runner.state.book.table.measured_cleanliness[:] = 0.95
    now = runner.devices.clock.now_s() + 6 * 3600.0  # the sun well up
    target = cfg.targets[0].id
    plant, held = runner.devices.plant, threading.Event()
    read = plant.cleanliness_many
    plant.cleanliness_many = lambda indices: (held.wait(30.0), read(indices))[1]  # on its way until let go
    try:
        assert runner._choose(target, now)[0] is None
        field.refresh_cleanliness(now)  # the first reads asked, on their way: still none chosen
        assert field._clean_pending is not None and runner._choose(target, now)[0] is None
        held.set()
        for k in range(20):  # the field's first reads, in the background, taken in by the next look
            field.refresh_cleanliness(now)
            if field._clean_pending is not None:
                field._clean_pending[1].result()
        assert np.all(np.isfinite(runner.state.clean_rows[1]))
        assert runner._choose(target, now)[0] is not None
    finally:
        held.set()
        field.close()
