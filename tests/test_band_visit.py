"""A visit in the 5–15° band ends at its first valid point; above the band it runs its loop.

On the in-process simulated plant (fast fidelity: the fitted sensor model), demo field, a real
store: new heliostats' first placements miss the board's centre by more than the loop threshold,
so outside the band they take a second placement, inside it they leave after the band point.
"""

from __future__ import annotations

import pytest

from helicalib.app.simulated import (
    SimulationOptions,
    default_start_s,
    simulate_campaign,
)
from helicalib.calibration.sun_days import sun_days
from helicalib.campaign.visit_types import VisitSettings
from helicalib.config import load_field_config
from helicalib.store.sqlite import Store

IDS = ["H0001", "H0005", "H0011", "H0030", "H0040", "H0022"]


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


@pytest.fixture(scope="module")
def rising(cfg):
    """(start, end) [UTC s] of the demo start day's rising 5–15° crossing."""
    start = default_start_s(cfg)
    day = sun_days(cfg.site, start, start + 86400.0, cfg.acceptance.low_band_deg, cfg.acceptance.high_elevation_deg)[0]
    return day.rise_band_start_s, day.rise_band_end_s


def _run(cfg, tmp_path, start_s: float, hours: float):
    res = simulate_campaign(cfg, tmp_path, SimulationOptions(hours / 24.0, seed=3, start_s=start_s, heliostat_ids=IDS,
                                                             fidelity="fast", spots_per_board="auto"))
    store = Store.open(res.database)
    try:
        return store.visits(), store.observations()
    finally:
        store.close()


def test_the_settings_carry_the_acceptance_band(cfg):
    assert VisitSettings.from_config(cfg).band_deg == tuple(float(x) for x in cfg.acceptance.low_band_deg)


def test_a_visit_in_the_band_leaves_after_its_first_valid_point(cfg, tmp_path, rising):
    lo, hi = cfg.acceptance.low_band_deg
    visits, obs = _run(cfg, tmp_path, rising[0] - 120.0, 0.5)
    in_band = 0
    for v in visits:
        valid = [o for o in obs if o.visit_id == v.id and o.valid and o.iteration >= 0]
        if v.ended_s is None or not valid or not all(lo <= o.sun_elevation_deg <= hi for o in valid):
            continue
        in_band += 1
        assert len(valid) == 1, (v.heliostat_id, [round(o.error_mrad, 2) for o in valid])
        if valid[0].error_mrad >= cfg.calibration.loop_threshold_mrad:
            assert v.outcome == "not_converged" and v.reason.startswith("band point"), (v.outcome, v.reason)
        else:
            assert v.outcome == "converged"
    band_points = [v for v in visits if v.reason.startswith("band point")]
    assert in_band >= len(IDS) and band_points  # every heliostat got its band point, new models left it early


def test_above_the_band_a_visit_still_converges(cfg, tmp_path, rising):
    visits, obs = _run(cfg, tmp_path, rising[1] + 1800.0, 0.4)
    hi = cfg.acceptance.low_band_deg[1]
    assert visits and not [v for v in visits if v.reason.startswith("band point")]
    second = [v for v in visits if sum(1 for o in obs if o.visit_id == v.id and o.valid and o.iteration >= 0) >= 2]
    assert second and all(o.sun_elevation_deg > hi for o in obs if o.valid)


@pytest.mark.parametrize("check, crew, whole_loop", [(False, False, False), (False, True, True), (True, False, True)])
def test_only_the_planner_s_visits_stop_at_the_band_point(cfg, tmp_path, check, crew, whole_loop):
    """A crew's re-check and a drift check run their whole correction loop in the band too: only the
    planner's visits leave after the band point."""
    from campaign_helpers import inprocess_campaign

    runner, *_rest = inprocess_campaign(cfg, tmp_path, 10, 2, IDS)
    hid = IDS[0]
    runner._choose = lambda target_id, now: (hid, check, crew)
    assert runner._start_visit(cfg.heliostat(hid).target, runner.devices.clock.now_s())
    settings = runner.state.active[hid].ctx.settings
    assert settings.band_deg == (None if whole_loop else tuple(cfg.acceptance.low_band_deg))
    assert runner.state.settings.band_deg == tuple(cfg.acceptance.low_band_deg)
