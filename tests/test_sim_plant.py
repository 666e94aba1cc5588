"""In-process simulated plant: clock, weather, soiling, truth, state machine, sky-wide evaluation."""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.config import load_field_config
from helicalib.devices.protocols import Camera, Clock, Plant
from helicalib.devices.registers import HeliostatState
from helicalib.errors import ConfigError
from helicalib.geometry import optics
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import sun_at_site, to_unix_seconds
from helicalib.sim.camera import SimCamera
from helicalib.sim.clock import RateClock, VirtualClock
from helicalib.geometry.sun import year_sun_times
from helicalib.sim.evaluate import evaluate_model
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.sim.soiling import SoilingModel
from helicalib.sim.weather import WeatherModel, clear_sky_dni_wm2

START = float(to_unix_seconds("2026-03-20T04:00:00Z"))


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def test_virtual_clock_sleep_advances_and_notifies():
    seen = []
    c = VirtualClock(1000.0)
    c.on_advance(seen.append)
    c.sleep(2.5)
    c.sleep(0.0)
    assert c.now_s() == 1002.5 and seen == [1002.5, 1002.5]
    with pytest.raises(ValueError):
        c.sleep(-1)
    assert isinstance(c, Clock)


def test_rate_clock_runs_at_rate():
    t = [10.0]
    c = RateClock(5000.0, 600.0, lambda: t[0])
    t[0] = 12.0
    assert c.now_s() == pytest.approx(5000.0 + 1200.0)


def test_weather_is_deterministic_and_random_access(cfg):
    spec = parse_scenario({"weather": {"dni": {"cloudy_fraction": 0.3}}}).weather
    w = WeatherModel(spec, cfg.site, seed=4)
    times = START + np.arange(0, 86400, 600.0)
    a = w.wind_ms(times)
    b = np.array([float(WeatherModel(spec, cfg.site, seed=4).wind_ms(t)) for t in times[::-1]])[::-1]
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, WeatherModel(spec, cfg.site, seed=5).wind_ms(times))
    assert np.all(a >= 0)


def test_clouds_dim_dni_for_the_configured_share(cfg):
    spec = parse_scenario({"weather": {"dni": {"cloudy_fraction": 0.3, "cloud_attenuation": 1.0}}}).weather
    w = WeatherModel(spec, cfg.site, seed=2)
    trans = w.cloud_transmittance(START + np.arange(0, 60 * 86400, 60.0))
    assert 0.2 < np.mean(trans < 0.5) < 0.4
    clear = WeatherModel(parse_scenario({}).weather, cfg.site, seed=2)
    assert np.all(clear.cloud_transmittance(START + np.arange(0, 86400, 300.0)) == 1.0)


def test_clear_sky_dni_reference_values():
    # Meinel: I = 1353·0.7^(AM^0.678); scaled to 1000 at AM 1 → at AM 2 (el 30°): 1000·0.7^(2^0.678-1)
    am2 = 1.0 / (np.cos(np.radians(60.0)) + 0.50572 * (96.07995 - 60.0) ** -1.6364)
    assert float(clear_sky_dni_wm2(30.0, 1000.0)) == pytest.approx(1000 * 0.7 ** (am2**0.678 - 1), rel=1e-9)
    assert float(clear_sky_dni_wm2(-1.0, 1000.0)) == 0.0


def test_weather_event_overrides(cfg):
    spec = parse_scenario({"weather": {"events": [
        {"start": "2026-03-20T06:00:00Z", "end": "2026-03-20T07:00:00Z", "wind_ms": 18, "dni_factor": 0.0}]}}).weather
    w = WeatherModel(spec, cfg.site, seed=1)
    t_in = float(to_unix_seconds("2026-03-20T06:30:00Z"))
    assert float(w.wind_ms(t_in)) == 18.0 and float(w.dni_wm2(t_in)) == 0.0
    assert float(w.wind_ms(t_in + 3600)) != 18.0


def test_scenario_errors_name_the_key():
    with pytest.raises(ConfigError, match=r"weather\.wind\.bogus: unknown key"):
        parse_scenario({"weather": {"wind": {"bogus": 1}}})
    with pytest.raises(ConfigError, match="unknown error-model parameter"):
        parse_scenario({"errors": {"tilt": 1.0}})
    with pytest.raises(ConfigError, match=r"backlash_1_mm.*unmodelled\.backlash_mm"):
        parse_scenario({"errors": {"backlash_1_mm": 0.3}})


def test_soiling_falls_then_jumps_back_at_cleaning():
    spec = parse_scenario({"soiling": {"rate_per_day": 0.01, "rate_spread": 0.0, "cleaning_interval_days": 10,
                                       "clean_value": 0.95}}).soiling
    s = SoilingModel(spec, n=4, seed=1)
    days = np.arange(0, 30, 0.25)
    c = np.array([s.cleanliness(d * 86400.0) for d in days])       # (T, 4)
    assert np.all(c <= 0.95 + 1e-12) and np.all(c >= 0.95 - 0.1 - 1e-9)
    jumps = np.diff(c[:, 0]) > 0.05
    assert jumps.sum() == 2                                          # cleaned on days 10 and 20
    assert np.all(np.diff(c[:, 0])[~jumps] <= 1e-12)


def test_plant_implements_protocols(cfg):
    p = SimulatedPlant(cfg, start_s=START)
    assert isinstance(p, Plant) and isinstance(SimCamera(p, "C1"), Camera)
    assert p.heliostat_count() == 40 and p.plant_time() == (START, 1.0)


def test_zero_errors_nominal_command_lands_on_target_centre(cfg):
    p = SimulatedPlant(cfg, start_s=START, zero_errors=True)
    t_hold = START + 600.0
    sun = sun_at_site(cfg.site, t_hold).vector_enu
    # independent of the plant's own code: aim normal by the fixed point of FIELD_CONFIG "Optics"
    nominal = HeliostatModel.from_config(cfg)
    aims = np.array([cfg.target(h.target).center_enu_m for h in cfg.heliostats])
    sol = nominal.strokes_for_aim(sun, aims)
    assert sol.in_range.all()
    for i in range(p.n):
        p.move_to(i, sol.strokes_mm[i])
    p.advance_to(t_hold)
    assert np.all(p.state == 3)
    err = p.true_tracking_error_mrad()
    assert np.nanmax(err) < 0.01
    # cross-check with a hand-made ray: r = 2(s·n)n − s from M = P + offset·n
    beam = p.true_beams(jitter=False)
    n = beam.normal_enu
    r = 2 * np.sum(sun * n, axis=1, keepdims=True) * n - sun
    m = nominal.pivots_enu + nominal.mirror_offset_m[:, None] * n
    lam = np.sum((aims - m) * r, axis=1) / np.sum(r * r, axis=1)
    miss = np.linalg.norm(m + lam[:, None] * r - aims, axis=1)
    assert np.max(miss) < 1e-3


def test_hidden_errors_are_hidden_and_seeded(cfg):
    a = SimulatedPlant(cfg, parse_scenario({"seed": 3}), start_s=START)
    b = SimulatedPlant(cfg, parse_scenario({"seed": 3}), start_s=START)
    c = SimulatedPlant(cfg, parse_scenario({"seed": 4}), start_s=START)
    np.testing.assert_array_equal(a.truth.params0, b.truth.params0)
    assert not np.allclose(a.truth.params0, c.truth.params0)
    sun = sun_at_site(cfg.site, START).vector_enu
    aims = np.array([cfg.target(h.target).center_enu_m for h in cfg.heliostats])
    sol = a.nominal.strokes_for_aim(sun, aims)
    beam = a.truth.beam(sol.strokes_mm, sun, START, jitter=False)
    _, hit, _ = a.truth.spots(beam, a.targets)
    err = optics.tracking_error_mrad(hit, aims, a.nominal.pivots_enu)
    assert np.median(err) > 2.0                  # uncalibrated heliostats miss by mrads


def test_backlash_depends_on_approach_direction(cfg):
    sc = parse_scenario({"errors": {}, "unmodelled": {"backlash_mm": 1.0, "gravity_sag_mrad": 0.0,
                                                      "gravity_sag_spread_mrad": 0.0, "repeatability_mm": 0.0}})
    p = SimulatedPlant(cfg, sc, start_s=START)
    strokes = np.tile([900.0, 800.0], (p.n, 1))
    sun = sun_at_site(cfg.site, START).vector_enu
    up = p.truth.beam(strokes, sun, START, approach=np.ones((p.n, 2)), jitter=False).normal_enu
    down = p.truth.beam(strokes, sun, START, approach=-np.ones((p.n, 2)), jitter=False).normal_enu
    ang = np.degrees(np.arccos(np.clip(np.sum(up * down, axis=1), -1, 1)))
    assert np.all(ang > 0) and np.median(ang) > 0.01   # ~ a millimetre of stroke ≈ a milliradian


def test_holding_truth_is_nan_unless_holding(cfg):
    p = SimulatedPlant(cfg, start_s=START)
    assert np.all(np.isnan(p.true_tracking_error_mrad()))


def test_sky_evaluation_zero_for_true_params_without_unmodelled(cfg):
    sc = parse_scenario({"unmodelled": {"gravity_sag_mrad": 0.0, "gravity_sag_spread_mrad": 0.0,
                                        "drift_mrad_per_week": 0.0, "backlash_mm": 0.0}})
    p = SimulatedPlant(cfg, sc, start_s=START)
    times, sun = year_sun_times(cfg.site, 2026, step_days=30, step_min=60)
    assert len(times) > 50 and np.all(sun[:, 2] >= np.sin(np.radians(5.0)) - 1e-9)
    exact = evaluate_model(p.truth, p.truth.params0, times, sun)
    assert exact.field_rms_mrad < 1e-6
    nominal = evaluate_model(p.truth, p.nominal, times, sun)
    assert nominal.field_rms_mrad > 1.0 and nominal.rms_mrad.shape == (40,)
    assert nominal.field_p95_mrad >= np.sqrt(np.nanmean(nominal.errors_mrad**2)) * 0.9
    # the error is the beam's angle; formula (1) on the (obliquely seen) board says more, never much less
    ratio = nominal.errors_formula1_mrad / nominal.errors_mrad
    assert np.nanmin(ratio) > 0.97 and nominal.field_formula1_rms_mrad > nominal.field_rms_mrad


def test_sky_evaluation_has_backlash_as_the_tracking_plant_has_it(cfg):
    """The evaluation's backlash (each actuator last moved the way its strokes go next) is the
    state the simulated plant is really in while it tracks: same true error as the plant's beams."""
    sc = parse_scenario({"tracking_aim": "target",
                         "unmodelled": {"backlash_mm": 0.5, "repeatability_mm": 0.0, "wind_jitter_mrad_per_ms": 0.0}})
    p = SimulatedPlant(cfg, sc, start_s=START)
    t = START + 1800.0
    p.advance_to(t)
    assert np.all(p.state == HeliostatState.TRACKING)
    aim = np.array([tg.center_enu_m for tg in p.targets])
    _, hit, _ = p.truth.spots(p.true_beams(jitter=False), p.targets)
    plant_err = optics.tracking_error_mrad(hit, aim, p.truth.nominal.pivots_enu)
    sun = p.sun(t)[0][None, :]
    # compared in the plant's own metric, formula (1) on the board
    tracking = evaluate_model(p.truth, p.nominal, np.array([t]), sun, t_eval_s=t).errors_formula1_mrad[:, 0]
    geometry = evaluate_model(p.truth, p.nominal, np.array([t]), sun, t_eval_s=t,
                              backlash="none").errors_formula1_mrad[:, 0]
    np.testing.assert_allclose(tracking, plant_err, atol=0.01)
    assert np.max(np.abs(geometry - plant_err)) > 0.2
    with pytest.raises(ValueError, match="backlash"):
        evaluate_model(p.truth, p.nominal, np.array([t]), sun, backlash="sometimes")


@pytest.mark.parametrize("name", ["clear_week", "windy"])
def test_shipped_scenarios_load_and_run(cfg, name, demo_field_path):
    from helicalib.sim.scenario import load_scenario

    sc = load_scenario(demo_field_path.parents[1] / "simulations" / "scenarios" / f"{name}.yaml")
    start = float(to_unix_seconds(sc.start))
    p = SimulatedPlant(cfg, sc, start_s=start)
    p.advance_to(start + 86400.0)
    w = p.weather()
    assert w.wind_ms >= 0 and 0 <= w.wind_direction_deg < 360


def test_soiling_rows_give_the_field_values_of_those_rows():
    spec = parse_scenario({"soiling": {"rate_per_day": 0.01, "rate_spread": 0.3, "cleaning_interval_days": 10}}).soiling
    s = SoilingModel(spec, n=50, seed=3)
    s.clean(5 * 86400.0, np.arange(50) % 3 == 0)
    rows = np.array([0, 7, 9, 49])
    for t in (0.0, 4.5 * 86400.0, 6.25 * 86400.0, 23.0 * 86400.0):
        assert np.array_equal(s.cleanliness(t, rows=rows), s.cleanliness(t)[rows])
        assert np.array_equal(s.last_cleaning_s(t, rows=rows), s.last_cleaning_s(t)[rows])


def _plant_state(p):
    return [p.reg_command, p.reg_sequence, p.reg_corrections, p.sequence_done, p.fault, p.corrections_mm,
            p.mode, p.state, p.arrival_s, p.command_count, p.stroke_noise_mm]


def test_track_many_leaves_the_plant_as_one_track_per_heliostat(cfg):
    one, many = SimulatedPlant(cfg, start_s=START), SimulatedPlant(cfg, start_s=START)
    rng = np.random.default_rng(4)
    for p in (one, many):  # some heliostats already commanded, some offline
        p.move_to(3, p.strokes_mm[3] + 1.0)
        p.offline[11] = True
    idx = np.array([5, 3, 11, 0, 39, 17])
    corr = rng.normal(0.0, 2.0, (idx.size, 2))
    for _round in range(2):
        seqs = [one.track(int(i), c) for i, c in zip(idx, corr)]
        assert many.track_many(idx, corr).tolist() == seqs
        for a, b in zip(_plant_state(one), _plant_state(many)):
            np.testing.assert_array_equal(a, b)
        assert [one.status(i) for i in range(40)] == [many.status(i) for i in range(40)]
    one.field_command(1), many.field_command(1)  # a stow refuses the command: a fault code, no motion
    one.track(7, corr[0]), many.track_many([7], corr[:1])
    for a, b in zip(_plant_state(one), _plant_state(many)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError):
        many.track_many([1, 1], corr[:2])


def test_cleanliness_many_reads_what_status_gives(cfg):
    p = SimulatedPlant(cfg, start_s=START)
    p.advance_to(START + 2 * 86400.0)  # soiled since the start
    idx = np.array([0, 17, 5, 39])
    want = [p.status(i).cleanliness for i in idx]
    assert p.cleanliness_many(idx).tolist() == want
    q = SimulatedPlant(cfg, start_s=START)
    q.advance_to(START + 2 * 86400.0)  # nothing cached yet: read row by row
    assert q.cleanliness_many(idx).tolist() == want
    assert [q.cleanliness_of(i) for i in idx] == want


def test_the_weather_of_one_instant_equals_the_vectorised_weather():
    """The knots a scalar weather reading remembers give the very values the vectorised process gives."""
    import numpy as np

    from helicalib.sim import noise

    t = np.linspace(1.78e9, 1.78e9 + 3 * 86400.0, 400)
    vec = noise.smooth_normal(3, 11, t, 7200.0)
    one = np.array([noise.smooth_normal(3, 11, float(x), 7200.0) for x in t])
    assert np.array_equal(vec, one)
    assert np.array_equal(noise.smooth_normal(4, 11, t, 7200.0),
                          [noise.smooth_normal(4, 11, float(x), 7200.0) for x in t])
    assert not np.allclose(vec, noise.smooth_normal(4, 11, t, 7200.0))


def test_noise_normal_is_box_muller_of_its_two_uniforms():
    """``noise.normal`` hashes its keys once for both uniforms; its values are still Box–Muller on
    ``uniform(..., *keys, 0)`` and ``uniform(..., *keys, 1)`` (so the simulated weather and jitter of a
    given seed do not change), over scalar and broadcast keys, and standard normal in distribution."""
    from helicalib.sim import noise

    keys = np.arange(-20, 4000, dtype=np.int64)
    for args in [(1, 7, keys), (987654321, 3, keys, np.int64(5)), (2, 9, np.int64(42)),
                 (5, 1, keys[:12].reshape(4, 3), np.arange(3))]:
        u1, u2 = noise.uniform(*args, 0), noise.uniform(*args, 1)
        expected = np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
        got = noise.normal(*args)
        assert got.shape == expected.shape
        np.testing.assert_array_equal(got, expected)
    z = noise.normal(11, 4, np.arange(200_000))
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.01
