"""The lazy simulated plant (heliostats in closed form, computed when read) against the stepped
reference (``SimulatedPlant(..., lazy=False)``): the same motions, states and approach at random
read times, and the same short campaign, measurement for measurement.

Tolerances: strokes 1e-9 mm and a campaign's offsets 1e-9 m / errors 1e-9 mrad. The closed form
adds a motion once (``base + clip(goal − base, ±speed · Δt)``) where stepping adds it step by step,
so the two may differ by a few ulp of a stroke (≈ 1e-13 mm), far below anything a beam resolves.
"""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helicalib.app.simulated import default_start_s
from helicalib.campaign.loop import CampaignRunner
from helicalib.config import load_field_config
from helicalib.devices.registers import FieldState, HeliostatState
from helicalib.sim.camera import simulated_flux
from helicalib.sim.clock import VirtualClock
from helicalib.sim.fast_sensor import fast_sensors
from helicalib.sim.lazy_plant import LazyPlant
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.store.sqlite import Store

STROKE_TOL_MM = 1e-9


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


@pytest.fixture(scope="module")
def demo(cfg):
    """The demo field's config behind a short repr (hypothesis prints its arguments)."""
    class Demo:
        field = cfg

        def __repr__(self) -> str:
            return "demo_north"
    return Demo()


def _iso(t_s: float) -> str:
    return datetime.fromtimestamp(t_s, UTC).isoformat()


def _pair(cfg, start_s: float, scenario=None):
    sc = parse_scenario({"seed": 3, **(scenario or {})})
    return (SimulatedPlant(cfg, sc, start_s=start_s), SimulatedPlant(cfg, sc, start_s=start_s, lazy=False))


def _same_status(lazy, ref, rows) -> None:
    for i in rows:
        a, b = lazy.status(int(i)), ref.status(int(i))
        assert a.state == b.state, (i, a.state, b.state)
        assert (a.sequence_done, a.fault, a.cleanliness) == (b.sequence_done, b.fault, b.cleanliness)
        np.testing.assert_allclose(a.strokes_mm, b.strokes_mm, rtol=0, atol=STROKE_TOL_MM)


def _same_field(lazy, ref) -> None:
    np.testing.assert_array_equal(lazy.state, ref.state)
    np.testing.assert_allclose(lazy.strokes_mm, ref.strokes_mm, rtol=0, atol=STROKE_TOL_MM)
    np.testing.assert_array_equal(lazy.approach, ref.approach)
    assert lazy.field_state() == ref.field_state()


def test_the_flag_chooses_the_motion(cfg):
    start = default_start_s(cfg) + 8 * 3600
    lazy, ref = _pair(cfg, start)
    assert isinstance(lazy, LazyPlant) and not isinstance(ref, LazyPlant)
    assert isinstance(lazy, SimulatedPlant)
    _same_field(lazy, ref)


def test_a_move_holds_after_travel_and_settle_as_stepped(cfg):
    start = default_start_s(cfg) + 9 * 3600
    lazy, ref = _pair(cfg, start)
    goal = ref.strokes_mm[4] + np.array([30.0, -12.0])  # 3 s of travel at 10 mm/s, then 3 s settle
    for p in (lazy, ref):
        p.move_to(4, goal)
    for dt in (1.0, 1.5, 0.5, 2.0, 1.0, 0.25, 300.0):
        for p in (lazy, ref):
            p.advance_to(p.t_s + dt)
        _same_status(lazy, ref, [4, 5])
        assert lazy.moving_rows().tolist() == ref.moving_rows().tolist()
    assert lazy.status(4).state == HeliostatState.HOLDING
    np.testing.assert_allclose(lazy.status(4).strokes_mm, goal, atol=STROKE_TOL_MM)
    _same_field(lazy, ref)


def test_a_wind_stow_mid_move_and_its_end_as_stepped(cfg):
    start = default_start_s(cfg) + 10 * 3600
    scenario = {"weather": {"events": [{"start": _iso(start + 1000.0), "end": _iso(start + 2500.0), "wind_ms": 25.0}]}}
    lazy, ref = _pair(cfg, start, scenario)
    for p in (lazy, ref):
        p.move_to(7, p.strokes_mm[7] + np.array([-200.0, 150.0]))
        p.advance_to(start + 990.0)
        p.move_to(9, p.strokes_mm[9] + np.array([120.0, 90.0]))  # still on its way when the wind comes
    seen = set()
    for t in np.arange(start + 995.0, start + 4000.0, 7.0):
        for p in (lazy, ref):
            p.advance_to(t)
        _same_status(lazy, ref, [7, 9, 20])
        assert lazy.field_state() == ref.field_state()
        seen.add(ref.field_state())
    assert seen == {FieldState.STOWING, FieldState.STOWED, FieldState.TRACKING}
    _same_field(lazy, ref)


def test_sunset_and_sunrise_send_tracking_heliostats_to_stow_and_back_as_stepped(cfg):
    start = default_start_s(cfg) + 19 * 3600  # an evening: the sun sets, rises at the next morning
    lazy, ref = _pair(cfg, start)
    for t in np.arange(start, start + 12 * 3600, 1234.5):
        for p in (lazy, ref):
            p.advance_to(t)
        _same_status(lazy, ref, [0, 13, 39])
    _same_field(lazy, ref)


_ops = st.lists(st.one_of(
    st.tuples(st.just("advance"), st.floats(0.5, 700.0)),
    st.tuples(st.just("move"), st.integers(0, 39), st.floats(-300.0, 300.0), st.floats(-300.0, 300.0)),
    st.tuples(st.just("track"), st.integers(0, 39), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)),
    st.tuples(st.just("track_many"), st.sets(st.integers(0, 39), min_size=1, max_size=40), st.floats(-2.0, 2.0)),
    st.tuples(st.just("stow"), st.integers(0, 39)),
    st.tuples(st.just("field"), st.sampled_from([1, 2])),
    st.tuples(st.just("offline"), st.integers(0, 39)),
    st.tuples(st.just("read"), st.sets(st.integers(0, 39), min_size=1, max_size=5)),
), min_size=1, max_size=25)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(hour=st.floats(5.0, 21.0), ops=_ops)
def test_closed_form_motion_equals_stepping_at_random_read_times(demo, hour, ops):
    """Moves (some out of range: FAULT), tracks, stows, field stow and resume, a heliostat going
    offline: both plants read alike at every read and at the end."""
    start = default_start_s(demo.field) + hour * 3600
    lazy, ref = _pair(demo.field, start)
    for op in ops:
        kind = op[0]
        if kind == "advance":
            for p in (lazy, ref):
                p.advance_to(p.t_s + op[1])
        elif kind == "move":
            goal = ref.strokes_mm[op[1]] + np.array(op[2:])
            assert lazy.move_to(op[1], goal) == ref.move_to(op[1], goal)
        elif kind == "track":
            assert lazy.track(op[1], np.array(op[2:])) == ref.track(op[1], np.array(op[2:]))
        elif kind == "track_many":
            idx = np.array(sorted(op[1]))
            corr = np.full((idx.size, 2), op[2])
            assert lazy.track_many(idx, corr).tolist() == ref.track_many(idx, corr).tolist()
        elif kind == "stow":
            assert lazy.stow(op[1]) == ref.stow(op[1])
        elif kind == "field":
            lazy.field_command(op[1]), ref.field_command(op[1])
        elif kind == "offline":
            lazy.offline[op[1]] = ref.offline[op[1]] = True
        else:
            _same_status(lazy, ref, sorted(op[1]))
            assert lazy.moving_rows().tolist() == ref.moving_rows().tolist()
            for i in op[1]:
                a, b = lazy.true_beam_of(i), ref.true_beam_of(i)
                np.testing.assert_allclose(a.direction_enu, b.direction_enu, rtol=0, atol=1e-12)
    _same_field(lazy, ref)


def _campaign(cfg, tmp_path, lazy: bool, days: float):
    start = default_start_s(cfg) + 6 * 3600
    # a wind stow in the afternoon: the field stows mid-campaign and resumes
    sc = parse_scenario({"seed": 5, "weather": {"events": [
        {"start": _iso(start + 0.2 * 86400), "end": _iso(start + 0.22 * 86400), "wind_ms": 20.0}]}})
    sim = SimulatedPlant(cfg, sc, start_s=start, lazy=lazy)
    clock = VirtualClock(start)
    clock.on_advance(sim.advance_to)
    store = Store.open(tmp_path / f"{lazy}.db", tmp_path / f"img{lazy}")
    ids = [h.id for h in cfg.heliostats]
    cid = store.start_campaign(name="t", mode="simulate", started_s=start,
                               heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in ids])
    runner = CampaignRunner(cfg, sim, fast_sensors(sim, seed=5), clock, store, cid, heliostat_ids=ids,
                            flux=simulated_flux(cfg, sc))
    runner.run_until(start + days * 86400.0)
    return store.observations(cid), store.visits(cid), store.latest_verdicts(cid), store.events(cid)


def test_the_same_campaign_on_the_lazy_and_the_stepped_plant(cfg, tmp_path):
    """0.3 plant day of the demo field, fast fidelity, a wind stow in it: the same visits, verdicts
    and measurements (validity, reason, times exactly; offsets, errors and strokes to float noise)."""
    lazy, ref = _campaign(cfg, tmp_path, True, 0.3), _campaign(cfg, tmp_path, False, 0.3)
    obs_a, obs_b = lazy[0], ref[0]
    assert len(obs_a) == len(obs_b) > 100
    assert sum(o.valid for o in obs_a) > 50
    for a, b in zip(obs_a, obs_b):
        assert (a.heliostat_id, a.target_id, a.iteration, a.valid, a.reason, a.capture_time_s, a.approach) == \
               (b.heliostat_id, b.target_id, b.iteration, b.valid, b.reason, b.capture_time_s, b.approach)
        for name, tol in (("offset_u_m", 1e-9), ("offset_v_m", 1e-9), ("error_mrad", 1e-9)):
            u, v = getattr(a, name), getattr(b, name)
            assert (u is None) == (v is None)
            if u is not None:
                assert u == pytest.approx(v, abs=tol, nan_ok=True)
        if a.strokes_read_mm is not None:
            np.testing.assert_allclose(a.strokes_read_mm, b.strokes_read_mm, rtol=0, atol=STROKE_TOL_MM)
    key = lambda v: (v.heliostat_id, v.target_id, v.started_s, v.ended_s, v.outcome, v.reason, v.iterations)
    assert [key(v) for v in lazy[1]] == [key(v) for v in ref[1]]
    assert {h: v.accepted for h, v in lazy[2].items()} == {h: v.accepted for h, v in ref[2].items()}
    assert [(e.kind, e.time_s) for e in lazy[3]] == [(e.kind, e.time_s) for e in ref[3]]
