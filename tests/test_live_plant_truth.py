"""What the crew's view says is true while the plant does not answer, and no visit starts then.

In-process plant on a virtual clock (real frames, real SQLite file) whose every call fails during a
blackout: ONE ``plant_lost`` and ONE ``plant_back`` (with how long) per loss, no visit started
during it, and the snapshot says "plant unreachable since ..." with the weather's time instead of
"calibration allowed".
"""

from __future__ import annotations

import pytest

from campaign_helpers import inprocess_campaign
from test_devices_camera_deadline import Raw, trickle_body
from test_live_faults import _Outage, served  # noqa: F401 - a fixture
from helicalib.config import load_field_config


@pytest.fixture(scope="module")
def cfg(demo_field_path):
    return load_field_config(demo_field_path)


class _Blackout(_Outage):
    """The in-process plant failing every call in [t0, t1), without its array calls (a plant over the
    wire has none: the runner then reads and writes heliostat by heliostat, as live)."""

    def __getattr__(self, name):
        if name.endswith("_many"):
            raise AttributeError(name)
        return super().__getattr__(name)


def test_a_lost_plant_is_one_line_each_way_and_no_visit_starts_meanwhile(cfg, tmp_path):
    proxy = {}
    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp_path, 9, 3, ["H0001", "H0021"],
                                                    plant=lambda s: proxy.setdefault("p", _Blackout(s)))
    runner.run_until(sim.t_s + 1800.0)  # a calibrating field, both boards busy
    assert runner.snapshot(sim.t_s).gate_open is True
    assert runner.state.weather_time_s is not None and sim.t_s - runner.state.weather_time_s <= 60.0
    blackout = proxy["p"]
    blackout.t0, blackout.t1 = sim.t_s, sim.t_s + 1200.0  # 20 plant minutes without an answer
    runner.run_until(sim.t_s + 600.0)
    snap = runner.snapshot(sim.t_s)
    assert snap.plant_unreachable_since_s == pytest.approx(blackout.t0, abs=61.0)
    assert snap.gate_open is False and "plant unreachable since" in snap.gate_reason
    assert snap.weather_time_s is not None and snap.weather_time_s <= blackout.t0
    assert snap.to_json()["plant_unreachable_since_s"] is not None
    runner.run_until(blackout.t1 + 900.0)
    snap = runner.snapshot(sim.t_s)
    events = store.events(campaign_id=cid)
    visits = store.visits(campaign_id=cid)
    store.close()
    lost = [e for e in events if e.kind == "plant_lost"]
    back = [e for e in events if e.kind == "plant_back"]
    assert len(lost) == 1 and len(back) == 1, [(e.kind, e.reason) for e in events]
    assert back[0].data["lost_s"] == pytest.approx(1200.0, abs=121.0) and "min unreachable" in back[0].reason
    # no fault line per poll while it was lost
    faults = [e for e in events if e.kind == "fault" and blackout.t0 <= e.time_s < blackout.t1]
    assert len(faults) <= 1, [f.reason for f in faults]
    # no visit started during the blackout (they used to start and fail at once); they start again after
    during = [v for v in visits if blackout.t0 + 1.0 <= v.started_s < blackout.t1]
    assert during == [], [(v.started_s - blackout.t0, v.outcome) for v in during]
    assert any(v.started_s >= blackout.t1 for v in visits)
    assert snap.plant_unreachable_since_s is None and snap.gate_open is True


# ---------------------------------------------------------------------------------------------------------
# a camera that trickles its answer, under the live jobs against the simulated plant served on loopback

def test_a_stalled_camera_does_not_stop_weather_reads_nor_the_stow(cfg, tmp_path, served):
    import threading
    import time

    from helicalib.app import live
    from helicalib.campaign.loop import CampaignRunner
    from helicalib.devices.camera_http import HttpCamera
    from helicalib.devices.protocols import Weather
    from helicalib.devices.registers import HeliostatState
    from helicalib.store.sqlite import Store

    plant, cameras, clock, sim, _server = served
    trickle = Raw(trickle_body)  # 2 kB every 0.5 s: each read well within a timeout
    deadline = 8.0
    board = cfg.heliostat("H0001").target
    cameras = dict(cameras, **{board: HttpCamera(trickle.url, timeout_s=2.0, retries=0, deadline_s=deadline)})
    store = Store.open(tmp_path / "c.db", tmp_path / "img")
    cid = store.start_campaign(name="t", mode="live", started_s=clock.now_s(),
                               heliostats=[("H0001", cfg.heliostat_index("H0001"), board)])
    runner = CampaignRunner(cfg, plant, cameras, clock, store, cid, heliostat_ids=["H0001"])
    stop, seen = threading.Event(), {}

    def watch():
        try:
            assert trickle.first.wait(60.0)  # the tick now waits on the camera (the visit's before frame)
            time.sleep(0.5)
            seen["weather_before"] = runner.state.weather_time_s
            calm = sim.weather()
            sim.weather = lambda: Weather(25.0, calm.wind_direction_deg, calm.dni_wm2, calm.temperature_c,
                                          calm.pressure_hpa)  # a gust front: the field must stow now
            t_wind = time.monotonic()
            while not runner.state.stowed and time.monotonic() - t_wind < deadline:
                time.sleep(0.05)
            seen["stow_after_s"] = time.monotonic() - t_wind
            seen["stowed"] = runner.state.stowed
            seen["camera_still_stalled"] = trickle.open > 0
            seen["weather_during"] = runner.state.weather_time_s
        finally:
            seen["stop_t"] = time.monotonic()
            stop.set()

    threading.Thread(target=watch, daemon=True).start()
    try:
        result = live.run_live(runner, clock.now_s() + 86400.0, stop_event=stop)
        stopped_in = time.monotonic() - seen["stop_t"]
        events = store.events(campaign_id=cid)
        idx, end = cfg.heliostat_index("H0001"), time.monotonic() + 10.0
        # on its way into the stow: asked over the plant's own interface, which brings the simulated
        # plant up to the plant time of the question (nothing else asks it once the campaign stopped)
        while plant.status(idx).state != HeliostatState.STOWED and time.monotonic() < end:
            time.sleep(0.1)
    finally:
        trickle.close()
        store.close()
    assert result.reason == "stopped"
    # the weather job read on and stowed while the camera still held the frame (before its deadline freed it)
    assert seen["stowed"] and seen["camera_still_stalled"], seen
    assert seen["weather_during"] > seen["weather_before"]
    assert plant.status(idx).state == HeliostatState.STOWED  # no command after the stow moved it
    assert [e.kind for e in events].count("stow") == 1
    # the stop waited at most for the camera's deadline, not for the camera
    assert stopped_in < deadline + 5.0, stopped_in
