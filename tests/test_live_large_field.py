"""A live run against a field larger than one Modbus unit id reaches (2016 heliostats in
PLANT_INTERFACE.md's layout): the demo field grown to 2500 heliostats, served on loopback in the
``plant-interface-1-units`` map (units 1 and 2), the real pymodbus server and client, HTTP cameras
rendering frames, and the controller on APScheduler (``run_live``) at 100× plant time.

Heliostats of both units are calibrated: a visit's moves and its return to tracking must reach the
mirror the camera sees (a valid measurement is the beam of the heliostat commanded), and the
tracking refresh writes a calibrated heliostat's corrections into its own registers on unit 2.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pytest
import yaml

from helicalib.app import live
from helicalib.app.simulated import _network_plant, default_start_s
from helicalib.campaign import verdict as verdicts
from helicalib.campaign.loop import CampaignRunner
from helicalib.config import load_field_config
from helicalib.devices.regmap import load_register_map, register_map_of
from helicalib.errors import ConfigError
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.sim.scenario import Scenario
from helicalib.store.records import Observation
from helicalib.store.sqlite import Store

N = 2500
RATE = 100.0
UNIT2_COPY = 50
"""The copy of the demo's 40 heliostats (2000..2039: the first blocks of unit 2) left on the demo's places."""


@pytest.fixture(scope="module")
def big_field(tmp_path_factory, demo_field_path):
    """The demo field's boards, cameras and drives with 2500 heliostats (copies of the demo's, each its
    own block) in the units map, as ``heliostats_csv``; one copy on the demo's own places on unit 2."""
    folder = tmp_path_factory.mktemp("big")
    doc = yaml.safe_load(Path(demo_field_path).read_text(encoding="utf-8"))
    demo = doc.pop("heliostats")
    rows = ["id,e_m,n_m,u_m,drive,target"]
    for k in range(N):
        h, copy = demo[k % len(demo)], k // len(demo)
        # the demo's own places for the copy on unit 2 (2000..), the others 300 m apart further north
        shift = (0.0, 0.0) if copy == UNIT2_COPY else ((copy % 8 - 4) * 300.0, (copy // 8 + 1) * 300.0)
        e, n, u = h["position_enu_m"]
        rows.append(",".join([f"H{k + 1:05d}", f"{e + shift[0]:.2f}", f"{n + shift[1]:.2f}", str(u), h["drive"],
                              h["target"]]))
    (folder / "field.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    doc["heliostats_csv"] = "field.csv"
    doc["plant"]["register_map"] = "plant-interface-1-units"
    (folder / "field.yaml").write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    cfg = load_field_config(folder / "field.yaml")
    assert cfg.heliostats[UNIT2_COPY * len(demo)].position_enu_m == pytest.approx(demo[0]["position_enu_m"])
    return cfg


def test_a_live_run_commands_heliostats_on_every_unit_of_a_field_beyond_2016(big_field, tmp_path):
    cfg = big_field
    with pytest.raises(ConfigError, match=r"beyond 65535"):  # the default map cannot address this field
        load_register_map("plant-interface-1").check_count(N)
    on_place = cfg.heliostats[2000:2040]                                     # unit 2, the demo's own places
    visited = [next(h.id for h in on_place if h.target == t.id) for t in cfg.targets[:2]]
    seeded = next(h.id for h in on_place[::-1] if h.id not in visited)
    ids = [*visited, seeded]
    start = default_start_s(cfg) + 9.5 * 3600
    with ExitStack() as stack:
        plant, cameras, clock, sim, server = _network_plant(cfg, Scenario(seed=3), start, RATE, stack,
                                                            register_map=register_map_of(cfg))
        assert server.units == {1, 2} and server.registers.map.name == "plant-interface-1-units"
        store = stack.enter_context(Store.open(tmp_path / "c.db", tmp_path / "img"))
        now = clock.now_s()
        cid = store.start_campaign(name="t", mode="live", started_s=now,
                                   heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in ids])
        _seed_point(cfg, store, cid, seeded, now - 86400.0)     # calibrated: the refresh writes its corrections
        runner = CampaignRunner(cfg, plant, cameras, clock, store, cid, heliostat_ids=ids,
                                planner="round-robin")
        result = live.run_live(runner, now + 3000.0, done=lambda: sum(runner.state.stats.outcomes.values()) >= 2
                               and runner.state.refresh_round is None and runner.state.corrections[seeded] is not None)
        observations = store.observations(campaign_id=cid)
        visits = store.visits(campaign_id=cid)
        corrections = dict(runner.state.corrections)
        said = [(round(e.time_s - now), e.kind, e.reason) for e in store.events(campaign_id=cid)]
    assert result.reason == "done" and not result.off_tracking, said
    for hid in visited:                                        # the beam the camera measured is the one commanded
        i = cfg.heliostat_index(hid)
        assert server.registers.map.unit_step(i) == 1 and sim.command_count[i] >= 2
        assert any(o.valid and o.heliostat_id == hid for o in observations), [(o.heliostat_id, o.reason)
                                                                               for o in observations]
    assert {v.heliostat_id for v in visits} >= set(visited)
    i = cfg.heliostat_index(seeded)
    assert corrections[seeded] is not None and np.any(np.abs(corrections[seeded]) > 1e-3)
    assert sim.corrections_mm[i] == pytest.approx(corrections[seeded], abs=1e-4)   # in its own registers, on unit 2
    assert not np.any(sim.command_count[:2000])                 # nothing on unit 1 was commanded


def _seed_point(cfg, store, cid, hid, t):
    """One visit of the day before with a located point 0.3 m right of the board's centre (the nominal
    model's strokes for the centre) and its fit: a model whose tracking corrections are not zero."""
    from helicalib.geometry.sun import SunTable

    target = cfg.target(cfg.heliostat(hid).target)
    vec, az, el, rising = SunTable(cfg.site).position(t)
    strokes = HeliostatModel.from_config(cfg, [hid]).strokes_for_aim(np.asarray(vec), np.asarray(target.center_enu_m))
    s = tuple(float(x) for x in strokes.strokes_mm[0])
    spot = target.uvw_to_enu(np.array([0.3, 0.0, 0.0]))
    visit = store.begin_visit(cid, hid, target.id, t - 120.0)
    store.end_visit(visit, ended_s=t + 60.0, outcome="converged", reason="ok", iterations=1)
    store.record_observation(Observation(
        campaign_id=cid, heliostat_id=hid, target_id=target.id, visit_id=visit, iteration=0, capture_time_s=t,
        strokes_cmd_mm=s, strokes_read_mm=s, sun_enu=tuple(float(x) for x in vec), sun_azimuth_deg=float(az),
        sun_elevation_deg=float(el), sun_rising=bool(rising), valid=True,
        spot_enu_m=tuple(float(x) for x in spot), error_mrad=1.0))
    nominal = HeliostatModel.from_config(cfg, [hid])            # its fit, as a visit's refit records it
    _model, fit = verdicts.refit(nominal, store.observations(campaign_id=cid, heliostat_id=hid), nominal)
    store.record_fit(campaign_id=cid, heliostat_id=hid, time_s=t, **verdicts.fit_record(fit))
