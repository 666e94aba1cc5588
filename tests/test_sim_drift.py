"""The simulator's drift events (scenario key ``drift``): who drifts, when, how much, and what the
true geometry does before, during and after."""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.errors import ConfigError
from helicalib.geometry import error_model as em
from helicalib.geometry.sun import sun_at_site, to_unix_seconds
from helicalib.sim.scenario import parse_scenario
from helicalib.sim.truth import DAY_S, TrueField

START = float(to_unix_seconds("2026-03-20T00:00:00Z"))
NO_SLOW_DRIFT = {"drift_mrad_per_week": 0.0}


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def _truth(cfg, seed=1, **drift):
    sc = parse_scenario({"seed": seed, "duration_days": 30, "unmodelled": NO_SLOW_DRIFT, "drift": drift})
    return TrueField(cfg, sc, START)


def test_no_drift_section_means_no_events(cfg):
    assert _truth(cfg).drift_events == ()
    assert TrueField(cfg, parse_scenario({"drift": {"share": 1.0}}), START, zero=True).drift_events == ()


def test_events_are_drawn_within_their_ranges_and_reproducibly(cfg):
    truth = _truth(cfg, share=1.0, after_days=2, within_days=10)
    events = truth.drift_events
    assert len(events) == len(cfg.heliostats)  # share 1: every heliostat drifts once
    assert [e.to_dict() for e in events] == [e.to_dict() for e in _truth(cfg, share=1.0, after_days=2,
                                                                             within_days=10).drift_events]
    assert {e.kind for e in events} == {"settle", "actuator", "creep"}
    for e in events:
        assert START + 2 * DAY_S <= e.start_s <= START + 12 * DAY_S
        if e.kind == "settle":
            tilt = np.hypot(e.delta["pedestal_tilt_e_mrad"], e.delta["pedestal_tilt_n_mrad"])
            assert 2.0 - 1e-9 <= tilt <= 5.0 + 1e-9 and e.end_s == e.start_s
        elif e.kind == "actuator":
            (name, mm), = e.delta.items()
            assert name in ("stroke_offset_1_mm", "stroke_offset_2_mm") and 1.0 <= abs(mm) <= 3.0
        else:
            tilt = np.hypot(e.delta["pedestal_tilt_e_mrad"], e.delta["pedestal_tilt_n_mrad"])
            assert 0.1 * 30 - 1e-9 <= tilt <= 0.3 * 30 + 1e-9 and e.end_s == e.start_s + 30 * DAY_S
    other_seed = _truth(cfg, seed=2, share=1.0, after_days=2, within_days=10).drift_events
    assert [e.start_s for e in other_seed] != [e.start_s for e in events]


def test_the_share_and_the_kind_weights_are_kept(cfg):
    truth = _truth(cfg, share=0.25, kinds={"settle": 1.0})
    n = len(cfg.heliostats)
    k = len(truth.drift_events)
    sd = np.sqrt(n * 0.25 * 0.75)
    assert abs(k - 0.25 * n) <= 4 * sd and 0 < k < n
    assert {e.kind for e in truth.drift_events} == {"settle"}


def test_a_step_changes_exactly_its_heliostat_from_its_second_on(cfg):
    truth = _truth(cfg, share=0.5, kinds={"settle": 1.0, "actuator": 1.0})
    e = truth.drift_events[0]
    before, after = truth.params_at(e.start_s - 1.0), truth.params_at(e.start_s)
    change = after - before
    expected = np.zeros(em.P)
    for name, value in e.delta.items():
        expected[em.index(name)] = value
    np.testing.assert_allclose(change[e.row], expected, atol=1e-12)
    others = np.delete(np.arange(truth.n), [x.row for x in truth.drift_events if x.start_s == e.start_s])
    assert not np.any(change[others])
    # the model the plant's beams come from: the step acts at its own second, not at the next hour
    t_mid = e.start_s if e.start_s % 3600.0 else e.start_s + 1800.0
    np.testing.assert_allclose(truth.model_at(t_mid - 1.0).params, truth.params_at(t_mid - 1.0), atol=1e-12)
    np.testing.assert_allclose(truth.model_at(t_mid).params, truth.params_at(t_mid), atol=1e-12)
    assert truth.model_at(e.start_s).params[e.row] == pytest.approx(after[e.row])
    assert truth.model_at(e.start_s - 1.0).params[e.row] == pytest.approx(before[e.row])


def test_a_creep_grows_linearly_then_stays(cfg):
    truth = _truth(cfg, share=1.0, kinds={"creep": 1.0}, creep_days=10)
    e = truth.drift_events[0]
    p0 = truth.params_at(e.start_s)[e.row]
    half = truth.params_at(e.start_s + 5 * DAY_S)[e.row] - p0
    full = truth.params_at(e.end_s)[e.row] - p0
    later = truth.params_at(e.end_s + 20 * DAY_S)[e.row] - p0
    cols = [em.index("pedestal_tilt_e_mrad"), em.index("pedestal_tilt_n_mrad")]
    np.testing.assert_allclose(full[cols], [e.delta["pedestal_tilt_e_mrad"], e.delta["pedestal_tilt_n_mrad"]])
    np.testing.assert_allclose(half, 0.5 * full, atol=1e-12)
    np.testing.assert_allclose(later, full, atol=1e-12)


def test_a_settling_step_tilts_the_true_normal_by_its_size(cfg):
    truth = _truth(cfg, share=0.5, kinds={"settle": 1.0})
    e = truth.drift_events[0]
    tilt_mrad = np.hypot(e.delta["pedestal_tilt_e_mrad"], e.delta["pedestal_tilt_n_mrad"])
    sun = np.asarray(sun_at_site(cfg.site, e.start_s + 0.25 * DAY_S).vector_enu, float).reshape(3)
    strokes = np.array([[np.mean(a.stroke_range_mm) for a in cfg.drive_of(h.id).actuators] for h in cfg.heliostats])
    n0 = truth.beam(strokes, sun, e.start_s - 1.0, jitter=False).normal_enu[e.row]
    n1 = truth.beam(strokes, sun, e.start_s + 1.0, jitter=False).normal_enu[e.row]
    angle_mrad = 1000.0 * np.arccos(np.clip(n0 @ n1, -1.0, 1.0))
    # a small rotation by `tilt` about the horizontal axis (e, n) moves a unit vector by tilt · |axis × normal|
    axis = np.array([e.delta["pedestal_tilt_e_mrad"], e.delta["pedestal_tilt_n_mrad"], 0.0]) / tilt_mrad
    assert angle_mrad == pytest.approx(tilt_mrad * np.linalg.norm(np.cross(axis, n0)), rel=0.01)
    assert angle_mrad > 0.3 * tilt_mrad


@pytest.mark.parametrize("drift,says", [
    ({"settle_mrad": [5, 2]}, "drift.settle_mrad"),
    ({"kinds": {"sinking": 1.0}}, "drift.kinds"),
    ({"kinds": {"settle": 0.0}}, "positive sum"),
    ({"share": 1.5}, "drift.share"),
    ({"share": 0.1, "after_days": 40}, "drift.after_days"),
])
def test_bad_drift_sections_name_their_key(drift, says):
    with pytest.raises(ConfigError, match=says):
        parse_scenario({"duration_days": 30, "drift": drift}, "s.yaml")


def test_simulate_drift_share_reports_the_drift_it_met(cfg, demo_field_path, tmp_path, capsys):
    """``helicalib simulate … --drift-share 1 --json``: every heliostat of the field drifts once within
    the run (after its first tenth here), and the summary lists the events that began."""
    import json

    from helicalib.app.simulated import default_start_s
    from helicalib.cli import main
    from helicalib.commands.simulate import with_drift_share
    from helicalib.sim.scenario import Scenario

    days = 0.1
    start = default_start_s(cfg) + 7 * 3600
    iso = np.datetime64(int(start), "s").astype(str) + "Z"
    assert main(["simulate", str(demo_field_path), "--days", str(days), "--seed", "3", "--fidelity", "fast",
                 "--heliostats", "H0001,H0021", "--start", iso, "--drift-share", "1", "--out", str(tmp_path),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    sc = with_drift_share(Scenario(seed=3), 1.0, days)
    events = TrueField(cfg, sc, start).drift_events
    assert len(events) == len(cfg.heliostats)
    assert all(start + 0.01 * DAY_S <= e.start_s <= start + days * DAY_S for e in events)
    met = [e for e in events if e.start_s < start + days * DAY_S and e.heliostat_id in ("H0001", "H0021")]
    assert summary["drifted"] == len(met) == 2  # the campaign's heliostats' events only
    assert [e["heliostat_id"] for e in summary["drift_events"]] == [e.heliostat_id for e in met]
