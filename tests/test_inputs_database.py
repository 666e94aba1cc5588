"""A database given where a field config (or another text file) belongs is named as a database in
one line, not as "not UTF-8 text" (a real helicalib database and a plain SQLite file)."""

from __future__ import annotations

import sqlite3

import pytest

from helicalib.cli import main
from helicalib.store.sqlite import Store


@pytest.fixture()
def campaign_db(tmp_path, demo_field_path):
    db = tmp_path / "helicalib.db"
    store = Store.open(db, tmp_path / "images", owner="test inputs")
    try:
        store.start_campaign(name="t", mode="live", started_s=0.0, heliostats=[("H0001", 0, "T1")],
                             config_path=str(demo_field_path))
    finally:
        store.close()
    return db


def _one_line(capsys, argv) -> str:
    """The command's one error line (``validate`` closes its problem lines with a count line)."""
    assert main(argv) == 1
    err = capsys.readouterr().err
    lines = err.strip().split("\n")
    assert "Traceback" not in err and len(lines) == (2 if argv[0] == "validate" else 1), err
    return lines[0]


@pytest.mark.parametrize("command", [["run"], ["validate"], ["check", "--heliostat", "H0001"]])
def test_a_helicalib_database_given_as_the_field_config_says_so(capsys, campaign_db, demo_field_path, command):
    err = _one_line(capsys, [command[0], str(campaign_db), *command[1:]])
    assert err.endswith(f"{campaign_db}: this is a helicalib database, not a field config; give the field config "
                        f"YAML (its newest campaign ran with {demo_field_path})")
    assert "UTF-8" not in err


def test_another_sqlite_file_is_named_as_a_database(tmp_path, capsys):
    db = tmp_path / "other.sqlite"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE t (x)")
    con.commit()
    con.close()
    err = _one_line(capsys, ["validate", str(db)])
    assert err == f"{db}: this is an SQLite database, not a field config; give the field config YAML"


def test_a_database_given_as_a_text_file_is_named(tmp_path, capsys, campaign_db, demo_field_path):
    err = _one_line(capsys, ["fit", str(campaign_db), "--field", str(demo_field_path), "--heliostat", "H0001"])
    assert err.endswith(f"{campaign_db}: an SQLite database, not a text file")
