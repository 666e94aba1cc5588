"""A crew's path on a plant not built to PLANT_INTERFACE.md, as the README gives it: ``sim-plant``
serves the plant its field config describes (an SCS-B plant through the shipped map, an OPC UA
plant through its node map), ``probe`` checks it and passes, and ``run --arm`` measures on it,
all as separate processes over loopback."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, free_port, wait_port

from helicalib.app.simulated import default_start_s
from helicalib.config import load_field_config


def _field(tmp_path: Path, name: str) -> tuple[Path, int, int]:
    """``field_config/NAME.yaml`` on free ports, its database in ``tmp_path``."""
    data = yaml.safe_load((ROOT / "field_config" / f"{name}.yaml").read_text())
    port, cam_port = free_port(), free_port()
    if data["plant"].get("protocol") == "opcua":
        data["plant"]["opcua"]["endpoint"] = f"opc.tcp://127.0.0.1:{port}/helicalib"
    else:
        data["plant"]["scs"]["port"] = port
    for cam in data["cameras"]:
        cam["url"] = f"http://127.0.0.1:{cam_port}/{cam['target']}.png"
    data["storage"] = {"database": "sqlite:///campaign.db", "images_dir": "frames"}
    field = tmp_path / "field.yaml"
    field.write_text(yaml.safe_dump(data, sort_keys=False))
    return field, port, cam_port


def _helicalib(*args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "helicalib", *args], capture_output=True, text=True,
                          timeout=timeout_s)


def _reasons(db: Path) -> list:
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT reason, COUNT(*) FROM observations GROUP BY reason").fetchall()
    finally:
        con.close()


@pytest.mark.parametrize("name", ["scs_b_demo", "opcua_demo"])
def test_sim_plant_probe_and_run_on_a_plant_of_its_own(tmp_path, name):
    field, port, cam_port = _field(tmp_path, name)
    start = default_start_s(load_field_config(field)) + 9.5 * 3600
    iso = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(start))
    log = (tmp_path / "sim-plant.log").open("w")
    plant = subprocess.Popen([sys.executable, "-m", "helicalib", "sim-plant", str(field), "--rate", "300",
                              "--start", iso, "--seed", "2"], stdout=log, stderr=subprocess.STDOUT, text=True)
    try:
        wait_port(port)
        wait_port(cam_port)
        probe = _helicalib("probe", str(field), "--json")
        assert probe.returncode == 0, probe.stdout[-2000:] + probe.stderr[-2000:]
        checks = json.loads(probe.stdout)["checks"]
        assert checks and all(c["status"] in ("ok", "warning") for c in checks)
        run = _helicalib("run", str(field), "--arm", "--days", "0.04", "--heliostats", "H0001", "--json")
        assert run.returncode == 0, run.stderr[-2000:]
        con = sqlite3.connect(tmp_path / "campaign.db")
        try:
            valid = con.execute("SELECT COUNT(*) FROM observations WHERE valid = 1").fetchone()[0]
        finally:
            con.close()
        assert valid >= 1, _reasons(tmp_path / "campaign.db")
    finally:
        plant.send_signal(signal.SIGTERM)
        try:
            plant.wait(20)
        except subprocess.TimeoutExpired:
            plant.kill()
    printed = (tmp_path / "sim-plant.log").read_text()
    assert ("OPC UA      opc.tcp://127.0.0.1:" if name == "opcua_demo" else "register map scs-b") in printed
