"""``check`` when nothing can be measured says exactly why and when it can measure next, and exits 3.

The simulated plant served on loopback at plant night (local midnight), the CLI's ``check --arm``.
"""

from __future__ import annotations

import json

import pytest

from test_live_clock_jump import cfg, served_field  # noqa: F401 - a fixture and its maker
from helicalib.app.session import EXIT_NOT_MEASURED
from helicalib.cli import main


@pytest.fixture()
def night(tmp_path, cfg, demo_data):  # noqa: F811 - cfg is the fixture imported above
    yield from served_field(tmp_path, cfg, demo_data, hours=0.0)


def test_check_at_night_says_why_and_when_and_exits_3(night, capsys):
    from helicalib.campaign.events import iso_utc

    path, start, _sim = night
    code = main(["check", str(path), "--arm", "--heliostats", "H0001", "--hours", "0.05"])
    out = capsys.readouterr().out.strip().splitlines()
    assert code == EXIT_NOT_MEASURED
    row = next(ln for ln in out if ln.startswith("H0001:"))
    assert "not measured: night: the sun is at -" in row and "below the low band's 5°" in row
    assert "it rises past 5° at " + iso_utc(start)[:4] in row and "check again then" in row
    assert "gated, night or not armed" not in row
    assert "0 of 1 heliostat measured" in out[-1] and "1 heliostats" not in out[-1]
    assert f"exit status {EXIT_NOT_MEASURED}" in out[-1]


def test_check_json_gives_the_next_chance(night, capsys):
    path, start, _sim = night
    code = main(["check", str(path), "--arm", "--heliostats", "H0001,H0021", "--hours", "0.05", "--json"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == EXIT_NOT_MEASURED
    rows = summary["rechecks"]
    assert [r["heliostat"] for r in rows] == ["H0001", "H0021"]
    assert all(r["present_error_mrad"] is None and r["next_chance"] > summary_time(start) for r in rows)


def summary_time(start_s: float) -> str:
    from helicalib.campaign.events import iso_utc

    return iso_utc(start_s)


def test_check_without_arm_says_not_armed(night, capsys):
    path, _start, _sim = night
    code = main(["check", str(path), "--heliostats", "H0001", "--hours", "0.05"])
    row = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("H0001:"))
    assert code == EXIT_NOT_MEASURED and "not measured: not armed" in row and "--arm" in row


def _check_with(path, after_s: float, action):
    """``check --arm --hours 2`` of H0001 with ``action()`` done ``after_s`` real seconds in;
    returns (exit status, real seconds it took)."""
    import threading
    import time

    timer = threading.Timer(after_s, action)
    timer.start()
    t0 = time.monotonic()
    try:
        return main(["check", str(path), "--arm", "--heliostats", "H0001", "--hours", "2"]), time.monotonic() - t0
    finally:
        timer.cancel()


def test_a_check_stopped_by_ctrl_c_exits_0(night, capsys):
    """A clean stop is status 0 (docs/running.md), even with nothing measured yet."""
    import os
    import signal

    path, _start, _sim = night
    code, took = _check_with(path, 3.0, lambda: os.kill(os.getpid(), signal.SIGINT))
    out = capsys.readouterr().out.strip().splitlines()
    assert took < 30.0
    assert code == 0, out[-3:]
    assert "Ctrl-C or SIGTERM" in out[-1] and "exit status" not in out[-1], out[-1]


def test_a_clock_jump_during_a_check_does_not_suggest_an_option_check_lacks(night, capsys, monkeypatch):
    import threading

    from helicalib.app.session import EXIT_CLOCK_JUMP
    from helicalib.devices.clock import ClockJumpError, PlantClock

    path, _start, _sim = night
    sync, jumped = PlantClock.sync, threading.Event()

    def sync_then_jump(self):
        t = sync(self)
        if jumped.is_set():  # the plant restarted at an earlier date
            raise ClockJumpError("plant time went backwards: the plant reads a day earlier", t, t - 86400.0)
        return t

    init = PlantClock.__init__

    def resync_often(self, plant, **kw):  # the jump is seen within a fifth of a real second
        init(self, plant, **{**kw, "resync_s": 0.2})

    monkeypatch.setattr(PlantClock, "sync", sync_then_jump)
    monkeypatch.setattr(PlantClock, "__init__", resync_often)
    code, took = _check_with(path, 2.0, jumped.set)
    err = capsys.readouterr().err.strip().splitlines()
    assert took < 20.0  # seen at once, not at the end of the check
    assert code == EXIT_CLOCK_JUMP, err[-3:]
    assert "went backwards" in err[-1] and "--accept-clock-jump" not in err[-1], err[-1]
