"""The live commands' shared options: one definition, and every value the session reads is set.

``run`` and ``operate`` resume a campaign, so both take ``--accept-clock-jump`` (defined once, the
same help); ``check`` starts its own campaign, so it has no such option, yet its namespace carries
the value the session reads (False), rather than the session guessing with ``getattr``.
"""

from __future__ import annotations

import argparse

import pytest

from helicalib.cli import build_parser


def _subparser(name):
    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return parser, subs.choices[name]


@pytest.mark.parametrize("command", ["run", "operate"])
def test_run_and_operate_take_accept_clock_jump(command):
    parser, _sub = _subparser(command)
    assert parser.parse_args([command, "f.yaml"]).accept_clock_jump is False
    assert parser.parse_args([command, "f.yaml", "--accept-clock-jump"]).accept_clock_jump is True


def test_one_help_text_for_the_option():
    helps = {c: next(a.help for a in _subparser(c)[1]._actions if a.dest == "accept_clock_jump")
             for c in ("run", "operate")}
    assert helps["run"] == helps["operate"]


def test_check_sets_what_the_session_reads_without_offering_the_option(capsys):
    parser, sub = _subparser("check")
    args = parser.parse_args(["check", "f.yaml", "--heliostats", "H0001"])
    assert args.accept_clock_jump is False
    assert not [a for a in sub._actions if "--accept-clock-jump" in a.option_strings]
    with pytest.raises(SystemExit):
        parser.parse_args(["check", "f.yaml", "--heliostats", "H0001", "--accept-clock-jump"])
    capsys.readouterr()
