"""``status`` shows the campaign a process is running (not merely the newest), and always says which
campaign it shows and why; ``--campaign`` with an id the database does not hold is one line."""

from __future__ import annotations

import json

import pytest

from helicalib.cli import main
from helicalib.store.sqlite import Store

T0 = 1_795_000_000.0


def _campaign(store, mode: str, status: str, command: str | None) -> int:
    cid = store.start_campaign(name=f"{mode} demo", mode=mode, started_s=T0, heliostats=[("H0001", 0, "T1")])
    if command is not None:  # what a session records when it opens (or resumes) a campaign
        store.record_event(campaign_id=cid, time_s=T0, kind="campaign", reason=f"campaign {cid}",
                           data={"command": command})
    if status != "running":
        store.finish_campaign(cid, T0 + 60, status)
    return cid


def _status(db, capsys, *extra) -> tuple[dict, str]:
    assert main(["status", str(db), "--json", *extra]) == 0
    js = json.loads(capsys.readouterr().out)
    assert main(["status", str(db), *extra]) == 0
    return js, capsys.readouterr().out


def test_a_running_run_is_shown_after_a_newer_check(tmp_path, capsys):
    db = tmp_path / "c.db"
    store = Store.open(db, tmp_path / "img")
    run_id = _campaign(store, "live", "running", "run")  # run --arm, resumed and running now
    _campaign(store, "check", "finished", "check")  # a check --arm that ended while it ran
    _campaign(store, "check", "running", "check")  # a check killed with kill -9: marked running, nobody runs it
    store.close()
    owner = Store.open(db, tmp_path / "img", owner=f"run {tmp_path / 'field.yaml'}")  # the run holds the database
    try:
        # the run re-opens its campaign after the others: its campaign event is the newest
        owner.record_event(campaign_id=run_id, time_s=T0 + 90, kind="campaign", reason="resumed",
                           data={"command": "run"})
        js, text = _status(db, capsys)
    finally:
        owner.close()
    assert js["campaign"] == run_id and js["mode"] == "live" and js["status"].startswith("running (pid")
    assert "the process holding the database runs" in js["shown_because"] and "field.yaml" in js["shown_because"]
    assert text.splitlines()[0].startswith(f"campaign {run_id}: the campaign the process holding the database runs")


def test_without_a_process_the_newest_running_then_the_newest_is_shown(tmp_path, capsys):
    db = tmp_path / "c.db"
    store = Store.open(db, tmp_path / "img")
    killed = _campaign(store, "live", "running", "run")
    _campaign(store, "check", "finished", "check")
    store.close()
    js, text = _status(db, capsys)
    assert js["campaign"] == killed and js["shown_because"] == "the newest campaign marked running"
    assert js["status"].startswith("interrupted")
    assert f"campaign {killed}: the newest campaign marked running" in text
    store = Store.open(db, tmp_path / "img")
    store.finish_campaign(killed, T0 + 10, "stopped")
    store.close()
    js, text = _status(db, capsys)
    assert js["campaign"] == 2 and js["shown_because"] == "the newest campaign (none is running)"
    js, text = _status(db, capsys, "--campaign", "1")
    assert js["campaign"] == 1 and js["shown_because"] == "asked for with --campaign"
    assert "campaign 1: asked for with --campaign" in text


@pytest.mark.parametrize("asked", ["12345678901234567890123", "3", "0", "-1"])
def test_a_campaign_the_database_does_not_hold_is_one_line(tmp_path, capsys, asked):
    db = tmp_path / "c.db"
    store = Store.open(db, tmp_path / "img")
    _campaign(store, "live", "finished", "run")
    _campaign(store, "check", "finished", "check")
    store.close()
    assert main(["status", str(db), "--campaign", asked]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and f"--campaign {asked}" in err[0] and "no such campaign" in err[0]
    assert "campaign ids: 1, 2" in err[0] and "Traceback" not in captured.err
