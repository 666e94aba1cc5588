"""A whole campaign against the simulated plant: in-process on a virtual clock, or over loopback.

:func:`simulate_campaign` builds the simulated plant from a field config and a scenario, connects
the campaign runner to it (directly, or through the real Modbus TCP and HTTP clients when
``over_network``), runs it for the given days and returns the summary figures, judged against
the simulator's truth (:mod:`.sim_figures`). What it runs is one :class:`SimulationOptions`.

This is the composition root of simulated runs: it knows both sides, the simulator
(:mod:`helicalib.sim`) and the campaign (:mod:`helicalib.campaign`). The campaign itself imports
nothing of ``sim``: it cannot tell a simulated plant from a real one (``tests/test_layers.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pandas as pd

from helicalib.app.sim_figures import MONTH_DAYS, MonthlyTracking, operation_summary, summarise
from helicalib.campaign.loop import CampaignRunner
from helicalib.geometry.sun import parse_time
from helicalib.store.sqlite import Store

DEFAULT_START = "2026-06-01T00:00:00+00:00"


@dataclass
class SimulationResult:
    summary: dict
    database: Path
    runner: CampaignRunner


def default_start_s(cfg) -> float:
    """Local midnight (by longitude) of the default start day, in UTC seconds."""
    t = parse_time(DEFAULT_START) - pd.Timedelta(hours=cfg.site.longitude_deg / 15.0)
    return (t - pd.Timestamp(0, tz="UTC")) / pd.Timedelta("1s")


FIDELITIES = ("render", "fast")
"""``render``: every frame drawn and measured by the vision (the camera sensor); ``fast``: the
simulator's true spot plus the fitted measurement-error model, no frames (:mod:`helicalib.sim.fast_sensor`)."""


@dataclass(frozen=True)
class SimulationOptions:
    """What a simulated campaign runs: ``days`` plant days from ``start_s`` (None: :func:`default_start_s`,
    or where the folder's unfinished campaign stopped), ``seed`` of the hidden errors, weather and noise
    (it overrides the scenario's), ``scenario`` (None: the default :class:`~helicalib.sim.scenario.Scenario`).

    ``over_network``: the plant served on loopback at ``rate`` × real time, reached through the real
    Modbus TCP and HTTP clients; ``planner``, ``refine``, ``operation`` (``"ranked"`` or ``"rota"``: the
    campaign then year-round operation), ``rota_days`` and ``spots_per_board`` (1, N or ``"auto"``,
    :mod:`helicalib.campaign.board`): as the live campaign takes them; ``heliostat_ids``: the campaign's
    heliostats (None: all); ``fidelity``: :data:`FIDELITIES`; ``monthly_tracking`` (None: with
    ``operation`` or :data:`~helicalib.app.sim_figures.MONTH_DAYS` days and more): the plant's true
    tracking sampled every plant day, reported per 30 days (``monthly_plant_tracking_rms_mrad``);
    ``keep_frames``: every night delete the frames of all but each heliostat's newest N observations
    and the rejected ones (as ``helicalib operate``; None: keep all); ``boards``: the targets whose
    cameras the campaign may use (None: all; one group of a split simulation keeps its own, so no
    board is lent across groups, :mod:`helicalib.app.split`).

    Over the network, ``protocol`` (``"modbus"`` or ``"opcua"``) is how the SCS is served and
    reached; ``register_map`` the Modbus map both sides speak (None: the field config's
    ``plant.register_map``, else PLANT_INTERFACE.md's); ``lockstep``: the served plant's clock is
    the controller's virtual clock (it moves only when the controller waits), so a run over the
    network is repeatable: the same seed gives the same campaign whatever the protocol or map.
    """

    days: float
    seed: int = 1
    scenario: Any = None
    start_s: float | None = None
    over_network: bool = False
    planner: str = "gaps"
    heliostat_ids: list[str] | None = None
    rate: float = 3000.0
    refine: bool = False
    fidelity: str = "render"
    operation: str | None = None
    rota_days: float = 14.0
    monthly_tracking: bool | None = None
    keep_frames: int | None = None
    spots_per_board: int | str = 1
    protocol: str = "modbus"
    register_map: str | None = None
    lockstep: bool = False
    boards: tuple[str, ...] | None = None


def simulate_campaign(cfg, out_dir: Path, options: SimulationOptions,
                      progress: Callable[[float], None] | None = None) -> SimulationResult:
    """Run a simulated campaign into ``out_dir`` (its database, frames and ``observations.csv``);
    returns its summary (:func:`~helicalib.app.sim_figures.summarise`). ``progress(now_s)`` is called
    as the plant clock advances."""
    from helicalib.errors import ConfigError
    from helicalib.sim.scenario import Scenario

    if options.fidelity not in FIDELITIES:
        raise ConfigError(f"fidelity {options.fidelity!r}: expected one of {', '.join(FIDELITIES)}")
    if (options.protocol != "modbus" or options.register_map is not None or options.lockstep) \
            and not options.over_network:
        raise ConfigError("--protocol, --register-map and --lockstep describe the served plant: add --over-network")
    if options.fidelity == "fast" and options.over_network:
        raise ConfigError("fidelity fast: the fast sensor reads the in-process simulator's truth; it cannot run "
                          "--over-network (a served plant has cameras)")
    scenario = (options.scenario or Scenario()).model_copy(update={"seed": options.seed})
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    db_path = out_dir / "helicalib.db"
    # durable=False: WAL with synchronous=NORMAL, still loses nothing on kill -9 (only on power loss)
    # relative to the database: OUT/images; owned by this process while it runs
    # writes batched (a killed simulation loses at most its last batch; it resumes from what was committed)
    store = Store.open(db_path, "images", durable=False, owner=f"simulate {cfg.source or ''}", batched=True)
    with store:  # closed (its last batch committed) however the run ends
        monthly_tracking = options.monthly_tracking
        if monthly_tracking is None:
            monthly_tracking = options.operation is not None or options.days >= MONTH_DAYS
        return _simulate(store, cfg, out_dir, db_path,
                         replace(options, scenario=scenario, monthly_tracking=monthly_tracking), progress)


def _simulate(store, cfg, out_dir: Path, db_path: Path, o: SimulationOptions, progress) -> SimulationResult:
    """The campaign of ``o`` (its scenario seeded, ``monthly_tracking`` decided) in the open ``store``."""
    from helicalib.sim.camera import simulated_flux
    from helicalib.sim.clock import VirtualClock
    from helicalib.sim.plant import SimulatedPlant

    days, seed, scenario, start_s, fidelity, operation = o.days, o.seed, o.scenario, o.start_s, o.fidelity, o.operation
    resumed = store.unfinished_campaign(mode="simulate")
    if resumed is not None:
        campaign_id = resumed.id
        start_s = resumed.started_s if start_s is None else start_s
    if start_s is None:
        start_s = default_start_s(cfg)
    end_s = start_s + days * 86400.0
    with ExitStack() as stack:
        if o.over_network:
            plant, cameras, clock, sim, _server = _network_plant(
                cfg, scenario, start_s, o.rate, stack, protocol=o.protocol, register_map=o.register_map,
                lockstep=o.lockstep)
        else:
            sim = SimulatedPlant(cfg, scenario, start_s=start_s)
            clock = VirtualClock(start_s)
            clock.on_advance(sim.advance_to)
            from helicalib.sim.camera import SimCamera

            plant = sim
            if fidelity == "fast":
                from helicalib.sim.fast_sensor import fast_sensors

                cameras = fast_sensors(sim, seed=seed)  # spot sensors: the runner uses them as they are
            else:
                cameras = {t.id: SimCamera(sim, cfg.cameras_for(t.id)[0].id) for t in cfg.targets}
        if o.boards is not None:
            cameras = {tid: cam for tid, cam in cameras.items() if tid in set(o.boards)}
        if resumed is None:
            ids = o.heliostat_ids or [h.id for h in cfg.heliostats]
            campaign_id = store.start_campaign(
                name=f"simulate {cfg.site.name}", mode="simulate", started_s=start_s,
                heliostats=[(hid, cfg.heliostat_index(hid), cfg.heliostat(hid).target) for hid in ids],
                config_path=str(cfg.source or ""),
                settings={"days": days, "seed": seed, "planner": o.planner, "refine": o.refine,
                          "over_network": o.over_network, "scenario": scenario.name, "fidelity": fidelity,
                          "operation": operation, "rota_days": o.rota_days if operation == "rota" else None,
                          "spots_per_board": o.spots_per_board,
                          **({"protocol": o.protocol, "register_map": o.register_map, "lockstep": o.lockstep}
                             if o.over_network else {})})
        elif clock.now_s() < store_resume_time(store, campaign_id, start_s):
            clock.sleep(store_resume_time(store, campaign_id, start_s) - clock.now_s())
        runner = CampaignRunner(cfg, plant, cameras, clock, store, campaign_id, heliostat_ids=o.heliostat_ids,
                                planner=o.planner, refine=o.refine, operation=operation, rota_days=o.rota_days,
                                spots_per_board=o.spots_per_board, flux=simulated_flux(cfg, scenario))
        if o.keep_frames is not None:
            runner.state.retention = (int(o.keep_frames), True)
        store.remove_orphan_frames(campaign_id)  # after the runner closed the interrupted visits
        wall0 = time.perf_counter()
        monthly = MonthlyTracking(cfg, sim, runner, start_s) if o.monthly_tracking else None
        if monthly is None:
            runner.run_until(end_s, progress=progress)
        else:  # a plant day at a time, the plant's true tracking sampled after each with the models of the day
            while clock.now_s() < end_s:
                day0 = clock.now_s()
                runner.run_until(min(end_s, day0 + 86400.0), progress=progress)
                monthly.sample(day0, clock.now_s())
        wall = time.perf_counter() - wall0
        store.finish_campaign(campaign_id, clock.now_s())
        summary = summarise(cfg, runner, sim, start_s, end_s)
        if monthly is not None:
            summary["monthly_plant_tracking_rms_mrad"] = monthly.rms_by_month()
            summary["monthly_plant_tracking_undrifted_rms_mrad"] = monthly.rms_by_month(steady_only=True)
        if operation is not None:
            summary.update(operation_summary(cfg, runner, sim, store, campaign_id, start_s, end_s))
        summary["wall_s"] = round(wall, 1)
        summary["fidelity"] = fidelity
        summary["database"] = str(db_path)
        store.export_observations_csv(out_dir / "observations.csv", campaign_id=campaign_id)
    return SimulationResult(summary=summary, database=db_path, runner=runner)


def store_resume_time(store: Store, campaign_id: int, start_s: float) -> float:
    """Plant time to resume at: after the newest thing recorded."""
    visits = store.visits(campaign_id=campaign_id)
    times = [start_s] + [v.started_s for v in visits] + [v.ended_s for v in visits if v.ended_s is not None]
    return max(times)


def _network_plant(cfg, scenario, start_s, rate, stack, *, protocol: str = "modbus", register_map=None,
                   lockstep: bool = False):
    """Serve the simulated plant on loopback (``protocol``, ``register_map``: see
    :class:`SimulationOptions`) and connect the real clients to it; returns (plant client, cameras,
    plant clock, simulated plant, server). With ``lockstep`` the server and the controller share one
    virtual clock; else the plant runs at ``rate`` × real time."""
    from helicalib.devices.clock import PlantClock
    from helicalib.devices.connect import cameras_from_config, plant_from_config
    from helicalib.sim.clock import RateClock, VirtualClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.server import FaultInjector, PlantServer

    sim = SimulatedPlant(cfg, scenario, start_s=start_s, rate=rate)
    served_clock = VirtualClock(start_s) if lockstep else RateClock(start_s, rate, time.monotonic, time.sleep)
    server = PlantServer(sim, served_clock, modbus_port=0, camera_port=0, protocol=protocol,
                         register_map=register_map, opcua_port=0,
                         faults=FaultInjector.from_scenario(scenario.faults, seed=scenario.seed))
    stack.enter_context(server)
    served = server.served_config(cfg)  # the field config with the bound ports (the map is the server's)
    plant = plant_from_config(served, armed=True,
                              register_map=server.registers.map if protocol == "modbus" else None)
    if hasattr(plant, "close"):
        stack.callback(plant.close)
    clock = served_clock if lockstep else PlantClock(plant)
    cameras = cameras_from_config(served, timeout_s=5.0, clock=clock)
    return plant, cameras, clock, sim, server
