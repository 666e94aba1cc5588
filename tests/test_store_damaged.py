"""Damaged database contents: every reader of the store names the database, table, row and column in
one line (``DataError``), and ``status``, ``report``, ``export-paint`` and ``prune-frames`` exit 1 with
that one line on stderr, no traceback.

The databases are real: a small campaign written with the store's API (frames, fits, verdicts,
events, an operator action), then damaged with raw SQLite UPDATEs or by overwriting a table's pages.
"""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from helicalib.cli import main
from helicalib.errors import DataError
from helicalib.store import Store
from test_store_sqlite import _obs

FRAME = np.zeros((24, 32), np.uint8)
HELIOSTATS = ("H0001", "H0002")


@pytest.fixture(scope="module")
def intact(tmp_path_factory, demo_field_path) -> Path:
    """A folder with ``c.db`` and its ``images``: 2 heliostats, 3 visits each, valid and rejected
    observations with frames, fits, verdicts, events and an operator action."""
    folder = tmp_path_factory.mktemp("intact")
    db = folder / "c.db"
    with Store.open(db, owner="test") as s:
        cid = s.start_campaign(name="demo", mode="simulate", started_s=1_750_000_000.0,
                               heliostats=[(h, i, "T1") for i, h in enumerate(HELIOSTATS)],
                               config_path=str(demo_field_path), settings={"seed": 1})
        n = 0
        for v in range(3):
            for h in HELIOSTATS:
                n += 1
                t = 1_750_000_000.0 + 600 * n
                vid = s.begin_visit(cid, h, "T1", t)
                frame = FRAME.copy()
                frame[n % 24] = 255
                s.record_observation(_obs(cid, vid, 0, hid=h, t=t, valid=n % 4 != 0), before_frame=frame,
                                     after_frames=[frame])
                s.end_visit(vid, ended_s=t + 60, outcome="converged", iterations=1, final_error_mrad=0.5)
                s.record_fit(campaign_id=cid, heliostat_id=h, time_s=t + 60, model="geometric-backlash-v2",
                             params={"a": 0.1}, sigma={"a": 0.01}, rms_mrad=0.8, n_points=v + 1)
                s.record_verdict(campaign_id=cid, heliostat_id=h, time_s=t + 60, accepted=False, n_points=v + 1,
                                 rms_mrad=0.8, reasons=["needs more points"], details={"n": v + 1})
                s.record_event(campaign_id=cid, time_s=t + 61, kind="note", reason="visit done", heliostat_id=h,
                               data={"visit": vid})
        s.request_action(campaign_id=cid, kind="pause", who="crew", requested_wall_s=1.0, requested_s=None)
    return db


def _copy(intact: Path, tmp_path: Path) -> Path:
    shutil.copy(intact, tmp_path / "c.db")
    shutil.copytree(intact.parent / "images", tmp_path / "images")
    return tmp_path / "c.db"


def _update(db: Path, sql: str) -> None:
    conn = sqlite3.connect(db)
    with conn:
        conn.execute(sql)
    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    conn.close()
    assert not db.with_name(db.name + "-wal").exists()


def _overwrite_pages(db: Path, table: str) -> None:
    """Garbage over every page of ``table``'s b-tree (the schema on page 1 stays intact)."""
    conn = sqlite3.connect(db)
    page_size = conn.execute("PRAGMA page_size").fetchone()[0]
    pages = [r[0] for r in conn.execute("SELECT pageno FROM dbstat WHERE name = ?", (table,))] if _has_dbstat(conn) \
        else [conn.execute("SELECT rootpage FROM sqlite_master WHERE name = ?", (table,)).fetchone()[0]]
    conn.close()
    assert pages and 1 not in pages
    with open(db, "r+b") as fh:
        for page in pages:
            fh.seek((page - 1) * page_size)
            fh.write(bytes([0xA5]) * page_size)


def _has_dbstat(conn) -> bool:
    try:
        conn.execute("SELECT 1 FROM dbstat LIMIT 1").fetchall()
        return True
    except sqlite3.Error:
        return False


def _last_valid(db: Path, heliostat: str) -> int:
    conn = sqlite3.connect(db)
    row = conn.execute("SELECT MAX(id) FROM observations WHERE valid = 1 AND heliostat_id = ?", (heliostat,)).fetchone()
    conn.close()
    return int(row[0])


# (what, how to damage the copy, what the line says, the commands that read it)
DAMAGE = [
    ("settings_json not JSON", lambda db: _update(db, "UPDATE campaigns SET settings_json = '{\"seed\": 1' WHERE id = 1"),
     r"c\.db: table campaigns, row 1: settings_json is not JSON", {"status", "report", "export-paint"}),
    ("settings_json not an object", lambda db: _update(db, "UPDATE campaigns SET settings_json = '[1, 2]'"),
     r"table campaigns, row 1: settings_json is not a JSON object", {"status", "report", "export-paint"}),
    ("events.data_json not JSON", lambda db: _update(db, "UPDATE events SET data_json = 'visit=3' WHERE id = 3"),
     r"c\.db: table events, row 3: data_json is not JSON", {"report"}),  # status reads the events it shows
    ("after_frame_paths_json not JSON",
     lambda db: _update(db, f"UPDATE observations SET after_frame_paths_json = 'a.png' WHERE id = {_last_valid(db, 'H0001')}"),
     r"table observations, row \d+: after_frame_paths_json is not JSON", {"report", "export-paint", "prune-frames"}),
    ("after_frame_paths_json not strings",
     lambda db: _update(db, "UPDATE observations SET after_frame_paths_json = '[1]' WHERE id = 1"),
     r"table observations, row 1: after_frame_paths_json is not a JSON list of strings",
     {"report", "export-paint", "prune-frames"}),
    ("text in observations.error_mrad",
     lambda db: _update(db, f"UPDATE observations SET error_mrad = 'big' WHERE id = {_last_valid(db, 'H0002')}"),
     r"table observations, row \d+: error_mrad is not a number \(str 'big'\)", {"status", "report", "export-paint"}),
    ("text in observations.capture_time_s",
     lambda db: _update(db, "UPDATE observations SET capture_time_s = 'noon' WHERE id = 2"),
     r"table observations, row 2: capture_time_s is not a number", {"report", "export-paint"}),
    ("text in events.time_s", lambda db: _update(db, "UPDATE events SET time_s = 'noon' WHERE id = 4"),
     r"table events, row 4: time_s is not a number", {"report"}),
    ("text in visits.started_s", lambda db: _update(db, "UPDATE visits SET started_s = 'x' WHERE id = 5"),
     r"table visits, row 5: started_s is not a number", {"report"}),
    ("text in verdicts.rms_mrad", lambda db: _update(db, "UPDATE verdicts SET rms_mrad = 'low' WHERE id = 6"),
     r"table verdicts, row 6: rms_mrad is not a number", {"status", "report"}),
    ("verdicts.reasons_json not a list", lambda db: _update(db, "UPDATE verdicts SET reasons_json = '{}' WHERE id = 5"),
     r"table verdicts, row 5: reasons_json is not a JSON list", {"status", "report"}),
    ("fits.params_json not numbers", lambda db: _update(db, "UPDATE fits SET params_json = '{\"a\": \"x\"}' WHERE id = 6"),
     r"table fits, row 6: params_json is not a JSON object of numbers", {"report"}),
    ("text in heliostats.block_index", lambda db: _update(db, "UPDATE heliostats SET block_index = 'one' WHERE rowid = 2"),
     r"table heliostats, row 2: block_index is not an integer", {"report"}),
    ("damaged observation pages", lambda db: _overwrite_pages(db, "observations"),
     r"c\.db: table observations: database disk image is malformed .*sqlite3 .*c\.db 'PRAGMA integrity_check'",
     {"status", "report", "export-paint", "prune-frames"}),
    ("damaged event pages", lambda db: _overwrite_pages(db, "events"),
     r"c\.db: table events: database disk image is malformed .*'PRAGMA integrity_check'", {"status", "report"}),
]

COMMANDS = {
    "status": lambda db, out: ["status", str(db), "--json"],
    "report": lambda db, out: ["report", str(db), "--out", str(out)],
    "export-paint": lambda db, out: ["export-paint", str(db), "--out", str(out), "--no-frames"],
    "prune-frames": lambda db, out: ["prune-frames", str(db), "--keep-last", "0", "--drop-rejected"],
}


def test_the_intact_database_reads_in_the_commands_that_fail_on_damage(intact, tmp_path, capsys):
    """The copy before damage: status, export-paint and prune-frames succeed (report's figures take
    seconds; its reader is the store's, exercised below)."""
    db = _copy(intact, tmp_path)
    for name in ("status", "export-paint", "prune-frames"):
        assert main(COMMANDS[name](db, tmp_path / f"out-{name}")) == 0, name
    capsys.readouterr()
    with Store.open(db, readonly=True) as s:
        assert len(s.observations()) == 6 and len(s.events()) == 6 and len(s.actions(1)) == 1


@pytest.mark.parametrize("what, damage, line, readers", DAMAGE, ids=[d[0] for d in DAMAGE])
def test_damaged_database_is_one_line_in_every_command(intact, tmp_path, capsys, what, damage, line, readers):
    import re

    db = _copy(intact, tmp_path)
    damage(db)
    for name, argv in COMMANDS.items():
        out = tmp_path / f"out-{name}"
        status = main(argv(db, out))  # a traceback would raise here
        err = capsys.readouterr().err.strip().splitlines()
        if name in readers:
            assert status == 1, (name, err)
            assert len(err) == 1 and re.search(line, err[0]), (name, err)
            assert err[0].startswith(f"helicalib {name}: error: "), err
        else:  # a command that does not read the damaged part works as before
            assert status == 0, (name, err)


def test_every_reader_of_the_store_names_the_row(intact, tmp_path):
    """The store's API, not only the commands: each reader raises DataError naming the row."""
    db = _copy(intact, tmp_path)
    _update(db, "UPDATE operator_actions SET heliostats_json = 'H0001' WHERE id = 1")
    _update(db, "UPDATE fits SET sigma_json = '[' WHERE id = 6")
    _update(db, "UPDATE verdicts SET details_json = '3' WHERE id = 3")
    _update(db, "UPDATE observations SET valid = 'yes' WHERE id = 6")
    with Store.open(db, readonly=True) as s:
        with pytest.raises(DataError, match=r"c\.db: table operator_actions, row 1: heliostats_json is not JSON"):
            s.actions(1)
        with pytest.raises(DataError, match=r"table fits, row 6: sigma_json is not JSON"):
            s.fits(1)
        with pytest.raises(DataError, match=r"table fits, row 6: sigma_json"):
            s.latest_fit("H0002", 1)
        with pytest.raises(DataError, match=r"table verdicts, row 3: details_json is not a JSON object \(3\)"):
            s.verdicts(1)
        with pytest.raises(DataError, match=r"table observations, row 6: valid is not an integer \(str 'yes'\)"):
            s.observations()
        with pytest.raises(DataError, match=r"table observations, row 6: valid"):
            s.observations_frame()
        with pytest.raises(DataError, match=r"table observations, row 6: valid"):
            s.latest_by_target(1)


def test_damaged_pages_when_opening_name_the_check(intact, tmp_path):
    """Pages of the schema itself damaged: the open fails in one line that says how to check the file."""
    db = _copy(intact, tmp_path)
    with open(db, "r+b") as fh:
        fh.seek(100)  # page 1 after the file header: the schema's b-tree page
        fh.write(bytes([0xA5]) * 200)
    for readonly in (True, False):
        with pytest.raises(DataError, match=r"c\.db: database disk image is malformed .*PRAGMA integrity_check") as err:
            Store.open(db, readonly=readonly)
        assert "\n" not in str(err.value)


def test_schema_version_that_is_not_a_number_is_named(intact, tmp_path):
    db = _copy(intact, tmp_path)
    _update(db, "UPDATE schema_version SET version = 'three'")
    for readonly in (True, False):
        with pytest.raises(DataError, match=r"c\.db: table schema_version, row 1: version is not an integer"):
            Store.open(db, readonly=readonly)
