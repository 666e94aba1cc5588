"""A campaign runner on the in-process simulated plant (virtual clock, real frames, real store)."""

from __future__ import annotations

from helicalib.campaign.loop import CampaignRunner
from helicalib.app.simulated import default_start_s
from helicalib.sim.camera import SimCamera, simulated_flux
from helicalib.sim.clock import VirtualClock
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.store.sqlite import Store


def inprocess_campaign(cfg, tmp_path, hours: float, seed: int, ids, camera=lambda cam, sim, target: cam,
                       scenario=None, plant=lambda sim: sim, campaign_id=None, **runner_kw):
    """A runner on the in-process plant from ``hours`` after local midnight, each board's camera
    wrapped by ``camera(sim_camera, sim, target)`` and the plant by ``plant(sim)``; a new campaign of
    ``ids`` in ``tmp_path/c.db``, or ``campaign_id`` resumed; returns (runner, sim, store, campaign id,
    cameras)."""
    start = default_start_s(cfg) + hours * 3600
    sim = SimulatedPlant(cfg, parse_scenario({"seed": seed, **(scenario or {})}), start_s=start)
    clock = VirtualClock(start)
    clock.on_advance(sim.advance_to)
    cams = {t.id: camera(SimCamera(sim, cfg.cameras_for(t.id)[0].id), sim, t) for t in cfg.targets}
    store = Store.open(tmp_path / "c.db", tmp_path / "img")
    cid = campaign_id if campaign_id is not None else store.start_campaign(
        name="t", mode="simulate", started_s=start,
        heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in ids])
    runner_kw.setdefault("flux", simulated_flux(cfg, sim.scenario))  # the simulated cameras' Fe, as simulate gives it
    return CampaignRunner(cfg, plant(sim), cams, clock, store, cid, heliostat_ids=ids, **runner_kw), sim, store, cid, cams
