"""The tracking refresh with several track commands in flight (devices/modbus_batch.py) against the
simulated plant served on loopback Modbus TCP, with the real client: a batch goes out while the tick
goes on, and is waited for only before the tick commands one of its heliostats; every heliostat's
corrections written exactly once, on several connections at once; a refused write reported as one
fault line.

Every write on any connection is slowed a little (a slow SCS) and logged; the one heliostat whose
writes the SCS refuses stands for a plant that says no.
"""

from __future__ import annotations

import re
import threading
import time
from collections import Counter

import numpy as np
import pytest

from test_live_faults import _network_runner, cfg, served  # noqa: F401 - fixtures
from helicalib.devices.modbus_link import ModbusLink
from helicalib.errors import PlantError

GO = re.compile(r"\((\S+)\) (sequence number|execute)$")
"""The write that makes the plant act on a command: its label names the heliostat."""
REFUSED = "H0005"


def test_a_parallel_refresh_writes_every_heliostat_s_corrections_once(cfg, tmp_path, served, monkeypatch):
    ids = [h.id for h in cfg.heliostats[:24]]
    runner, store, cid = _network_runner(cfg, tmp_path, served, ids)
    plant, _cams, _clock, sim, _server = served
    st = runner.state
    st.book.points = lambda hid: [hid]  # every heliostat calibrated: the refresh writes each one's corrections
    assert runner.devices.abilities.parallel_tracking and not runner.devices.abilities.bulk_tracking
    runner.tracking.batches = True      # as run_live sets it
    acted, links, lock = Counter(), set(), threading.Lock()
    flight = {"now": 0, "peak": 0}
    write = ModbusLink.write

    def logged(link, address, values, what, **kw):
        with lock:
            flight["now"] += 1
            flight["peak"] = max(flight["peak"], flight["now"])
            links.add(id(link))
        try:
            time.sleep(0.004)
            if f"({REFUSED})" in what:
                raise PlantError(f"plant {link.name}: write of {what} refused: Modbus exception 4 (device failure)")
            write(link, address, values, what, **kw)
        finally:
            with lock:
                flight["now"] -= 1
        go = GO.search(what)
        if go:
            with lock:
                acted[go.group(1)] += 1

    monkeypatch.setattr(ModbusLink, "write", logged)
    kept = st.corrections[REFUSED]
    runner.tracking.refresh(runner.devices.clock.now_s())
    runner.tracking.write_round()                              # a batch sent: the tick goes on meanwhile
    r = st.refresh_round
    assert r.sent is not None and not r.sent.done() and [h for h, _c in r.flight] == ids[:len(r.flight)]
    runner.tracking.land({"nobody"})                           # none of its heliostats commanded: no wait
    assert r.sent is not None
    runner.tracking.land({ids[2]})                             # a command of the tick's own to one of them waits
    assert r.sent is None and not r.flight
    assert np.allclose(st.corrections[ids[2]], sim.corrections_mm[cfg.heliostat_index(ids[2])], atol=0.006)
    while st.refresh_round is not None:
        runner.tracking.write_round()
    written = [h for h in ids if h != REFUSED]
    assert acted == Counter({h: 1 for h in written})          # each heliostat's command once, the refused one never
    for hid in written:                                        # in the plant's registers (0.01 mm resolution)
        assert np.allclose(sim.corrections_mm[cfg.heliostat_index(hid)], st.corrections[hid], atol=0.006)
    assert st.corrections[REFUSED] is kept                    # the campaign keeps what the plant has
    assert flight["peak"] >= 2 and len(links) >= 2            # several commands in flight, on their own connections
    faults = store.events(campaign_id=cid, kind="fault")
    store.close()
    assert len(faults) == 1 and "1 heliostat(s)" in faults[0].reason and REFUSED in faults[0].reason
    assert "device failure" in faults[0].reason


def test_an_endpoint_that_takes_one_client_gets_the_refresh_one_command_at_a_time(cfg, served):
    """The batch's own connections cannot connect (nothing listens where they go) while the SCS
    connection answers: the commands go on the SCS connection, each heliostat's corrections taken."""
    from conftest import free_port

    from helicalib.devices.modbus_batch import TrackBatch

    plant, _cams, _clock, sim, _server = served
    plant.guard.armed = True
    plant.weather()   # the SCS connection answers (the weather station is on it)
    assert plant.scs.answered
    batch = TrackBatch(plant, links=2)
    nowhere = free_port()
    for link in batch.links:
        link.port, link.retries, link.backoff_s = nowhere, 0, 0.0
    plant._batch = batch
    items = [(i, np.array([0.1 * (i + 1), -0.05 * (i + 1)])) for i in range(6)]
    try:
        assert plant.send_tracks(items).results() == [None] * 6
    finally:
        plant.guard.armed = False
    assert batch.direct is not None and "took no connection beside the SCS one" in batch.direct
    assert not any(link.answered for link in batch.links)
    for i, c in items:
        assert sim.corrections_mm[i] == pytest.approx(c, abs=1e-3)
