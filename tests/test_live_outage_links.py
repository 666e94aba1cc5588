"""A plant whose links fail one at a time: each link is back only when that link answers.

The simulated plant is served on loopback (Modbus TCP); the real client reads the weather over a
link of its own. The SCS link is then pointed at a closed port (connections refused) while the
weather link keeps answering, and the live jobs run in turn as the scheduler would call them.
"""

from __future__ import annotations

import socket
import threading

from test_live_faults import _network_runner, cfg, served  # noqa: F401 - fixtures
from helicalib.app import live
from helicalib.devices.modbus import ModbusLink


def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _separate_weather_link(plant):
    scs = plant.scs
    plant.weather_link = ModbusLink(scs.host, scs.port, scs.unit, scs.timeout_s, retries=0)


def test_an_scs_down_with_the_weather_answering_is_one_lost_line_not_a_flap(cfg, tmp_path, served):
    runner, store, cid = _network_runner(cfg, tmp_path, served, ["H0001"])
    plant, _cams, clock, _sim, _server = served
    _separate_weather_link(plant)
    plant.scs.close()
    plant.scs.port, plant.scs.retries, plant.scs.down_s = _closed_port(), 0, 0.0  # the SCS is down
    lock = threading.Lock()
    for _ in range(4):  # four plant minutes of jobs: the weather poll answers, the clock's resync does not
        runner.state.last_poll_s = -1e18
        clock.resync_s = 1e9  # the weather job on the clock's extrapolation
        live._weather_job(runner, lock)
        clock.resync_s = 0.0  # the tick when the clock's resync is due: over the SCS
        live._tick_job(runner, lock)
    events = store.events(campaign_id=cid)
    store.close()
    kinds = [e.kind for e in events if e.kind in ("plant_lost", "plant_back")]
    assert kinds == ["plant_lost"], [(e.kind, e.reason) for e in events]
    assert runner.state.faults.plant_unreachable_since_s is not None
    assert len([e for e in events if e.kind == "fault"]) <= 2  # the tick's and the weather job's, once each


def test_the_scs_answering_again_ends_the_loss_in_one_line(cfg, tmp_path, served):
    runner, store, cid = _network_runner(cfg, tmp_path, served, ["H0001"])
    plant, _cams, clock, _sim, _server = served
    _separate_weather_link(plant)
    port = plant.scs.port
    plant.scs.close()
    plant.scs.port, plant.scs.retries, plant.scs.down_s = _closed_port(), 0, 0.0
    clock.resync_s = 0.0
    lock = threading.Lock()
    live._tick_job(runner, lock)
    assert runner.state.faults.plant_unreachable_since_s is not None
    plant.scs.close()
    plant.scs.port = port  # the SCS answers again
    live._tick_job(runner, lock)
    events = store.events(campaign_id=cid)
    store.close()
    assert [e.kind for e in events if e.kind in ("plant_lost", "plant_back")] == ["plant_lost", "plant_back"]
    assert runner.state.faults.plant_unreachable_since_s is None


def test_a_refusal_is_an_answer_not_an_unreachable_plant(cfg, tmp_path, served):
    from helicalib.errors import PlantError

    runner, store, cid = _network_runner(cfg, tmp_path, served, ["H0001"])
    lock = threading.Lock()

    def refuse():  # what ModbusLink raises for a Modbus exception reply
        raise PlantError("plant 127.0.0.1:5020 unit 1: read of weather block refused: Modbus exception 4 "
                         "(device failure)")

    runner.devices.plant.weather = refuse
    for _ in range(3):
        runner.state.last_poll_s = -1e18
        live._weather_job(runner, lock)
    events = store.events(campaign_id=cid)
    store.close()
    assert runner.state.faults.plant_unreachable_since_s is None
    assert not [e for e in events if e.kind == "plant_lost"]
    faults = [e.reason for e in events if e.kind == "fault"]
    assert len(faults) == 1 and "Modbus exception 4" in faults[0], faults  # one line, not one per poll


def test_two_jobs_losing_the_plant_at_once_say_it_once(cfg, tmp_path, served):
    """The tick's thread and the weather job find the plant gone at the same moment: ONE plant_lost."""
    import time

    runner, store, cid = _network_runner(cfg, tmp_path, served, ["H0001"])
    clock = served[2]
    estimate = clock.estimate_s

    def slow_estimate():  # a busy machine: the thread is descheduled between the check and the set
        time.sleep(0.05)
        return estimate()

    clock.estimate_s = slow_estimate
    jobs = [threading.Thread(target=runner.journal.plant_failed, args=(f"{job}: no answer",)) for job in ("tick", "weather")]
    for job in jobs:
        job.start()
    for job in jobs:
        job.join(10.0)
    lost = store.events(campaign_id=cid, kind="plant_lost")
    store.close()
    assert len(lost) == 1, [e.reason for e in lost]
