"""A wind gust while the tick is held up by a slow plant: the weather job's stow is the last word.

The simulated plant is served on loopback (Modbus TCP) with the real client; each write to the
plant is slowed down and logged in wire order. The tick's thread refreshes the field's tracking
corrections (one track command per calibrated heliostat, a slice per tick, or a live run's batches
of several in flight on connections of their own) while the weather job, finding the tick
busy, reads a gust and stows the field on its own (:mod:`helicalib.app.live`).
"""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from test_live_faults import _network_runner, cfg, served  # noqa: F401 - fixtures
from helicalib.app import live
from helicalib.devices import registers as R
from helicalib.devices.modbus_link import ModbusLink


@pytest.mark.parametrize("batches", [False, True], ids=["a-slice-per-tick", "batches-in-flight"])
def test_no_track_or_move_is_accepted_after_a_gust_stows_the_field_mid_refresh(cfg, tmp_path, served, monkeypatch,
                                                                               batches):
    ids = [h.id for h in cfg.heliostats[:12]]
    runner, store, cid = _network_runner(cfg, tmp_path, served, ids)
    runner.tracking.batches = batches  # a live run's (run_live), or a simulation's over the network
    plant, _cams, clock, sim, _server = served
    runner.state.book.points = lambda hid: [hid]  # every heliostat calibrated: the refresh writes each one's corrections
    wire, busy = [], threading.Event()
    write, weather = ModbusLink.write, plant.weather

    def slow_write(link, address, values, what, **kw):  # a slow SCS: 30 ms a write, on every connection
        busy.set()
        time.sleep(0.03)
        write(link, address, values, what, **kw)
        wire.append((address, what))

    monkeypatch.setattr(ModbusLink, "write", slow_write)  # the refresh's batches go on connections of their own
    plant.weather = lambda: dataclasses.replace(weather(), wind_ms=cfg.gating.stow_wind_ms + 5.0)  # a gust
    lock = threading.Lock()

    def tick():  # the tick's thread, holding the jobs' lock while it refreshes on the slow plant
        with lock:
            runner.tracking.refresh(clock.now_s())
        while runner.state.refresh_round is not None:  # the round's slices, a tick each
            with lock:
                runner.tracking.write_round()

    ticking = threading.Thread(target=tick)
    ticking.start()
    busy.wait(10.0)
    time.sleep(0.1)
    live._weather_job(runner, lock)  # the tick holds the lock: the weather job stows on its own
    ticking.join(30.0)
    events = store.events(campaign_id=cid)
    store.close()
    assert (plant._batch is not None) == batches   # the round went out in batches, or one command after another
    assert runner.state.stowed and [e.kind for e in events if e.kind == "stow"] == ["stow"]
    stow_at = next(k for k, (addr, _w) in enumerate(wire) if addr == R.REG_FIELD_COMMAND)
    assert 0 < stow_at, "the gust came before the refresh wrote anything"
    assert wire[stow_at + 1:] == []  # no heliostat's command went out after the stow
    assert not np.any(sim.fault == R.FaultCode.REFUSED_DURING_STOW)
    # the refresh stopped quietly: the stow is the news, not a fault line per heliostat
    assert not [e for e in events if e.kind == "fault"], [e.reason for e in events if e.kind == "fault"]
