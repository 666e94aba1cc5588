"""A short closed-loop campaign whose plant is the simulated plant served over OPC UA: the
campaign core drives it through :class:`OpcUaPlant` on a real asyncua server on loopback (the
board cameras are the simulated plant's in-process cameras) and reaches the same valid
observations as the same campaign on the in-process plant; then the server stops, and the client
says the plant is unreachable."""

from __future__ import annotations

import pytest

from helicalib.config import load_field_config
from helicalib.devices.guard import CommandGuard
from helicalib.devices.opcua import OpcUaPlant
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.sim.opcua_server import OpcUaPlantService

from campaign_helpers import inprocess_campaign

IDS = ["H0001", "H0007"]


class SimTime:
    """The in-process plant's own time as the server's clock (the campaign's virtual clock moves it)."""

    rate = 1.0

    def __init__(self, sim):
        self.sim = sim

    def now_s(self) -> float:
        return self.sim.t_s


def _observations(store, cid):
    """What a verdict stands on: who, when, which strokes (commanded and read back), valid or why not."""
    return [(o.heliostat_id, o.iteration, o.valid, o.reason, round(o.capture_time_s, 6), o.strokes_cmd_mm,
             o.strokes_read_mm) for o in store.observations(cid)]


def test_a_campaign_runs_against_the_plant_served_over_opcua(demo_field_path, tmp_path):
    cfg = load_field_config(demo_field_path)
    served: dict = {}

    def over_opcua(sim):
        svc = served["svc"] = OpcUaPlantService(sim, SimTime(sim)).start()
        g = CommandGuard.from_config(cfg, armed=True)
        served["client"] = OpcUaPlant(svc.endpoint, svc.map, g.heliostat_ids, len(cfg.heliostats), armed=True,
                                      stroke_limits_mm=g.stroke_limits_mm, timeout_s=3.0)
        return served["client"]

    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path / "opcua", 10, 3, IDS, plant=over_opcua)
    svc, op = served["svc"], served["client"]
    try:
        runner.run_until(sim.t_s + 1800)
        over = _observations(store, cid)
        store.close()
        assert sum(o[2] for o in over) >= 4, over         # both heliostats placed, corrected and placed again
        moves = [name for name, _args in svc.calls if name == "MoveTo"]
        assert len(moves) >= len([o for o in over if o[1] == 0])
        svc.stop()                                         # the plant goes away mid-run
        with pytest.raises(PlantUnreachableError) as err:
            op.status(1)
        msg = str(err.value)
        assert "\n" not in msg and svc.endpoint in msg and "H0002" in msg and "after 2 attempts" in msg
        with pytest.raises(PlantUnreachableError, match="not tried: the plant did not answer moments ago"):
            op.weather()
    finally:
        op.close()
        svc.stop()
    # the same campaign on the in-process plant: the same observations, verdict by verdict
    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path / "direct", 10, 3, IDS)
    runner.run_until(sim.t_s + 1800)
    assert _observations(store, cid) == over
    store.close()
