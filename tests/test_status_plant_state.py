"""``status`` says when the plant stopped answering (the newest ``plant_lost`` / ``plant_back`` event
in the order recorded) before anything else, and gives the gate and the weather it shows with their
plant times: a plant that stopped answering no longer reads as "calibration allowed"."""

from __future__ import annotations

import json

import pytest

from helicalib.cli import main
from helicalib.store.records import Observation
from helicalib.store.sqlite import Store

T0 = 1_795_010_000.0  # 2026-11-18 13:53:20 UTC


@pytest.fixture(autouse=True)
def _wide(monkeypatch):  # one line each, as on a wide terminal
    monkeypatch.setenv("COLUMNS", "300")


def _campaign(tmp_path):
    store = Store.open(tmp_path / "c.db", tmp_path / "img")
    cid = store.start_campaign(name="live demo", mode="live", started_s=T0, heliostats=[("H0001", 0, "T1")])
    store.record_event(campaign_id=cid, time_s=T0, kind="ungated",
                       reason="calibration allowed: wind 2.9 m/s (good), DNI 926 W/m² (good)")
    store.record_observation(Observation(
        campaign_id=cid, heliostat_id="H0001", target_id="T1", visit_id=None, iteration=0, capture_time_s=T0 + 60,
        strokes_cmd_mm=(100.0, 200.0), strokes_read_mm=None, sun_enu=(0.0, 0.6, 0.8), sun_azimuth_deg=180.0,
        sun_elevation_deg=53.0, valid=True, wind_ms=3.2, dni_wm2=810.0, error_mrad=1.2))
    store.record_event(campaign_id=cid, time_s=T0 + 300, kind="plant_lost", reason="the plant stopped answering")
    store.record_event(campaign_id=cid, time_s=T0 + 900, kind="fault", reason="tick: no answer",
                       data={"clock": "controller"})
    return store, cid


def _status(tmp_path, capsys):
    assert main(["status", str(tmp_path / "c.db")]) == 0
    text = capsys.readouterr().out
    assert main(["status", str(tmp_path / "c.db"), "--json"]) == 0
    return text, json.loads(capsys.readouterr().out)


def test_a_lost_plant_is_said_first_with_the_age_of_what_is_shown(tmp_path, capsys):
    store, cid = _campaign(tmp_path)
    store.take_ownership("run field.yaml")  # the run still holds the database
    try:
        text, js = _status(tmp_path, capsys)
    finally:
        store.close()
    lines = text.splitlines()
    assert lines[1].startswith("plant unreachable since 2026-11-18 13:58:20 UTC (10.0 min before the newest "
                               "record, 2026-11-18 14:08:20 UTC): the gate and weather below are as of before")
    assert lines[2] == ("gate (last known): open: calibration allowed: wind 2.9 m/s (good), DNI 926 W/m² (good) "
                        "(since 2026-11-18 13:53:20 UTC, 15.0 min before the newest record)")
    assert lines[3] == ("weather of the newest measurement: wind 3.2 m/s, DNI 810 W/m² (as of 2026-11-18 13:54:20 "
                        "UTC, 14.0 min before the newest record)")
    assert js["plant_unreachable_since_s"] == T0 + 300 and js["plant_unreachable_since"] == "2026-11-18 13:58:20 UTC"
    assert js["gate"]["kind"] == "ungated" and js["gate"]["since_s"] == T0
    assert js["weather"]["as_of_s"] == T0 + 60 and js["weather"]["dni_wm2"] == 810.0
    assert js["newest_record_s"] == T0 + 900


def test_a_plant_back_recorded_later_ends_it_even_if_stamped_earlier(tmp_path, capsys):
    store, cid = _campaign(tmp_path)
    # the plant restarted with its clock a day earlier: its plant_back is stamped before the loss
    store.record_event(campaign_id=cid, time_s=T0 - 86400, kind="plant_back", reason="the plant answers again")
    store.close()
    text, js = _status(tmp_path, capsys)
    assert "unreachable" not in text and js["plant_unreachable_since_s"] is None
    assert "gate: open: calibration allowed" in text


def test_a_loss_left_by_a_stopped_process_says_so(tmp_path, capsys):
    store, _cid = _campaign(tmp_path)
    store.close()
    text, _js = _status(tmp_path, capsys)
    assert "so it was when the campaign's process stopped" in text.splitlines()[1]
