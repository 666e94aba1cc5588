"""``helicalib probe`` against plants not built to PLANT_INTERFACE.md, each simulated on loopback:
an SCS-B plant (its own register map, served by the simulated plant's real Modbus server) probed
with the shipped ``scs-b`` map, and with the wrong map; an OPC UA plant (a real asyncua server).
The cameras are the simulated plant's HTTP cameras.
"""

from __future__ import annotations

import copy
import json
import time

import pytest
import yaml

from helicalib.app.probe import EXIT_MISMATCH
from helicalib.cli import main


def _sim(demo_field_path):
    from helicalib.app.simulated import default_start_s
    from helicalib.config import load_field_config
    from helicalib.sim.clock import RateClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario

    cfg = load_field_config(demo_field_path)
    start = default_start_s(cfg) + 9 * 3600
    return SimulatedPlant(cfg, Scenario(seed=5), start_s=start, rate=200.0), \
        RateClock(start, 200.0, time.monotonic, time.sleep)


@pytest.fixture(scope="module")
def scs_b(demo_field_path):
    """The demo field served as an SCS-B plant; yields the parsed config pointing at it."""
    from helicalib.sim.server import PlantServer

    sim, clock = _sim(demo_field_path)
    data = yaml.safe_load(demo_field_path.read_text())
    with PlantServer(sim, clock, modbus_port=0, camera_port=0, register_map="scs-b") as server:
        data["plant"]["scs"]["port"] = server.modbus_port
        for cam in data["cameras"]:
            cam["url"] = server.camera_url(cam["id"])
        yield data


def _write(tmp_path, data) -> str:
    path = tmp_path / "field.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


def _probe(argv, capsys):
    code = main(["probe", *argv, "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_an_scs_b_plant_probed_with_its_map_passes(scs_b, tmp_path, capsys):
    path = _write(tmp_path, scs_b)
    code, doc = _probe([path, "--register-map", "scs-b"], capsys)
    assert code == 0, [c for c in doc["checks"] if c["status"] != "ok"]
    assert doc["summary"]["heliostats"] == {"read": 40, "ok": 40, "mismatch": 0, "warning": 0}
    # the map in the field config does the same
    data = copy.deepcopy(scs_b)
    data["plant"]["register_map"] = "scs-b"
    code, doc = _probe([_write(tmp_path, data)], capsys)
    assert code == 0 and doc["summary"]["passed"]


def test_an_scs_b_plant_probed_with_the_default_map_fails_the_count_line(scs_b, tmp_path, capsys):
    code, doc = _probe([_write(tmp_path, scs_b)], capsys)
    assert code == EXIT_MISMATCH
    count = next(c for c in doc["checks"] if c["name"] == "heliostat count")
    assert count["status"] == "mismatch" and f"127.0.0.1:{scs_b['plant']['scs']['port']}" in count["found"]
    assert next(c for c in doc["checks"] if c["section"] == "heliostats")["status"] == "skipped"


def test_an_unknown_register_map_is_bad_usage(scs_b, tmp_path, capsys):
    assert main(["probe", _write(tmp_path, scs_b), "--register-map", "scs-z"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "scs-z" in err[0]


def test_an_opc_ua_plant_passes(demo_field_path, tmp_path, capsys):
    from helicalib.sim.opcua_server import OpcUaPlantService
    from helicalib.sim.server import PlantServer

    sim, clock = _sim(demo_field_path)
    data = yaml.safe_load(demo_field_path.read_text())
    with PlantServer(sim, clock, modbus_port=0, camera_port=0) as cameras:
        with OpcUaPlantService(sim, clock, lock=cameras.registers.lock) as svc:
            data["plant"] = {"protocol": "opcua", "clock": "plant",
                             "opcua": {"endpoint": svc.endpoint, "security_policy": "None", "timeout_s": 2.0}}
            for cam in data["cameras"]:
                cam["url"] = cameras.camera_url(cam["id"])
            code, doc = _probe([_write(tmp_path, data), "--arm"], capsys)
            assert svc.calls == []  # no command method called, --arm or not
    assert code == 0, [c for c in doc["checks"] if c["status"] != "ok"]
    assert doc["plant"] == f"OPC UA {svc.endpoint}"
    assert doc["summary"]["heliostats"]["ok"] == 40
