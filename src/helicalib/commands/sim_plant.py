"""``helicalib sim-plant``: serve a simulated plant (Modbus TCP or OPC UA, and its cameras) on loopback."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_register_map, iso_time, nonnegative_int, port, positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim-plant", help="serve a simulated plant over the plant interface (Modbus TCP or OPC UA + cameras)",
        description="Simulated plant with hidden heliostat errors, weather, soiling and rendering cameras, "
                    "served on 127.0.0.1 at the addresses of the field config (options override them). "
                    "Stops cleanly on Ctrl-C or SIGTERM. See docs/simulator.md.")
    p.add_argument("field", help="field config YAML")
    p.add_argument("--rate", type=positive_float, default=600.0, help="plant seconds per real second (default 600)")
    p.add_argument("--start", default=None, type=iso_time,
                   help="plant start time, ISO 8601 with offset (default: the scenario's start, else now)")
    p.add_argument("--seed", type=nonnegative_int, default=None, help="seed of the hidden errors and weather (default: scenario's)")
    p.add_argument("--protocol", choices=("modbus", "opcua"), default=None,
                   help="serve the SCS over Modbus TCP or OPC UA (default: the field config's plant.protocol)")
    p.add_argument("--port", type=port, default=None,
                   help="the SCS's port: Modbus TCP (default plant.scs.port) or OPC UA (default the port of "
                        "plant.opcua.endpoint, else 4840); 0 = a free port")
    p.add_argument("--camera-port", type=port, default=None,
                   help="HTTP port for every camera (default: the ports of the cameras' URLs; 0 = free port)")
    p.add_argument("--scenario", default=None, help="scenario YAML (weather, soiling, errors, faults)")
    p.add_argument("--zero-errors", action="store_true", help="a perfect field: no hidden errors at all")
    add_register_map(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import signal
    import threading
    import time
    from urllib.parse import urlparse
    from datetime import datetime, timezone

    from helicalib.config import load_field_config
    from helicalib.devices.regmap import register_map_of
    from helicalib.errors import ConfigError
    from helicalib.geometry.sun import parse_time, to_unix_seconds, utc_now
    from helicalib.sim.clock import RateClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import load_scenario
    from helicalib.sim.server import MODBUS, FaultInjector, PlantServer, PortInUseError

    if not args.rate > 0:
        raise ConfigError(f"--rate {args.rate}: must be > 0")
    cfg = load_field_config(args.field)
    cfg.require_cameras()  # a PAINT import describes a plant; it cannot be measured
    protocol = args.protocol or cfg.plant.protocol
    if protocol == "opcua" and args.register_map is not None:
        raise ConfigError(f"--register-map {args.register_map}: an OPC UA plant is served through its node map "
                          "(plant.opcua.node_map), not a register map")
    register_map = register_map_of(cfg, args.register_map) if protocol == "modbus" else None
    scenario = load_scenario(args.scenario)
    if args.seed is not None:
        scenario = scenario.model_copy(update={"seed": args.seed})
    start = args.start or scenario.start
    start_s = float(to_unix_seconds(parse_time(start))) if start else float(to_unix_seconds(utc_now()))
    plant = SimulatedPlant(cfg, scenario, start_s=start_s, rate=args.rate, zero_errors=args.zero_errors)
    clock = RateClock(start_s, args.rate, time.monotonic, time.sleep)
    faults = FaultInjector.from_scenario(scenario.faults, scenario.seed)
    if protocol == "modbus":
        scs = cfg.plant.scs
        port = (scs.port if scs is not None else 5020) if args.port is None else args.port
        weather = cfg.plant.weather_endpoint
        weather_port = weather.port if (args.port is None and weather is not None and scs is not None
                                        and weather.port != scs.port) else None
        server = PlantServer(plant, clock, modbus_port=port, camera_port=args.camera_port, weather_port=weather_port,
                             faults=faults, register_map=register_map)
    else:
        endpoint = cfg.plant.opcua.endpoint if cfg.plant.opcua is not None else None
        port = (urlparse(endpoint).port or 4840 if endpoint else 4840) if args.port is None else args.port
        server = PlantServer(plant, clock, camera_port=args.camera_port, faults=faults, protocol="opcua",
                             opcua_port=port)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        server.start()
    except PortInUseError as exc:
        option = "--port" if exc.kind == MODBUS else "--camera-port"
        raise ConfigError(f"{exc} (another sim-plant or plant server?); choose another with {option}, "
                          f"0 picks a free one") from None
    except ConfigError as exc:
        if "OPC UA port" not in str(exc):
            raise
        raise ConfigError(f"{exc} (another sim-plant or plant server?); choose another with --port, "
                          f"0 picks a free one") from None
    print(f"sim-plant: {plant.n} heliostats, scenario '{scenario.name}', seed {scenario.seed}, rate {args.rate}x, "
          f"plant time starts {datetime.fromtimestamp(start_s, tz=timezone.utc).isoformat()}")
    for p in server.modbus_ports:
        print(f"  Modbus TCP  127.0.0.1:{p}  unit(s) {sorted(server.units)}  register map {register_map.name}")
    if server.opcua is not None:
        print(f"  OPC UA      {server.opcua.endpoint}  node map {server.opcua.map.name}")
    for c in cfg.cameras:
        print(f"  camera {c.id:<6} {server.camera_url(c.id)}")
    print("  Ctrl-C or SIGTERM to stop", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        server.stop()
        print("sim-plant: stopped", flush=True)
    return 0
