"""Writes that fail: a full database, a read-only database file or folder, a frames folder that cannot
be written. Each gives one ``StorageError`` line naming the file and what SQLite or the system said,
never a raw ``sqlite3.OperationalError`` / ``PermissionError``.

The tests run as root in CI, where ``chmod`` stops nothing, so the failures are made for real in
ways root cannot bypass: SQLite's ``PRAGMA max_page_count`` (the database is full exactly as on a
full disk: "database or disk is full"), ``PRAGMA query_only`` (SQLite refuses every write:
"attempt to write a readonly database"), a path whose parent is a file, and ``chattr +i`` (an
immutable file or folder, which root cannot write either; ``chmod`` when not root).
"""

from __future__ import annotations

import os
import shutil
import sqlite3
import subprocess
from pathlib import Path

import numpy as np
import pytest

from helicalib.cli import main
from helicalib.errors import StorageError
from helicalib.store import Store
from test_store_sqlite import _obs

FRAME = np.zeros((24, 32), np.uint8)


def _cannot(why: str) -> None:
    """Skip on a developer's machine that cannot freeze a file; fail in CI, whose machine can (its
    tests must not pass by skipping)."""
    if os.environ.get("CI"):
        pytest.fail(f"CI cannot run this test: {why}")
    pytest.skip(why)


@pytest.fixture
def freeze():
    """``freeze(path)`` makes a file or folder unwritable for this process, undone at teardown."""
    frozen: list[Path] = []

    def _freeze(path: Path) -> None:
        if os.geteuid() == 0:
            if shutil.which("chattr") is None:
                _cannot("root without chattr: no way to make a file read-only here")
            done = subprocess.run(["chattr", "+i", str(path)], capture_output=True, text=True)
            if done.returncode != 0:
                _cannot(f"chattr +i not supported on this file system: {done.stderr.strip()}")
        else:
            path.chmod(0o555 if path.is_dir() else 0o444)
        frozen.append(path)

    yield _freeze
    for path in reversed(frozen):
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(path)], check=True)
        else:
            path.chmod(0o755 if path.is_dir() else 0o644)


def _campaign(store: Store) -> int:
    return store.start_campaign(name="w", mode="simulate", started_s=0.0, heliostats=[("H0001", 0, "T1")])


def _one_line(err: pytest.ExceptionInfo) -> str:
    text = str(err.value)
    assert "\n" not in text and isinstance(err.value, StorageError)
    return text


def test_a_full_database_is_one_line_naming_it(tmp_path):
    db = tmp_path / "full.db"
    with Store.open(db, owner="run") as s:
        cid = _campaign(s)
        pages = s._conn.execute("PRAGMA page_count").fetchone()[0]
        s._conn.execute(f"PRAGMA max_page_count = {pages + 2}")  # as full as a full disk
        with pytest.raises(StorageError) as err:
            for i in range(10_000):
                s.record_event(campaign_id=cid, time_s=float(i), kind="note", reason="x" * 200)
        assert _one_line(err) == f"{db}: cannot write the database: database or disk is full"
        with pytest.raises(StorageError, match="database or disk is full"):
            s.start_campaign(name="w2", mode="simulate", started_s=0.0, heliostats=[(f"H{i}", i, "T1")
                                                                                   for i in range(500)])
        assert len(s.events(cid)) > 0  # what was written before stays readable


def test_a_full_database_in_a_batched_store_fails_at_its_commit_and_still_closes(tmp_path):
    db = tmp_path / "batched.db"
    s = Store.open(db, owner="simulate", batched=True, durable=False)
    cid = _campaign(s)
    s.flush()
    pages = s._conn.execute("PRAGMA page_count").fetchone()[0]
    s._conn.execute(f"PRAGMA max_page_count = {pages + 1}")
    with pytest.raises(StorageError, match=r"batched\.db: cannot write the database: database or disk is full"):
        for i in range(10_000):
            s.record_event(campaign_id=cid, time_s=float(i), kind="note", reason="x" * 200)
        s.close()
    s.close()
    assert s.owner() is None  # the ownership went with the close
    with Store.open(db, owner="again"):
        pass


def test_a_database_sqlite_will_not_write_is_one_line(tmp_path):
    db = tmp_path / "ro.db"
    with Store.open(db, owner="run") as s:
        cid = _campaign(s)
        s._conn.execute("PRAGMA query_only = 1")
        vid_err = pytest.raises(StorageError, match=r"ro\.db: cannot write the database: attempt to write a readonly "
                                                    r"database$")
        with vid_err:
            s.begin_visit(cid, "H0001", "T1", 1.0)
        with pytest.raises(StorageError, match="readonly"):
            s.close_interrupted_visits(cid, 2.0)
        with pytest.raises(StorageError, match="readonly"):
            s.set_frame_paths([(1, None, [])])


def test_a_read_only_database_file_is_refused_at_the_open(tmp_path, freeze):
    db = tmp_path / "frozen.db"
    with Store.open(db, owner="run") as s:
        _campaign(s)
    freeze(db)
    with pytest.raises(StorageError) as err:
        Store.open(db, owner="run --arm")
    assert _one_line(err).startswith(f"{db}: cannot write the database: attempt to write a readonly database")
    with Store.open(db, readonly=True) as reader:  # a reader still reads it
        assert len(reader.campaigns()) == 1


def test_a_read_only_folder_is_refused_at_the_open(tmp_path, freeze):
    folder = tmp_path / "frozen"
    folder.mkdir()
    freeze(folder)
    with pytest.raises(StorageError) as err:
        Store.open(folder / "new.db", owner="run")
    assert _one_line(err).startswith(f"{folder / 'new.db.lock'}: cannot create the database's owner lock: ")
    with pytest.raises(StorageError) as err:
        Store.open(folder / "new.db")  # no owner: SQLite itself cannot create the file
    assert _one_line(err).startswith(f"{folder / 'new.db'}: cannot write the database: unable to open database file")


def test_a_database_whose_folder_is_a_file_is_one_line(tmp_path):
    blocker = tmp_path / "runs"
    blocker.write_text("not a folder")
    with pytest.raises(StorageError) as err:
        Store.open(blocker / "x.db", owner="run")
    assert _one_line(err).startswith(f"{blocker}: cannot create the database's folder: ")


def test_a_frames_folder_that_cannot_be_written_names_the_frame_and_keeps_the_database(tmp_path):
    blocker = tmp_path / "images"
    blocker.write_text("not a folder")
    with Store.open(tmp_path / "c.db", images_dir=blocker, owner="run") as s:
        cid = _campaign(s)
        vid = s.begin_visit(cid, "H0001", "T1", 1.0)
        with pytest.raises(StorageError) as err:
            s.record_observation(_obs(cid, vid), before_frame=FRAME, after_frames=[FRAME])
        assert _one_line(err).startswith(f"{blocker}/c{cid}/H0001/v{vid}_i0_before.png: cannot write the frame: ")
        assert s.observations() == []  # no row points to a frame that was not written
        s.record_observation(_obs(cid, vid))  # the database still takes rows
        assert len(s.observations()) == 1


def test_a_frozen_frames_folder_leaves_no_temporary_file(tmp_path, freeze):
    images = tmp_path / "images"
    (images / "c1" / "H0001").mkdir(parents=True)
    with Store.open(tmp_path / "c.db", owner="run") as s:
        cid = _campaign(s)
        freeze(images / "c1" / "H0001")
        with pytest.raises(StorageError, match=r"v1_i0_before\.png: cannot write the frame: (Operation not permitted|"
                                               r"Permission denied)$"):
            s.save_frame(FRAME, campaign_id=cid, heliostat_id="H0001", visit_id=1, iteration=0, capture_time_s=0.0,
                         kind="before")
    assert not list(images.rglob("*.tmp"))


def test_prune_frames_on_a_read_only_database_is_one_line(tmp_path, freeze, capsys):
    db = tmp_path / "p.db"
    with Store.open(db, owner="run") as s:
        _campaign(s)
    sqlite3.connect(db).close()
    freeze(db)
    assert main(["prune-frames", str(db), "--keep-last", "1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "p.db: cannot write the database: attempt to write a readonly database" in err[0], err
