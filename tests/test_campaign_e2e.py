"""End-to-end campaigns against the simulated plant over real loopback Modbus TCP and HTTP.

The plant is the real simulated plant served by the real servers; the campaign uses the real
Modbus and HTTP clients, a real SQLite file and real PNG frames. A plant subclass logs every
move command it receives, so "no stroke outside the range" is checked from the plant's side.
"""

from __future__ import annotations

import time
from contextlib import ExitStack

import cv2
import numpy as np
import pytest

from helicalib.campaign.loop import CampaignRunner
from helicalib.app.simulated import default_start_s
from helicalib.config import load_field_config
from helicalib.devices.camera_http import HttpCamera
from helicalib.devices.clock import PlantClock
from helicalib.devices.modbus import ModbusPlant
from helicalib.devices.registers import HeliostatCommand
from helicalib.sim.clock import RateClock
from helicalib.sim.lazy_plant import LazyPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.sim.server import FaultInjector, PlantServer
from helicalib.store.sqlite import Store

IDS = ["H0001", "H0040"]  # one heliostat on each target
MORNING_S = 6.6 * 3600.0  # local solar time of the start: the sun rises through the low band


class LoggingPlant(LazyPlant):
    """The simulated plant (the lazy one a simulation uses), logging every command it is asked to act on (the plant's side of the wire)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.moves: list[tuple[int, float, float]] = []

    def write_command(self, index, command, sequence, strokes_mm=None, corrections_mm=None):
        if int(command) == int(HeliostatCommand.MOVE) and strokes_mm is not None:
            self.moves.append((index, float(strokes_mm[0]), float(strokes_mm[1])))
        super().write_command(index, command, sequence, strokes_mm=strokes_mm, corrections_mm=corrections_mm)


def _run_network(cfg, tmp_path, hours, scenario=None, rate=800.0, faults=None):
    scenario = scenario or parse_scenario({"seed": 3})
    start = default_start_s(cfg) + MORNING_S
    sim = LoggingPlant(cfg, scenario, start_s=start, rate=rate)
    store = Store.open(tmp_path / "c.db", tmp_path / "images")
    with ExitStack() as stack:
        server = PlantServer(sim, RateClock(start, rate, time.monotonic, time.sleep), modbus_port=0, camera_port=0,
                             faults=faults or FaultInjector())
        stack.enter_context(server)
        ep = cfg.plant.scs.model_copy(update={"host": "127.0.0.1", "port": server.modbus_port, "timeout_s": 1.0})
        plant = ModbusPlant(ep, ep, len(cfg.heliostats), armed=True, heliostat_ids=[h.id for h in cfg.heliostats],
                            backoff_s=0.05)
        stack.callback(plant.close)
        cams = {t.id: HttpCamera(server.camera_url(cfg.cameras_for(t.id)[0].id), timeout_s=2.0, retries=1)
                for t in cfg.targets}
        clock = PlantClock(plant)
        cid = store.start_campaign(name="e2e", mode="simulate", started_s=start,
                                   heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in IDS])
        runner = CampaignRunner(cfg, plant, cams, clock, store, cid, heliostat_ids=IDS)
        runner.run_until(clock.now_s() + hours * 3600.0)
    return sim, store, cid, runner


@pytest.fixture(scope="module")
def network_campaign(tmp_path_factory, demo_field_path):
    cfg = load_field_config(demo_field_path)
    tmp = tmp_path_factory.mktemp("e2e")
    sim, store, cid, runner = _run_network(cfg, tmp, hours=3.0)
    yield cfg, sim, store, cid, runner, tmp
    store.close()


def test_campaign_over_loopback_records_valid_observations(network_campaign):
    cfg, sim, store, cid, runner, tmp = network_campaign
    obs = store.observations(campaign_id=cid)
    valid = [o for o in obs if o.valid]
    assert len(valid) >= 4, [(o.reason, o.message) for o in obs if not o.valid][:5]
    # each valid observation has its frames on disk, decodable, and a finite error
    for o in valid:
        assert np.isfinite(o.error_mrad)
        for rel in (o.before_frame_path, *o.after_frame_paths):
            img = cv2.imread(str(tmp / "images" / rel), cv2.IMREAD_UNCHANGED)
            assert img is not None and img.ndim == 2
    visits = store.visits(campaign_id=cid)
    assert {v.heliostat_id for v in visits} == set(IDS)
    assert all(v.outcome not in ("running",) for v in visits[:-2])


def test_loop_converges_below_threshold(network_campaign):
    cfg, sim, store, cid, runner, tmp = network_campaign
    visits = [v for v in store.visits(campaign_id=cid) if v.outcome == "converged"]
    assert visits, "no visit converged"
    assert all(v.final_error_mrad < cfg.calibration.loop_threshold_mrad for v in visits)


def test_no_stroke_outside_the_range_reached_the_plant(network_campaign):
    cfg, sim, store, cid, runner, tmp = network_campaign
    assert sim.moves, "the plant saw no move command"
    for index, s1, s2 in sim.moves:
        act = cfg.drive_of(cfg.heliostats[index].id).actuators
        assert act[0].stroke_range_mm[0] <= s1 <= act[0].stroke_range_mm[1]
        assert act[1].stroke_range_mm[0] <= s2 <= act[1].stroke_range_mm[1]
    assert not np.any(sim.fault == 1)


def test_faults_make_visits_invalid_and_the_campaign_goes_on(demo_field_path, tmp_path):
    cfg = load_field_config(demo_field_path)
    # per grab (one retry) about 1 in 4 fails: over a few hours both failures and valid visits are
    # certain to occur (P(no failure in 20 grabs) ~ 0.4 %, P(no valid visit in 10) ~ 0.02 %)
    faults = FaultInjector(camera_503_probability=0.4, camera_truncate_probability=0.15,
                           modbus_drop_probability=0.02)
    sim, store, cid, runner = _run_network(cfg, tmp_path, hours=4.0, faults=faults)
    obs = store.observations(campaign_id=cid)
    bad = [o for o in obs if not o.valid]
    reasons = {o.reason for o in bad}
    assert any(r.startswith("camera") for r in reasons), reasons
    assert all(o.message for o in bad)
    assert any(o.valid for o in obs), "the campaign stopped producing valid points after the faults"
    store.close()


def test_wind_gates_and_stows_within_one_poll(demo_field_path, tmp_path):
    from helicalib.campaign.field import WEATHER_POLL_S
    from helicalib.app.simulated import SimulationOptions, simulate_campaign
    from helicalib.devices.registers import FieldState

    cfg = load_field_config(demo_field_path)
    start = default_start_s(cfg) + MORNING_S + 2 * 3600
    iso = lambda s: time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(s))  # noqa: E731
    scenario = parse_scenario({"weather": {"wind": {"mean_ms": 2.0, "diurnal_amplitude_ms": 0.0, "variability_ms": 0.0},
                                           "events": [{"start": iso(start), "end": iso(start + 3600), "wind_ms": 12.0},
                                                      {"start": iso(start + 3600), "end": iso(start + 7200),
                                                       "wind_ms": 16.0}]}})
    res = simulate_campaign(cfg, tmp_path, SimulationOptions(days=2.5 / 24, seed=1, scenario=scenario, start_s=start,
                                                             heliostat_ids=IDS))
    store = Store.open(res.database)
    visits = store.visits()
    # 12 m/s (above wind_max 10): no visit starts in the first hour
    assert not [v for v in visits if start <= v.started_s < start + 3600]
    stows = store.events(kind="stow")
    assert stows, "no stow event"
    assert start + 3600 <= stows[0].time_s <= start + 3600 + WEATHER_POLL_S + 1e-6
    gated = store.events(kind="gated")
    assert gated and "wind" in gated[0].reason
    # no visit while stowed; the field resumes within one poll once the wind is back at or below wind_max
    assert not [v for v in visits if start + 3600 <= v.started_s < start + 7200]
    resumes = store.events(kind="resume")
    assert resumes and start + 7200 <= resumes[0].time_s <= start + 7200 + WEATHER_POLL_S + 1e-6
    store.close()
    assert not res.runner.state.stowed
    assert res.runner.devices.plant.field_state() == FieldState.TRACKING


def test_campaign_measures_mirror_cleanliness_from_the_spot(demo_field_path, tmp_path):
    """Issue 9: each valid visit records the cleanliness measured from the spot's power; the
    simulated plant's soiling records (the register) are the independent truth."""
    from helicalib.app.simulated import SimulationOptions, simulate_campaign

    cfg = load_field_config(demo_field_path)
    start = default_start_s(cfg) + MORNING_S + 3 * 3600
    res = simulate_campaign(cfg, tmp_path, SimulationOptions(days=2.0 / 24, seed=2, start_s=start, heliostat_ids=IDS))
    store = Store.open(res.database)
    valid = [o for o in store.observations(valid=True)]
    store.close()
    assert valid
    measured = [(o.cleanliness_measured, o.cleanliness) for o in valid if o.cleanliness_measured is not None]
    assert len(measured) >= 0.8 * len(valid), "most valid visits should measure the mirror's cleanliness"
    for got, plant in measured:
        assert abs(got - plant) < 0.03


def test_simulate_command_with_a_relative_out_dir(demo_field_path, tmp_path, monkeypatch):
    """`make demo` passes a relative --out: frames must land in OUT/images, where the report finds them."""
    import json
    import subprocess
    import sys

    monkeypatch.chdir(tmp_path)
    cfg = load_field_config(demo_field_path)
    start = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(default_start_s(cfg) + MORNING_S))
    r = subprocess.run([sys.executable, "-m", "helicalib", "simulate", str(demo_field_path), "--days", "0.05",
                        "--start", start, "--heliostats", "H0001", "--out", "out", "--json", "--report"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["visits"] >= 1
    frames = list((tmp_path / "out" / "images").rglob("*.png"))
    assert frames, sorted(str(p) for p in (tmp_path / "out").rglob("*"))[:10]
    assert not (tmp_path / "out" / "out").exists()
    store = Store.open(tmp_path / "out" / "helicalib.db")
    rel = store.observations()[0].before_frame_path
    store.close()
    assert (tmp_path / "out" / "images" / rel).is_file()


def test_demo_command_runs_simulate_with_its_defaults(demo_field_path, tmp_path):
    """`helicalib demo` (what `make demo` runs) hands simulate every option it reads: a night-time
    hour gives no visits (exit 1, said so), but a summary, a database and a report, no traceback."""
    import json
    import subprocess
    import sys

    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "helicalib", "demo", str(demo_field_path), "--days", "0.02",
                        "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1  # no visit at night
    assert json.loads((out / "summary.json").read_text())["visits"] == 0
    assert (out / "helicalib.db").is_file() and (out / "report" / "index.html").is_file()
