"""The command line speaks one language: ``--heliostats`` for a list of heliostats (``check``'s old
``--heliostat`` still works for existing scripts, unadvertised), the campaign database is ``DB`` with
the same help in every command, and every option has a help text."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from helicalib.cli import build_parser

FIELD = str(Path(__file__).resolve().parents[1] / "field_config" / "demo_north.yaml")
DB_COMMANDS = ("report", "export-paint", "prune-frames")


def _subparser(name: str) -> argparse.ArgumentParser:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


@pytest.mark.parametrize("option", ["--heliostats", "--heliostat"])
def test_check_takes_heliostats_and_still_the_old_name(option):
    args = build_parser().parse_args(["check", FIELD, option, "H0007,H0012"])
    assert args.heliostats == "H0007,H0012"


def test_check_advertises_only_heliostats(capsys):
    help_text = _subparser("check").format_help()
    assert "--heliostats" in help_text
    assert not re.search(r"--heliostat\b(?!s)", help_text)


def test_check_without_heliostats_names_the_option(capsys):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["check", FIELD])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == "helicalib check: error: one of the arguments --heliostats is required"


def test_spot_single_board_size_has_help():
    action = next(a for a in _subparser("spot-single")._actions if "--board-size-m" in a.option_strings)
    assert action.help and "W x H metres" in action.help


@pytest.mark.parametrize("command", DB_COMMANDS)
def test_the_database_argument_is_db_with_one_help(command):
    from helicalib.commands._args import DATABASE_HELP

    positional = [a for a in _subparser(command)._actions if not a.option_strings and a.dest != "help"]
    assert [(a.dest, a.metavar, a.help) for a in positional] == [("db", "DB", DATABASE_HELP)]
    assert f"{command} [-h]" in _subparser(command).format_usage() and " DB" in _subparser(command).format_usage()


@pytest.mark.parametrize("command", DB_COMMANDS)
def test_a_campaign_id_beyond_sqlites_integers_is_one_line(command, tmp_path, capsys):
    from helicalib.cli import main

    db = tmp_path / "c.db"
    db.write_bytes(b"")
    argv = [command, str(db), "--campaign", "12345678901234567890123"]
    argv += ["--keep-last", "1"] if command == "prune-frames" else ["--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"helicalib {command}: error: argument --campaign: '12345678901234567890123': expected a "
                       "whole number in [1, 9223372036854775807]")
    assert "Traceback" not in "\n".join(err) and not (tmp_path / "o").exists()
