"""The gate a view shows is judged from the weather reading it shows beside it (the tick judges the
gate only when a board is free: with every board busy its reason quoted an older reading)."""

from __future__ import annotations

import dataclasses

import pytest

from campaign_helpers import inprocess_campaign
from helicalib.config import load_field_config


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


def test_the_snapshot_gate_follows_the_weather_shown_while_every_board_is_busy(cfg, tmp_path):
    ids = [h.id for h in cfg.heliostats][:4]
    runner, sim, store, _cid, _ = inprocess_campaign(cfg, tmp_path, 11, 3, ids)
    try:
        for _ in range(60):  # until every board holds a visit
            runner.run_until(sim.t_s + 20.0)
            if len(runner.state.active) >= len(cfg.targets):
                break
        assert len(runner.state.active) >= len(cfg.targets), "the boards never all held a visit"
        now = sim.t_s
        first = runner.snapshot(now)
        assert first.gate_open is True and f"{first.dni_wm2:.0f}" in first.gate_reason, first.gate_reason
        # the next reading, taken while the boards are busy: DNI under the minimum
        dim = dataclasses.replace(runner.state.last_weather, dni_wm2=cfg.gating.dni_min_wm2 - 5.0)
        runner.state.last_weather, runner.state.weather_time_s = dim, now
        shown = runner.snapshot(now)
        assert shown.dni_wm2 == dim.dni_wm2
        assert shown.gate_open is False and f"{dim.dni_wm2:.0f}" in shown.gate_reason, shown.gate_reason
    finally:
        store.close()
