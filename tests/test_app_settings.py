"""A live session's settings are read once from the parsed command line, with each command's defaults."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import pytest

from helicalib.app.session import session_days
from helicalib.app.settings import LiveSettings
from helicalib.app.simulated import SimulationOptions
from helicalib.cli import build_parser
from helicalib.console.server import ConsoleOptions
from helicalib.errors import ConfigError


def _parse(*argv):
    return build_parser().parse_args(list(argv))


def test_run_reads_ids_console_and_defaults():
    args = _parse("run", "f.yaml", "--heliostats", "H0001, H0002,", "--arm", "--console", "8765", "--json")
    s = LiveSettings.from_args(args, "live")
    assert s.command == "run" and s.mode == "live" and s.armed
    assert s.heliostat_ids == ["H0001", "H0002"]
    assert s.console == ConsoleOptions(console="8765", console_public=False, json=True) and s.as_json
    assert (s.operation, s.keep_frames, s.rota_days, s.planner, s.recheck, s.refine) == (None, None, 14.0, "gaps",
                                                                                           False, False)
    assert not s.new_campaign and not s.accept_clock_jump
    assert session_days(s) == 7.0


def test_operate_runs_until_stopped_unless_given_days():
    args = _parse("operate", "f.yaml", "--rule", "rota", "--rota-days", "3")
    args.operation = args.rule  # as `helicalib operate` sets it
    s = LiveSettings.from_args(args, "live")
    assert s.command == "operate" and s.operation == "rota" and s.rota_days == 3.0 and s.keep_frames == 20
    assert session_days(s) == math.inf
    assert session_days(replace(s, days=2.0)) == 2.0
    with pytest.raises(ConfigError, match="--days inf"):
        session_days(replace(s, days=math.inf))


def test_check_is_a_recheck_of_its_hours():
    args = _parse("check", "f.yaml", "--heliostats", "H0007", "--hours", "3")
    args.until, args.days, args.planner, args.recheck = None, args.hours / 24.0, "gaps", True  # as `check` sets them
    s = LiveSettings.from_args(args, "check")
    assert s.command == "check" and s.recheck and s.heliostat_ids == ["H0007"] and not s.armed
    assert session_days(s) == pytest.approx(0.125)


def test_console_options_refuse_public_without_an_address():
    ConsoleOptions(console="127.0.0.1:0").check()
    with pytest.raises(ConfigError, match="--console-public: needs --console"):
        ConsoleOptions(console_public=True).check()
    with pytest.raises(ConfigError, match="needs --console-public"):
        ConsoleOptions(console="0.0.0.0:8765").check()


def test_simulation_options_default_as_the_simulate_command():
    args = _parse("simulate", "f.yaml", "--out", "o")
    defaults = SimulationOptions(days=args.days)
    assert (defaults.seed, defaults.planner, defaults.rate, defaults.fidelity, defaults.rota_days,
            defaults.keep_frames, defaults.spots_per_board, defaults.operation) == \
           (args.seed, args.planner, args.rate, args.fidelity, args.rota_days, args.keep_frames,
            args.spots_per_board, args.operate)
    assert "fidelity" in {f.name for f in fields(SimulationOptions)}


@pytest.mark.parametrize("argv", [("run", "f.yaml"), ("operate", "f.yaml"), ("check", "f.yaml", "--heliostats", "H1")])
def test_register_map_reaches_the_session(argv):
    def settings(*extra):
        args = _parse(*argv, *extra)
        if argv[0] == "check":  # as `helicalib check` sets them
            args.until, args.days, args.planner, args.recheck = None, args.hours / 24.0, "gaps", True
        return LiveSettings.from_args(args, "check" if argv[0] == "check" else "live")

    assert settings().register_map is None
    assert settings("--register-map", "maps/ours.yaml").register_map == "maps/ours.yaml"
