"""``status``'s "not confirmed back to tracking" comes from the events that confirm a return, in the
order they were recorded, not from their plant times (a plant restarted with its clock earlier
stamps the confirming ``back_to_tracking`` events before the ``off_tracking`` ones)."""

from __future__ import annotations

import json

from helicalib.cli import main
from helicalib.store.records import off_tracking
from helicalib.store.sqlite import Store

IDS = [f"H{i:04d}" for i in range(1, 7)]
T_LATE = 1_795_000_000.0  # the plant's clock before its restart ...
T_EARLY = T_LATE - 86400.0  # ... and after it: a day earlier


def _store(tmp_path) -> tuple[Store, int]:
    store = Store.open(tmp_path / "c.db", tmp_path / "img")
    cid = store.start_campaign(name="t", mode="live", started_s=T_EARLY,
                               heliostats=[(h, i, "T1") for i, h in enumerate(IDS)])
    return store, cid


def test_returns_confirmed_after_the_plant_clock_went_back_are_not_listed(tmp_path, capsys):
    store, cid = _store(tmp_path)
    for h in IDS:
        store.record_event(campaign_id=cid, time_s=T_LATE + 60, kind="off_tracking", reason=f"{h}: no answer",
                           heliostat_id=h)
    for h in IDS:  # the plant restarted a day earlier; the next run sends them back and the plant confirms
        store.record_event(campaign_id=cid, time_s=T_EARLY + 120, kind="back_to_tracking", reason=f"{h}: tracks",
                           heliostat_id=h)
    events = store.events(cid)
    store.close()
    assert off_tracking(events) == []
    assert main(["status", str(tmp_path / "c.db"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["off_tracking"] == []
    assert main(["status", str(tmp_path / "c.db")]) == 0
    assert "not confirmed back to tracking" not in capsys.readouterr().out


def test_a_return_that_failed_after_the_confirmation_is_still_listed(tmp_path):
    store, cid = _store(tmp_path)
    store.record_event(campaign_id=cid, time_s=T_LATE, kind="back_to_tracking", reason="tracks", heliostat_id="H0001")
    store.record_event(campaign_id=cid, time_s=T_EARLY, kind="off_tracking", reason="no answer", heliostat_id="H0001")
    store.record_event(campaign_id=cid, time_s=T_EARLY, kind="off_tracking", reason="no answer", heliostat_id="H0002")
    store.record_event(campaign_id=cid, time_s=T_EARLY + 5, kind="back_to_tracking", reason="tracks",
                       heliostat_id="H0002")
    events = store.events(cid)
    store.close()
    assert off_tracking(events) == ["H0001"]
