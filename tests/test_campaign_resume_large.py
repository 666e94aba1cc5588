"""kill -9 on a large field: ``helicalib sim-field --n 2100`` (beyond the 2016 heliostats one Modbus
unit id reaches, so served on units 1 and 2 of ``plant-interface-1-units``), ``helicalib sim-plant``
on loopback and ``helicalib run --arm`` on every heliostat, killed with SIGKILL in the middle of its
work and run again: the campaign of 2100 heliostats is read back, resumed (not started anew) and
nothing it had recorded is lost (rows unchanged, every frame they point to on disk).
"""

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
from conftest import free_port, stop, wait_port
from test_campaign_resume import _rows, _wait_rows

from helicalib.app.simulated import default_start_s
from helicalib.config import load_field_config

N = 2100


def _helicalib(*args: str, log: Path | None = None):
    out = subprocess.DEVNULL if log is None else log.open("w")
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", *args], stdout=out, stderr=subprocess.STDOUT,
                            text=True)
    proc.log = log
    return proc


@pytest.fixture(scope="module")
def large_plant(tmp_path_factory):
    """A sim-field of N heliostats on free loopback ports, and the simulated plant serving it."""
    folder = tmp_path_factory.mktemp("large")
    field = folder / "field.yaml"
    subprocess.run([sys.executable, "-m", "helicalib", "sim-field", "--n", str(N), "--targets", "2",
                    "--site=40.063,94.426,1267", "--out", str(field)], check=True, capture_output=True)
    data = yaml.safe_load(field.read_text())
    assert data["plant"]["register_map"] == "plant-interface-1-units"
    port, cam_port = free_port(), free_port()
    data["plant"]["scs"]["port"] = port
    for cam in data["cameras"]:
        cam["url"] = f"http://127.0.0.1:{cam_port}/{cam['target']}.png"
    data["storage"] = {"database": "sqlite:///campaign.db", "images_dir": "frames"}
    field.write_text(yaml.safe_dump(data, sort_keys=False))
    cfg = load_field_config(field)
    start = default_start_s(cfg) + 8.0 * 3600
    iso = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(start))
    plant = _helicalib("sim-plant", str(field), "--rate", "200", "--start", iso, "--seed", "5")
    try:
        wait_port(port, 60.0)
        wait_port(cam_port, 60.0)
        yield field, folder
    finally:
        stop(plant)


def _kill_9(proc) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)


def test_kill_9_on_a_field_beyond_one_unit_loses_nothing_and_resumes(large_plant):
    field, folder = large_plant
    db = folder / "campaign.db"
    first = _helicalib("run", str(field), "--arm", "--days", "1", log=folder / "run1.log")
    try:
        _wait_rows(db, 4, first, timeout_s=240.0)
    finally:
        _kill_9(first)
    before = _rows(db)
    con = sqlite3.connect(db)
    last_visit = con.execute("SELECT MAX(id) FROM visits").fetchone()[0]
    con.close()
    second = _helicalib("run", str(field), "--arm", "--days", "1", log=folder / "run2.log")
    try:
        _wait_rows(db, len(before) + 3, second, timeout_s=240.0)
    finally:
        _kill_9(second)
    after = _rows(db)
    assert after[: len(before)] == before                     # every row recorded before the kill, unchanged
    con = sqlite3.connect(db)
    campaigns = con.execute("SELECT id FROM campaigns").fetchall()
    members = con.execute("SELECT COUNT(*) FROM heliostats").fetchone()[0]
    running = [r[0] for r in con.execute("SELECT id FROM visits WHERE outcome = 'running'")]
    cols = [d[1] for d in con.execute("PRAGMA table_info(observations)")]
    con.close()
    assert len(campaigns) == 1 and members == N, (campaigns, members)   # resumed, all N read back
    assert all(vid > last_visit for vid in running), running        # the first run's cut visits were closed
    log = (folder / "run2.log").read_text()
    assert "resumed" in log, log[-2000:]
    i_before, i_after = cols.index("before_frame_path"), cols.index("after_frame_paths_json")
    for row in after:
        for rel in [row[i_before], *json.loads(row[i_after] or "[]")]:
            if rel:
                assert (folder / "frames" / rel).is_file(), rel
