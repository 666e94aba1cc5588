"""A wind stow the weather job sends while another thread commands heliostats (a tick held up by a
slow plant, a refresh of the field's tracking corrections): the client's stow gate.

The simulated plant is served on loopback; each write to it is slowed down (a slow SCS), and every
write is logged in the order it went on the wire.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from test_devices_modbus import client, mid_strokes, served  # noqa: F401 - a fixture
from helicalib.devices import registers as R
from helicalib.devices.protocols import FieldStowedError
from helicalib.errors import PlantError


def _slow_and_logged(mp, delay_s=0.01):
    """Slow every write of ``mp`` down by ``delay_s`` and log (address, what) in wire order."""
    wire = []
    write = mp.scs.write

    def slow_write(address, values, what):
        time.sleep(delay_s)
        write(address, values, what)
        wire.append((address, what))

    mp.scs.write = slow_write
    return wire


def test_no_heliostat_command_lands_after_a_stow_all(served):
    cfg, plant, _server, endpoint, _source, _faults = served
    mp = client(cfg, endpoint)
    wire = _slow_and_logged(mp)
    refused, started = [], threading.Event()

    def commands():  # a refresh of the field's tracking, or a visit's moves, on a slow plant
        for i in range(12):
            if i == 2:
                started.set()
            try:
                if i % 2:
                    mp.move_to(i, mid_strokes(cfg, i))
                else:
                    mp.track(i, np.array([0.1, -0.1]))
            except FieldStowedError as err:
                refused.append((i, str(err)))

    worker = threading.Thread(target=commands)
    worker.start()
    started.wait(10.0)
    time.sleep(0.015)  # mid-command: between its fields and its sequence number
    mp.field_command(R.FieldCommand.STOW_ALL)
    worker.join(20.0)
    stow_at = next(k for k, (addr, _w) in enumerate(wire) if addr == R.REG_FIELD_COMMAND)
    after = [what for _a, what in wire[stow_at + 1:]]
    # nothing of a heliostat command went on the wire after the stow: the plant acts on none of them
    assert after == [], after
    assert refused and all("stowed" in text for _i, text in refused)
    assert not np.any(plant.fault == R.FaultCode.REFUSED_DURING_STOW)
    assert mp.stowed
    # a stow of one heliostat stays allowed; the field's resume opens the gate again
    mp.stow(20)
    mp.field_command(R.FieldCommand.RESUME_TRACKING)
    assert not mp.stowed
    mp.track(0, None)
    mp.close()


def test_the_gate_refuses_in_one_line_naming_the_heliostat(served):
    cfg, _plant, _server, endpoint, _source, _faults = served
    with client(cfg, endpoint) as mp:
        mp.field_command(R.FieldCommand.STOW_ALL)
        with pytest.raises(PlantError, match=r"TRACK command to heliostat 3 \(H0004\) not sent: the field is stowed"):
            mp.track(3, None)
