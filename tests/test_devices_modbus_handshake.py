"""A command's last write when its answer is lost, over real loopback sockets: the simulated plant's
Modbus server handles the request and then drops the connection without answering (or drops it
before handling), and :class:`ModbusPlant` must neither send the command twice nor lose track of it.

An execute handshake (SCS-B) acts on every write of 1, so the execute write is sent once and the
plant's counter decides; a sequence handshake (PLANT_INTERFACE.md) acts on a change, so its write is
retried and the rewrite of the same number is no second command.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_devices_modbus import client, served  # noqa: F401 - a fixture: the default plant on loopback
from test_devices_modbus_maps import BASE, STRIDE, regs, serve

from helicalib.devices.protocols import PlantUnreachableError
from helicalib.devices.registers import HeliostatState
from helicalib.errors import PlantError

EXECUTE = 9


class Faults:
    """The server's ``request_fault``: ``kind`` for writes of one register from the ``when``-th on
    (``every``: and for every request after it)."""

    def __init__(self, address: int, kind: str, every: bool = False):
        self.address, self.kind, self.every = address, kind, every
        self.hits = 0

    def __call__(self, pdu):
        if self.every and self.hits:
            self.hits += 1
            return self.kind
        if pdu.function_code in (6, 16) and pdu.address == self.address and not self.hits:
            self.hits += 1
            return self.kind
        return None


def count_commands(monkeypatch, plant) -> list[int]:
    """Heliostat indices of every command the simulated plant acts on, in order."""
    taken: list[int] = []
    act = plant._process

    def spy(i):
        taken.append(int(i))
        return act(i)

    monkeypatch.setattr(plant, "_process", spy)
    return taken


def test_a_lost_execute_answer_is_not_resent_and_the_command_counts_once(monkeypatch):
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        i = 4
        b = BASE + STRIDE * i
        before = regs(raw, "input", b + 7, 1)[0]
        taken = count_commands(monkeypatch, plant)
        server._modbus[0].request_fault = fault = Faults(b + EXECUTE, "lose_answer")
        token = mp.move_to(i, [700.0, 600.0])
        assert fault.hits == 1 and mp.scs.reconnects >= 1          # the answer was lost, the link reopened
        assert token == (before + 1) & 0xFFFF and taken == [i]      # taken once: no second execute
        assert plant.sequence_done[i] == token
        source.t += 30
        st = mp.status(i)                                           # the campaign's wait ends
        assert st.sequence_done == token and st.state == HeliostatState.HOLDING
        assert np.allclose(plant.goal_cmd_mm[i], [700.0, 600.0])


def test_an_execute_write_the_plant_never_took_is_refused_not_resent(monkeypatch):
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        i = 5
        b = BASE + STRIDE * i
        before = int(plant.sequence_done[i])
        taken = count_commands(monkeypatch, plant)
        server._modbus[0].request_fault = fault = Faults(b + EXECUTE, "drop")
        with pytest.raises(PlantError) as err:
            mp.move_to(i, [700.0, 600.0])
        msg = str(err.value)
        assert not isinstance(err.value, PlantUnreachableError)     # the plant answered the check
        assert "\n" not in msg and "heliostat 5 (H0006)" in msg and f"holding {b + EXECUTE}" in msg
        assert f"shows {before}, not {before + 1}" in msg and msg.endswith("may or may not have been taken; not resent")
        assert fault.hits == 1 and taken == [] and regs(raw, "holding", b + EXECUTE, 1) == [0]
        assert plant.sequence_done[i] == before
        # the heliostat takes the next command as usual
        assert mp.move_to(i, [650.0, 600.0]) == before + 1 and taken == [i]


def test_no_answer_to_the_check_either_is_unreachable(monkeypatch):
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        i = 6
        b = BASE + STRIDE * i
        taken = count_commands(monkeypatch, plant)
        server._modbus[0].request_fault = Faults(b + EXECUTE, "drop", every=True)
        with pytest.raises(PlantUnreachableError) as err:
            mp.stow(i)
        msg = str(err.value)
        assert "\n" not in msg and "heliostat 6 (H0007)" in msg and "none to the check of its counter" in msg
        assert msg.endswith("may or may not have been taken; not resent") and taken == []


def test_a_lost_sequence_answer_is_retried_and_taken_once(served, monkeypatch):
    cfg, plant, server, endpoint, source, _faults = served
    i = 2
    m = server.registers.map
    seq = m.address(m.q["heliostats.command.handshake.sequence"], i)
    taken = count_commands(monkeypatch, plant)
    server._modbus[0].request_fault = fault = Faults(seq, "lose_answer")
    with client(cfg, endpoint) as mp:
        token = mp.move_to(i, [700.0, 600.0])
        assert fault.hits == 1 and mp.scs.reconnects >= 1
        assert taken == [i] and plant.sequence_done[i] == token      # rewritten, not acted on again
