"""A live campaign killed with SIGKILL resumes on the same database and loses nothing recorded.

Real processes: ``helicalib sim-plant`` serves the simulated plant on loopback (Modbus TCP + HTTP),
``helicalib run --arm`` calibrates against it and is killed -9 in the middle of its work, then run
again. Also: without ``--arm`` nothing is written to the plant, and ``helicalib check`` re-checks.
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
from conftest import free_port, wait_port

from helicalib.app.simulated import default_start_s
from helicalib.config import load_field_config

IDS = "H0001,H0040"


def _rows(db: Path) -> list[tuple]:
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return con.execute("SELECT * FROM observations ORDER BY id").fetchall()
    except sqlite3.OperationalError:
        return []
    finally:
        con.close()


def _wait_rows(db: Path, n: int, proc, timeout_s: float = 120.0) -> list[tuple]:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        rows = _rows(db)
        if len(rows) >= n:
            return rows
        assert proc.poll() is None, proc.log.read_text()
        time.sleep(0.2)
    raise AssertionError(f"fewer than {n} observations after {timeout_s} s")


@pytest.fixture()
def plant(tmp_path, demo_field_path):
    """A field config pointing at free loopback ports, and the simulated plant serving it."""
    data = yaml.safe_load(demo_field_path.read_text())
    port, cam_port = free_port(), free_port()
    data["plant"]["scs"]["port"] = port
    for cam in data["cameras"]:
        cam["url"] = f"http://127.0.0.1:{cam_port}/{cam['target']}.png"
    data["storage"] = {"database": "sqlite:///campaign.db", "images_dir": "frames"}
    field = tmp_path / "field.yaml"
    field.write_text(yaml.safe_dump(data, sort_keys=False))
    cfg = load_field_config(field)
    start = default_start_s(cfg) + 6.6 * 3600
    iso = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(start))
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", "sim-plant", str(field), "--rate", "400",
                             "--start", iso, "--seed", "5"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    try:
        wait_port(port)
        wait_port(cam_port)
        yield field, tmp_path
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()


def _background(command: str, field: Path, *extra: str):
    """``helicalib COMMAND FIELD --heliostats IDS ...`` in the background; its output goes to a file
    (a full pipe would block it)."""
    log = field.parent / f"{command}{len(list(field.parent.glob(f'{command}*.log')))}.log"
    out = log.open("w")
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", command, str(field), "--heliostats", IDS, *extra],
                            stdout=out, stderr=subprocess.STDOUT, text=True)
    proc.log = log
    return proc


def _run(field: Path, *extra: str):
    """``helicalib run`` for a plant day in the background."""
    return _background("run", field, "--days", "1", *extra)


def _kill_9_after(proc, db: Path, n: int) -> None:
    """Kill ``proc`` with SIGKILL once the database holds ``n`` observations."""
    try:
        _wait_rows(db, n, proc)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)


def test_kill_9_and_resume_loses_nothing(plant):
    field, tmp = plant
    db = tmp / "campaign.db"
    _kill_9_after(_run(field, "--arm"), db, 4)
    before = _rows(db)  # everything committed up to the kill
    assert before
    con = sqlite3.connect(db)
    last_visit_of_first_run = con.execute("SELECT MAX(id) FROM visits").fetchone()[0]
    con.close()
    second = _run(field, "--arm")
    try:
        after = _wait_rows(db, len(before) + 3, second)
    finally:
        second.send_signal(signal.SIGKILL)
        second.wait(10)
    after = _rows(db)
    # every observation recorded before the kill is still there, unchanged
    assert after[: len(before)] == before
    con = sqlite3.connect(db)
    campaigns = con.execute("SELECT id, status FROM campaigns").fetchall()
    running = [r[0] for r in con.execute("SELECT id FROM visits WHERE outcome = 'running'")]
    cols = [d[1] for d in con.execute("PRAGMA table_info(observations)")]
    con.close()
    assert len(campaigns) == 1, "the second run started a new campaign instead of resuming"
    # visits the first kill cut off were closed as 'interrupted' on resume: only the second
    # process's own visits (one per target at most) can still read 'running'
    assert all(vid > last_visit_of_first_run for vid in running), running
    # every frame an observation points to exists
    i_before, i_after = cols.index("before_frame_path"), cols.index("after_frame_paths_json")
    for row in after:
        for rel in [row[i_before], *json.loads(row[i_after] or "[]")]:
            if rel:
                assert (tmp / "frames" / rel).is_file(), rel


def test_without_arm_nothing_is_written(plant):
    field, tmp = plant
    proc = _run(field)
    try:  # until the dry run has made a decision it would have sent (a slow start under load is fine)
        end = time.monotonic() + 90.0
        while time.monotonic() < end and not _notes(tmp / "campaign.db", "not armed: would send"):
            assert proc.poll() is None, proc.log.read_text()
            time.sleep(0.3)
        assert proc.poll() is None, proc.log.read_text()
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
    assert "not armed" in proc.log.read_text()
    con = sqlite3.connect(tmp / "campaign.db")
    visits = con.execute("SELECT COUNT(*) FROM visits").fetchone()[0]
    notes = [r[0] for r in con.execute("SELECT reason FROM events WHERE kind = 'note'")]
    con.close()
    assert visits == 0
    assert any(n.startswith("not armed: would send") for n in notes), notes
    # stopped, and kept apart as a dry run: never shown as running, never resumed as a calibration
    assert _campaigns(tmp / "campaign.db") == [(1, "dry-run", "stopped")]
    # the plant's side: no heliostat ever processed a command sequence, the field was never commanded
    from helicalib.devices.modbus import ModbusPlant

    cfg = load_field_config(field)
    plant = ModbusPlant.from_config(cfg, armed=False)
    try:
        for hid in IDS.split(","):
            st = plant.status(cfg.heliostat_index(hid))
            assert st.sequence_done == 0 and st.state == 1, (hid, st)
    finally:
        plant.close()


def test_check_reports_the_present_error(plant):
    field, tmp = plant
    r = subprocess.run([sys.executable, "-m", "helicalib", "check", str(field), "--heliostat", "H0001", "--arm",
                        "--json", "--hours", "3"], capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in r.stdout.splitlines()]  # JSON lines: every line parses
    assert lines[0]["event"] == "campaign" and lines[-1]["event"] == "summary"
    assert {"visit", "measurement", "visit_end"} <= {line["event"] for line in lines}
    rows = lines[-1]["rechecks"]
    assert [row["heliostat"] for row in rows] == ["H0001"]
    assert rows[0]["visits"] >= 1
    # this database holds no earlier calibration of H0001, so the check places it with the nominal
    # model, and the simulated plant's hidden errors put it mrads off (a calibrated one would not be)
    assert rows[0]["present_error_mrad"] is not None and rows[0]["present_error_mrad"] > 0.5
    # printed beside the acceptance limit, with the verdict that follows from the two
    assert rows[0]["limit_mrad"] == 1.2
    assert rows[0]["verdict"].startswith("in spec" if rows[0]["present_error_mrad"] <= 1.2 else "out of spec")
    con = sqlite3.connect(tmp / "campaign.db")
    modes = [m for (m,) in con.execute("SELECT mode FROM campaigns")]
    con.close()
    assert modes == ["check"]


def test_a_recheck_of_a_calibrated_heliostat_is_tested_against_its_fit(plant):
    field, tmp = plant
    first = _cli(field, "run", "--arm", "--days", "0.01", "--heliostats", "H0001", "--json")
    assert first.returncode == 0, first.stderr
    r = _cli(field, "check", "--heliostat", "H0001", "--arm", "--json", "--hours", "3", timeout=240)
    assert r.returncode == 0, r.stderr
    row = json.loads(r.stdout.splitlines()[-1])["rechecks"][0]
    assert row["calibrated"] and row["present_error_mrad"] is not None
    d = row["drift"]  # the placement against the band its fit predicts
    assert d is not None and d["fit_points"] >= 1 and d["band_mrad"] > 0 and 0.0 <= d["p_value"] <= 1.0
    assert d["drift"] == (d["p_value"] < 1e-3)
    assert ("suspected drift" in row["verdict"]) == d["drift"]
    # printed as a line a crew reads: the band and the p-value beside the error and the limit
    text = _cli(field, "check", "--heliostat", "H0001", "--arm", "--hours", "3", timeout=240)
    assert text.returncode == 0, text.stderr
    assert "the fit predicts" in text.stdout and "p = " in text.stdout


def _notes(db: Path, prefix: str) -> list[str]:
    """Notes of the database starting with ``prefix`` (read-only; none while it does not exist yet)."""
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return [r[0] for r in con.execute("SELECT reason FROM events WHERE kind = 'note'") if r[0].startswith(prefix)]
    except sqlite3.OperationalError:
        return []
    finally:
        con.close()


def _cli(field: Path, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "helicalib", *args, str(field)], capture_output=True, text=True,
                          timeout=timeout)


def _campaigns(db: Path) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT id, mode, status FROM campaigns ORDER BY id").fetchall()
    finally:
        con.close()


def test_run_resumes_the_fields_campaign_and_says_what_it_holds(plant):
    field, tmp = plant
    db = tmp / "campaign.db"
    first = _cli(field, "run", "--arm", "--days", "0.01", "--heliostats", IDS, "--json")
    assert first.returncode == 0, first.stderr
    lines = [json.loads(line) for line in first.stdout.splitlines()]  # every line is one JSON object
    assert lines[0]["event"] == "campaign" and "campaign 1 (armed, new)" in lines[0]["reason"]
    assert lines[-1]["event"] == "summary" and lines[-1]["status"] == "finished"
    n_obs = lines[-1]["observations"]
    # again after its --days ended: the same campaign, resumed, and the first line says what it holds
    again = _cli(field, "run", "--arm", "--days", "0.005")
    assert again.returncode == 0, again.stderr
    head = again.stderr.splitlines()[0]
    assert head.startswith("campaign 1 (armed, resumed; it was finished): 2 heliostats"), head
    assert f"{n_obs} observations" in head
    assert _campaigns(db) == [(1, "live", "finished")]
    # a new one only when asked
    new = _cli(field, "run", "--arm", "--days", "0.005", "--new-campaign", "--heliostats", "H0002")
    assert new.returncode == 0, new.stderr
    assert new.stderr.startswith("campaign 2 (armed, new): 1 heliostat;")
    assert [c[0] for c in _campaigns(db)] == [1, 2]


def test_a_dry_run_is_never_resumed_by_an_armed_run(plant):
    field, tmp = plant
    dry = _cli(field, "run", "--days", "0.005", "--heliostats", IDS)
    assert dry.returncode == 0, dry.stderr
    assert "dry run: nothing is written to the plant" in dry.stderr.splitlines()[0]
    armed = _cli(field, "run", "--arm", "--days", "0.005", "--heliostats", IDS)
    assert armed.returncode == 0, armed.stderr
    head = armed.stderr.splitlines()[0]
    assert head.startswith("campaign 2 (armed, new)") and "campaign 1 was a dry run" in head, head
    assert _campaigns(tmp / "campaign.db") == [(1, "dry-run", "finished"), (2, "live", "finished")]


def test_a_field_config_that_does_not_match_the_plant_is_refused_at_start(plant):
    field, tmp = plant
    data = yaml.safe_load(field.read_text())
    data["heliostats"] = data["heliostats"][:-1]
    short = tmp / "short.yaml"
    short.write_text(yaml.safe_dump(data, sort_keys=False))
    r = _cli(short, "run", "--arm", "--days", "0.01")
    assert r.returncode == 1
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1 and "40 heliostats" in err and "39" in err and "refusing to start" in err


def test_one_campaign_process_per_database(plant):
    field, tmp = plant
    first = _run(field, "--arm")
    try:
        _wait_rows(tmp / "campaign.db", 1, first)
        second = _cli(field, "run", "--arm", "--days", "0.01")
        status = subprocess.run([sys.executable, "-m", "helicalib", "status", str(tmp / "campaign.db"), "--json"],
                                capture_output=True, text=True, timeout=60)
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(10)
    assert second.returncode == 1 and "in use by helicalib (pid" in second.stderr, second.stderr
    assert json.loads(status.stdout)["status"].startswith("running (pid")
    after = subprocess.run([sys.executable, "-m", "helicalib", "status", str(tmp / "campaign.db"), "--json"],
                           capture_output=True, text=True, timeout=60)
    assert json.loads(after.stdout)["status"].startswith("interrupted")  # killed: not shown as running


def test_run_on_a_terminal_shows_the_campaign_moving(plant):
    """``run --arm`` on a (pseudo-)terminal: the live view, redrawn as the campaign goes."""
    import os
    import pty
    import select

    field, _tmp = plant
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", "run", str(field), "--arm", "--heliostats", IDS,
                             "--days", "1"], stdin=slave, stdout=slave, stderr=slave,
                            env={**os.environ, "COLUMNS": "140", "LINES": "50", "TERM": "xterm"})
    os.close(slave)
    seen = b""
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and b"visit_end" not in seen:
            if select.select([master], [], [], 0.5)[0]:
                try:
                    seen += os.read(master, 65536)
                except OSError:
                    break
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            while select.select([master], [], [], 0.5)[0]:
                seen += os.read(master, 65536)
        except OSError:
            pass
        proc.wait(60)
        os.close(master)
    text = seen.decode("utf-8", "replace")
    assert "\x1b[" in text  # drawn with terminal control sequences, not plain lines
    for part in ("plant time", "ARMED", "accepted", "board", "events", "onto", "visit_end"):
        assert part in text, part
    assert "stopping:" in text and proc.returncode == 0


def _operate(field: Path, *extra: str):
    """``helicalib operate`` in the background (no end: it runs until stopped)."""
    return _background("operate", field, "--keep-frames", "2", *extra)


def test_operate_is_a_service_that_resumes_after_kill_9_and_stops_on_sigterm(plant):
    field, tmp = plant
    db = tmp / "campaign.db"
    _kill_9_after(_operate(field, "--arm"), db, 3)
    before = _rows(db)
    second = _operate(field, "--arm")
    try:
        _wait_rows(db, len(before) + 2, second)
        assert second.poll() is None, "operate ended by itself; it runs until stopped"
    finally:
        second.send_signal(signal.SIGTERM)  # systemd's stop: a clean one
        code = second.wait(60)
    assert code == 0, second.log.read_text()
    after = _rows(db)
    assert after[: len(before)] == before  # nothing recorded before the kill was lost
    # one campaign, resumed by the second process, left 'stopped' (not running) by the clean stop
    assert _campaigns(db) == [(1, "live", "stopped")]
    log = second.log.read_text().splitlines()
    # a service's log: one line per event, the opening line says it resumed, the end says why it stopped
    assert any("campaign 1 (armed, resumed" in line for line in log), log[:5]
    assert any(" visit " in f" {line} " or "onto" in line for line in log)
    assert any("Ctrl-C or SIGTERM" in line for line in log), log[-5:]
