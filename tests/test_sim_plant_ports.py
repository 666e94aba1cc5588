"""``helicalib sim-plant`` on a port that is taken: one line naming the port, no traceback, nothing left listening."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import free_port

from helicalib.config import load_field_config
from helicalib.sim.clock import RateClock
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import Scenario
from helicalib.sim.server import CAMERA_HTTP, MODBUS, PlantServer, PortInUseError

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"


@pytest.fixture()
def taken_port():
    """A port on 127.0.0.1 held by a listening socket for the test's duration."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


def sim_plant(*options: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "helicalib", "sim-plant", str(FIELD), *options],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("which", ["modbus", "camera"])
def test_sim_plant_names_the_port_in_use(taken_port, which):
    options = (["--port", str(taken_port), "--camera-port", "0"] if which == "modbus"
               else ["--port", "0", "--camera-port", str(taken_port)])
    r = sim_plant(*options)
    assert r.returncode == 1
    assert "Traceback" not in r.stderr and r.stdout == ""
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    kind, option = (MODBUS, "--port") if which == "modbus" else (CAMERA_HTTP, "--camera-port")
    assert f"{kind} port {taken_port} on 127.0.0.1 is in use" in lines[0]
    assert f"choose another with {option}" in lines[0]


def test_plant_server_closes_what_it_opened_when_a_later_port_is_taken(taken_port):
    cfg = load_field_config(FIELD)
    plant = SimulatedPlant(cfg, Scenario(), start_s=1.78e9)
    modbus = free_port()
    server = PlantServer(plant, RateClock(1.78e9, 600.0, time.monotonic, time.sleep), modbus_port=modbus,
                         camera_port=taken_port)
    with pytest.raises(PortInUseError) as err:
        server.start()
    assert (err.value.kind, err.value.port) == (CAMERA_HTTP, taken_port)
    # the Modbus listener it had opened is closed again: the port can be listened on at once
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", modbus))
        s.listen()
