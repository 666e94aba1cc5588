"""Ids, names, reasons and owner lines stored by a campaign are printed by ``status`` as text: rich
markup in them neither crashes it (MarkupError) nor becomes a style or a clickable link (databases
written before ids were restricted hold such ids)."""

from __future__ import annotations

import json

import pytest

from helicalib.cli import main
from helicalib.store.sqlite import Store

T0 = 1_795_000_000.0
LINK = "[link=http://evil.example]H3[/link]"
HOSTILE = ["[/]", LINK, "[bold red]H4", "H5[/bold]"]
SITE = "[link=http://evil.example]Plant[/link] [/]"


@pytest.fixture()
def hostile_db(tmp_path):
    db = tmp_path / "c.db"
    store = Store.open(db, tmp_path / "img")
    cid = store.start_campaign(name=f"live {SITE}", mode="live", started_s=T0,
                               heliostats=[(h, i, "[/]T1") for i, h in enumerate(HOSTILE)])
    store.record_verdict(campaign_id=cid, heliostat_id=LINK, time_s=T0, accepted=False, n_points=2, rms_mrad=None,
                         reasons=[f"too few points [link=http://evil.example]x[/link] {LINK}"])
    store.record_event(campaign_id=cid, time_s=T0, kind="off_tracking", reason="[/] gone", heliostat_id=LINK)
    store.record_event(campaign_id=cid, time_s=T0, kind="stow", reason=f"wind [/] {LINK}")
    store.close()
    return db


def test_status_prints_hostile_ids_and_names_as_text(hostile_db, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("FORCE_COLOR", "1")  # as on a crew's terminal: links would be OSC 8 escapes
    monkeypatch.setenv("COLUMNS", "400")
    owner = Store.open(hostile_db, tmp_path / "img", owner=f"run /srv/[link=http://evil.example]f[/link].yaml")
    try:
        assert main(["status", str(hostile_db)]) == 0
        out = capsys.readouterr().out
        assert main(["status", str(hostile_db), "--json"]) == 0
        js = json.loads(capsys.readouterr().out)
    finally:
        owner.close()
    assert "\x1b]8;" not in out  # no hyperlink escape anywhere
    for text in [*HOSTILE, SITE, "[/]T1", f"too few points [link=http://evil.example]x[/link] {LINK}",
                 f"wind [/] {LINK}", "/srv/[link=http://evil.example]f[/link].yaml"]:
        assert text in out, text
    assert "not confirmed back to tracking" in out and js["off_tracking"] == [LINK]
    assert [r["heliostat_id"] for r in js["heliostats"]] == HOSTILE
