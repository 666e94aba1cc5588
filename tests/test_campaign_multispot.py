"""Several heliostats in one board visit (campaign/board.py): their beams take turns on the board.

On the in-process simulated plant with rendered frames and a real store; and over a loopback
Modbus TCP + HTTP plant. The truth (where every beam lands) comes from the simulator, not from
the campaign's models.
"""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.campaign.board import Board
from helicalib.config import load_field_config
from helicalib.devices.registers import HeliostatState
from helicalib.errors import PlantError
from helicalib.geometry import optics

from campaign_helpers import inprocess_campaign


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def _t1(cfg, n):
    return [h.id for h in cfg.heliostats if h.target == "T1"][:n]


def _drain(gen):
    """Step a generator to its end; returns how many waits it yielded."""
    n = 0
    for _ in gen:
        n += 1
    return n


def test_the_frame_lock_goes_to_waiters_in_the_order_they_asked():
    b = Board("T1", cap=3)
    for h in ("A", "B", "C"):
        b.join(h)
    assert _drain(b.acquire("A")) == 0 and b.lock_holder == "A"
    waits_b, waits_c = b.acquire("B"), b.acquire("C")
    assert next(waits_b) > 0 and next(waits_c) > 0  # both wait while A measures
    b.release("A")
    assert b.lock_holder == "B"  # handed over to the first waiter, not to whoever asks next
    again = b.acquire("A")
    assert next(again) > 0  # A asks again: it waits behind C
    assert _drain(waits_b) == 0 and b.lock_holder == "B"
    assert next(waits_c) > 0
    b.leave("B")  # a visit that ends (or is stopped) gives its turn on
    assert b.lock_holder == "C" and _drain(waits_c) == 0
    b.release("C")
    assert b.lock_holder == "A" and _drain(again) == 0
    b.join("D")  # B's place is free again
    with pytest.raises(ValueError, match="at most 3"):
        b.join("E")


class _BoardWatch:
    """The board's camera, noting at every frame which beams light the board (the simulator's truth
    of where each beam lands) and, for the after frames, where the measured heliostat's beam is."""

    def __init__(self, inner, sim, target):
        self.inner, self.sim, self.target = inner, sim, target
        self.lit: list[tuple[float, tuple[int, ...]]] = []
        self.truth: dict[tuple[int, float], np.ndarray] = {}

    def grab(self):
        sim = self.sim
        beams = sim.true_beams(sim.t_s)  # as the renderer draws them (wind jitter included)
        uv, hit, valid = optics.intersect_target(beams.origin_enu, beams.direction_enu, self.target)
        with np.errstate(invalid="ignore"):
            on = valid & np.all(np.abs(uv) <= np.asarray(self.target.size_m) / 2.0, axis=-1)
        lit = tuple(int(i) for i in np.flatnonzero(on))
        self.lit.append((sim.t_s, lit))
        frame = self.inner.grab()
        for i in lit:
            self.truth[(i, round(frame.capture_time_s, 3))] = hit[i].copy()
        return frame


def test_visits_overlap_but_one_beam_at_a_time_lights_the_board(cfg, tmp_path):
    """Ten heliostats of one board, three visits at once (auto): visits overlap in time (the
    board is not idle while a heliostat slews to or from it), yet every frame shows at most one
    beam on the board, and every valid measurement agrees with the true spot as a lone one does."""
    ids = _t1(cfg, 10)
    watch = {}

    def camera(cam, sim, target):
        watch[target.id] = _BoardWatch(cam, sim, target)
        return watch[target.id]

    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path, 8, 5, ids, camera=camera, spots_per_board="auto")
    assert runner.state.boards["T1"].cap == 3
    runner.run_until(sim.t_s + 3 * 3600)
    visits = store.visits(campaign_id=cid)
    obs = [o for o in store.observations(campaign_id=cid) if o.valid]
    store.close()
    assert runner.state.stats.peak_on_board == 3 and runner.state.stats.shared_visits >= 10
    overlapping = sum(1 for a in visits for b in visits if a.id < b.id and a.target_id == b.target_id
                      and a.ended_s is not None and b.started_s < a.ended_s)
    assert overlapping >= 10
    for w in watch.values():  # (a heliostat of T1 may borrow T2 while T1 is busy)
        assert max(len(lit) for _t, lit in w.lit) <= 1
    assert max(len(lit) for _t, lit in watch["T1"].lit) == 1
    err = []
    for o in obs:
        true = watch[o.target_id].truth.get((cfg.heliostat_index(o.heliostat_id), round(o.capture_time_s, 3)))
        assert true is not None, (o.heliostat_id, o.target_id, o.capture_time_s)
        err.append(1000 * np.linalg.norm(np.asarray(o.spot_enu_m) - true))
    # against the beam as the renderer drew it: the vision's own error (about 1 mm on these boards)
    assert len(err) >= 20 and float(np.sqrt(np.mean(np.square(err)))) < 5.0, np.round(err, 1)


class _FaultOn:
    """The plant, with one heliostat whose move commands fail from the moment the test arms the fault."""

    def __init__(self, sim, victim: int):
        self.sim, self.victim, self.armed_fault = sim, victim, False
        self.faulted_at = None

    def __getattr__(self, name):
        return getattr(self.sim, name)

    def move_to(self, index, strokes):
        if index == self.victim and self.armed_fault:
            if self.faulted_at is None:
                self.faulted_at = self.sim.t_s
            raise PlantError(f"heliostat {index}: register write refused (injected)")
        return self.sim.move_to(index, strokes)


def test_a_fault_on_one_heliostat_parks_it_and_the_others_go_on_measuring(cfg, tmp_path):
    ids = _t1(cfg, 6)
    holder = {}

    def plant(sim):
        holder["p"] = _FaultOn(sim, cfg.heliostat_index(ids[0]))
        return holder["p"]

    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path, 8, 7, ids, plant=plant, spots_per_board=3)
    p = holder["p"]
    for _ in range(4000):  # until the victim is in a visit beside others on its board
        runner.run_until(sim.t_s + 5)
        if ids[0] in runner.state.boards["T1"].visitors and len(runner.state.boards["T1"].visitors) >= 2:
            break
    assert ids[0] in runner.state.boards["T1"].visitors and len(runner.state.boards["T1"].visitors) >= 2
    p.armed_fault = True
    runner.run_until(sim.t_s + 3600)
    visits = store.visits(campaign_id=cid)
    store.close()
    assert p.faulted_at is not None
    mine = [v for v in visits if v.heliostat_id == ids[0] and v.started_s <= p.faulted_at]
    assert mine[-1].outcome == "fault", mine[-1]
    later = [v for v in visits if v.heliostat_id != ids[0] and v.started_s >= p.faulted_at - 600
             and v.outcome == "converged"]
    assert len(later) >= 3  # the board went on serving the others
    # parked: back to tracking (its standby move failed, the track command did not), its turn given on
    assert sim.state[cfg.heliostat_index(ids[0])] == HeliostatState.TRACKING or ids[0] in runner.state.active
    assert runner.state.boards["T1"].lock_holder != ids[0] or ids[0] in runner.state.active


def test_one_spot_per_board_is_one_visit_at_a_time(cfg, tmp_path):
    """The default: one visit per board at a time."""
    ids = _t1(cfg, 6)
    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path, 8, 5, ids)
    runner.run_until(sim.t_s + 2 * 3600)
    visits = sorted(store.visits(campaign_id=cid), key=lambda v: v.started_s)
    store.close()
    assert runner.state.stats.peak_on_board == 1 and runner.state.stats.shared_visits == 0
    assert len(visits) >= 6
    for board in {v.target_id for v in visits}:  # (T1's heliostats may borrow T2)
        on = [v for v in visits if v.target_id == board]
        assert all(a.ended_s <= b.started_s for a, b in zip(on, on[1:]) if a.ended_s is not None)


def test_simulate_over_loopback_with_three_visits_per_board(cfg, tmp_path, capsys):
    """``helicalib simulate --over-network --spots-per-board auto``: a real Modbus TCP + HTTP plant
    on 127.0.0.1; visits overlap on the board, every one ends with its reason, none is lost."""
    import json

    from helicalib.cli import main

    ids = ",".join(_t1(cfg, 5))
    rc = main(["simulate", str(cfg.source), "--days", "0.06", "--over-network", "--spots-per-board", "auto",
               "--heliostats", ids, "--start", "2026-06-01T07:00:00+06:18", "--seed", "4", "--rate", "500",
               "--out", str(tmp_path / "sim"), "--json"])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert s["spots_per_board"] == "auto" and s["peak_visits_on_a_board"] >= 2 and s["shared_visits"] >= 2
    from helicalib.store.sqlite import Store

    store = Store.open(tmp_path / "sim" / "helicalib.db", "images")
    visits = store.visits(campaign_id=1)
    store.close()
    assert all(v.outcome in ("converged", "not_converged", "invalid", "refused", "fault") for v in visits
               if v.ended_s is not None)
    assert sum(1 for v in visits if v.outcome == "converged") >= 3
