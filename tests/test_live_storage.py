"""A database that cannot be written: one line, never a traceback, and a run that stops safely.

Real failures, not mocks (the tests run as root, for whom a chmod changes nothing):

* a **read-only file or folder**: ``chattr +i`` makes it immutable, which stops root too
  (``run``, ``operate``, ``check --arm`` each say so in one line, exit status 1);
* a **full disk**: the database lives on a small tmpfs that is filled while ``run --arm`` works;
  after a few failed writes every beam goes back to tracking and the run exits with status 4 and
  one line (it used to log "database or disk is full" 2255 times in 120 s and never exit).

Both need CAP_LINUX_IMMUTABLE / CAP_SYS_ADMIN; without them the tests are skipped, except under CI
(``CI`` set: CI runs as root, so a missing capability is a broken runner and fails the test).
"""

from __future__ import annotations

import errno
import os
import signal
import sqlite3
import subprocess
import threading
import time
from contextlib import contextmanager

import pytest

from test_live_clock_jump import cfg, field  # noqa: F401 - fixtures: the simulated plant served on loopback
from helicalib.app.session import EXIT_STORAGE
from helicalib.cli import main
from helicalib.store.sqlite import Store


def _skip_unless_ci(why: str) -> None:
    """Skip the test for ``why``; under CI (``CI`` set, root) fail it instead: it must run there."""
    if os.environ.get("CI"):
        pytest.fail(f"{why} (CI is set: these tests must run)")
    pytest.skip(why)


@contextmanager
def _immutable(path):
    """``chattr +i path`` for the block (root cannot write it either); skips the test if not allowed."""
    r = subprocess.run(["chattr", "+i", str(path)], capture_output=True, text=True)
    if r.returncode != 0:
        _skip_unless_ci(f"chattr +i not allowed here: {r.stderr.strip()}")
    try:
        yield
    finally:
        subprocess.run(["chattr", "-i", str(path)], check=True)


def _campaign(db):
    store = Store.open(db, db.parent / "img")
    store.start_campaign(name="live", mode="live", started_s=0.0, settings={"armed": True},
                         heliostats=[("H0001", 0, "T2")])
    store.close()


COMMANDS = [["run", "--arm", "--heliostats", "H0001", "--days", "0.001"],
            ["operate", "--arm", "--heliostats", "H0001", "--days", "0.001"],
            ["check", "--arm", "--heliostats", "H0001", "--hours", "0.01"]]


@pytest.mark.parametrize("what", ["file", "folder"])
@pytest.mark.parametrize("argv", COMMANDS, ids=[c[0] for c in COMMANDS])
def test_a_database_that_cannot_be_written_is_one_line(field, capsys, argv, what):
    path, _start, sim = field
    db = path.parent / "c.db"
    _campaign(db)
    before = db.read_bytes()
    with _immutable(db if what == "file" else db.parent):
        code = main([argv[0], str(path), *argv[1:]])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and err[0].startswith(f"helicalib {argv[0]}: error: ") and "c.db" in err[0], err
    assert "cannot" in err[0], err  # what cannot be written, and what the system said
    assert "Traceback" not in "\n".join(err)
    assert db.read_bytes() == before


@pytest.fixture()
def small_disk(tmp_path):
    """A 64 MB tmpfs at tmp_path/disk (a disk that can really fill up)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(disk)], capture_output=True, text=True)
    if r.returncode != 0:
        _skip_unless_ci(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def _fill(disk) -> None:
    with open(disk / "filler", "wb") as fh:
        try:
            while True:
                fh.write(b"\0" * (1 << 20))
                fh.flush()
        except OSError as err:
            assert err.errno == errno.ENOSPC


def _observations(db) -> int:
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)
        try:
            return con.execute("SELECT COUNT(*) FROM observations").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def test_a_full_disk_stops_the_run_safely_with_one_line_and_status_4(field, small_disk, capsys):
    import yaml

    path, _start, sim = field
    data = yaml.safe_load(path.read_text())
    data["storage"] = {"database": f"sqlite:///{small_disk / 'c.db'}", "images_dir": str(small_disk / "img")}
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    db = small_disk / "c.db"
    state = {}

    def watch():
        end = time.monotonic() + 120.0
        while _observations(db) < 1 and time.monotonic() < end:
            time.sleep(0.2)
        _fill(small_disk)  # the disk fills up mid-campaign
        state["full"] = time.monotonic()
        if not state.get("done"):
            time.sleep(60.0)
        if not state.get("done"):  # a run that never gives up: stop it (the test then fails)
            os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=watch, daemon=True).start()
    code = main(["run", str(path), "--arm", "--heliostats", "H0001,H0021", "--days", "1"])
    state["done"] = True
    took = time.monotonic() - state["full"]
    out = capsys.readouterr()
    full = [ln for ln in (out.out + out.err).splitlines() if "No space left" in ln or "disk is full" in ln]
    assert code == EXIT_STORAGE, (code, out.err[-2000:])
    assert took < 45.0, took
    # one fault line when it began, one line when the run gave up: not one per write
    assert len(full) == 2, "\n".join(full)
    last = out.err.strip().splitlines()[-1]
    # the place that failed, on the full disk: the database or a frame's file, whichever write met it first
    assert last.startswith("helicalib run: error: ") and str(small_disk) in last and "went back to tracking" in last
    from helicalib.devices.registers import HeliostatState

    for hid in ("H0001", "H0021"):  # the field is safe: no beam left on a board
        assert sim.state[int(hid[1:]) - 1] in (HeliostatState.TRACKING, HeliostatState.MOVING), hid
    assert f"exit status {EXIT_STORAGE}" in last
    assert "Traceback" not in out.err


def test_a_frames_folder_that_cannot_be_written_stops_the_run_with_status_4(field, capsys):
    """The database takes every record but no frame can be written (the images folder read-only or
    on a full disk): each visit's fault is recorded, yet the run gives up after a few and exits 4
    (a written fault line must not count as a write that succeeded)."""
    path, _start, sim = field
    img = path.parent / "img"
    img.mkdir()
    state = {}

    def watch():  # a run that never gives up: stop it (the test then fails)
        if not state.get("done"):
            time.sleep(90.0)
        if not state.get("done"):
            os.kill(os.getpid(), signal.SIGINT)

    with _immutable(img):
        threading.Thread(target=watch, daemon=True).start()
        code = main(["run", str(path), "--arm", "--heliostats", "H0001,H0021", "--days", "1"])
        state["done"] = True
    out = capsys.readouterr()
    assert code == EXIT_STORAGE, (code, out.err[-2000:])
    last = out.err.strip().splitlines()[-1]
    assert last.startswith("helicalib run: error: ") and "img" in last and "went back to tracking" in last, last
    from helicalib.devices.registers import HeliostatState

    for hid in ("H0001", "H0021"):  # the field is safe: no beam left on a board
        assert sim.state[int(hid[1:]) - 1] in (HeliostatState.TRACKING, HeliostatState.MOVING), hid
    assert "Traceback" not in out.err


def test_a_storage_failure_whose_fault_line_cannot_be_written_counts_once(cfg, tmp_path):
    from campaign_helpers import inprocess_campaign
    from helicalib.errors import StorageError

    runner, _sim, store, _cid, _cams = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0001"])
    full = StorageError(f"database {store.path}: cannot be written (database or disk is full)")

    def refuse(**_kw):
        raise full

    store.record_event = refuse  # the disk is full: the fault line's own write fails too
    lines = []
    runner.journal.listeners.append(lines.append)
    runner.journal.storage_failed(full)
    store.close()
    assert runner.state.faults.storage_errors == 1
    assert [e.kind for e in lines] == ["fault"]  # still said once, to the listeners
