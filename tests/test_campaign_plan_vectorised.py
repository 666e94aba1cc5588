"""The gaps planner over arrays (choice.choose_next_vectorised) makes the same choice as the
reference (choice.choose_next), on the states of a real simulated campaign."""

from __future__ import annotations

import numpy as np

from helicalib.campaign import choice
from helicalib.campaign.book import Book, PlanTable
from helicalib.campaign.choice import choose_next
from helicalib.campaign.verdict import verdict
from helicalib.config import load_field_config
from helicalib.calibration import acceptance
from helicalib.sim.fast_sensor import FastSensor, SensorErrorModel

from campaign_helpers import inprocess_campaign


def _reference(runner, target_id, now, busy, active, cleanliness, recheck, refine, spreads, usable):
    cfg = runner.cfg
    guests = {h: r for h, r in runner.state.guests.get(target_id, {}).items() if cfg.heliostat(h).target in active}
    cands = runner.state.home[target_id]
    return choose_next(cfg, runner.state.book, cands, now, {h: cleanliness.get(h) for h in [*cands, *guests]},
                       planner="gaps", recheck=recheck, busy_heliostats=busy, refine=refine, spreads=spreads,
                       target_id=target_id, guests=guests, usable=usable)


def test_vectorised_gaps_planner_chooses_as_the_reference_on_a_real_campaign(demo_field_path, tmp_path):
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats]
    model = SensorErrorModel.load()
    runner, sim, store, _cid, _cams = inprocess_campaign(
        cfg, tmp_path, hours=5.5, seed=3, ids=ids, camera=lambda cam, sim, target: FastSensor(sim, target.id, model, 3))
    rng = np.random.default_rng(7)
    compared = {"n": 0, "chosen": 0, "guest_refusals": 0, "states": set()}
    real = choice.choose_next_vectorised

    def checked(cfg_, book, target_id, now, cleanliness, **kw):
        choice = real(cfg_, book, target_id, now, cleanliness, **kw)
        rows = np.arange(len(runner.state.ids))
        plant = dict(zip(runner.state.ids, cleanliness(rows)))
        plant = {h: (None if not np.isfinite(v) else float(v)) for h, v in plant.items()}
        ref = _reference(runner, target_id, now, kw["busy_heliostats"], kw["active_targets"], plant,
                         kw["recheck"], kw["refine"], kw["spreads"], kw["usable"])
        assert choice == ref, (target_id, now)
        # and on varied inputs at the same state: other boards busy, heliostats busy, dirty mirrors,
        # a re-check, guests that cannot reach the board
        for _ in range(int(rng.random() < 0.25)):
            active = [t.id for t in cfg.targets if rng.random() < 0.6 and t.id != target_id]
            busy = list(rng.choice(runner.state.ids, size=3, replace=False))
            dirty = {h: (None if rng.random() < 0.1 else (0.5 if rng.random() < 0.1 else v)) for h, v in plant.items()}
            rows_clean = np.array([np.nan if dirty[h] is None else dirty[h] for h in runner.state.ids])
            recheck = bool(rng.random() < 0.2)
            refuse = set(rng.choice(runner.state.ids, size=len(runner.state.ids) // 2, replace=False))

            def usable(h):
                compared["guest_refusals"] += h in refuse
                return h not in refuse

            got = real(cfg_, book, target_id, now, lambda r: rows_clean[r], recheck=recheck, busy_heliostats=busy,
                       refine=False, spreads=None, active_targets=active, usable=usable)
            want = _reference(runner, target_id, now, busy, active, dirty, recheck, False, None, usable)
            assert got == want, (target_id, now, active, busy, recheck)
            compared["n"] += 1
        compared["chosen"] += choice is not None
        compared["states"].update(book.table.need.tolist())
        return choice

    choice.choose_next_vectorised = checked
    try:
        runner.run_until(runner.devices.clock.now_s() + 1.1 * 86400.0)
    finally:
        choice.choose_next_vectorised = real
        store.close()
    # the comparison saw real variety: many decisions, verdicts of several kinds, guests refused
    assert compared["chosen"] >= 100 and compared["n"] >= 500
    assert len(compared["states"]) >= 4 and PlanTable.BLANK in compared["states"]
    assert compared["guest_refusals"] > 0
    assert sum(runner.state.book.accepted(h) for h in ids) > 0


def test_the_plan_table_follows_every_write_to_the_book(demo_field_path):
    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats]
    book = Book(cfg, ids)
    tb = book.table
    b = book.h[ids[3]]
    b.visits = 4
    b.cooldown_until_s = 123.0
    b.last_first_error_mrad = 2.5
    b.measured_cleanliness = 0.93
    r = tb.row[ids[3]]
    assert (tb.visits[r], tb.cooldown_until_s[r], tb.predicted_error_mrad[r], tb.measured_cleanliness[r]) == \
        (4, 123.0, 2.5, 0.93)
    assert tb.need[r] == PlanTable.BLANK and not tb.accepted[r]
    v = verdict(cfg, book, ids[0], None, 0.0)
    b.points.append(object())  # a point with no verdict yet
    tb.update(r, b)
    assert tb.need[r] == PlanTable.UNJUDGED
    book.set_verdict(ids[3], v)
    assert tb.need[r] >= 0 and tb.needs[tb.need[r]] == acceptance.needs(v, cfg.acceptance)
    assert tb.visits[tb.row[ids[2]]] == 0  # other rows untouched
