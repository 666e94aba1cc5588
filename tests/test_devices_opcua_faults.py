"""The OPC UA client at its edges, against the simulated plant on a real asyncua server on loopback:
values a method argument's type cannot carry, a Float stroke at its drive's limit, a command whose
answer is lost (never executed twice), and the client's event loop closed with it.

The lost answers are real link faults: the server closes its connections from inside the method
call (after acting on it, or before), or stops altogether (``OpcUaPlantService.lose_next_call``).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from asyncua import ua

from helicalib.config import load_field_config
from helicalib.devices.guard import CommandGuard
from helicalib.devices.opcua import OpcUaPlant
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.devices.registers import FieldCommand
from helicalib.errors import PlantError
from helicalib.geometry.sun import to_unix_seconds
from helicalib.sim.clock import RateClock
from helicalib.sim.opcua_server import OpcUaPlantService
from helicalib.sim.plant import SimulatedPlant

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))
RATE = 600.0


@pytest.fixture(scope="module")
def served(demo_field_path):
    cfg = load_field_config(demo_field_path)
    source = SimpleNamespace(t=100.0)
    plant = SimulatedPlant(cfg, start_s=START, rate=RATE)
    svc = OpcUaPlantService(plant, RateClock(START, RATE, lambda: source.t)).start()
    yield cfg, plant, svc
    svc.stop()


def client(cfg, svc, node_map=None, limits=None, timeout_s=2.0) -> OpcUaPlant:
    g = CommandGuard.from_config(cfg, True)
    return OpcUaPlant(svc.endpoint, node_map or svc.map, g.heliostat_ids, len(cfg.heliostats), armed=True,
                      stroke_limits_mm=g.stroke_limits_mm if limits is None else limits, timeout_s=timeout_s)


def mid_strokes(cfg, i):
    return np.array([a.stroke_range_mm for a in cfg.drive_of(cfg.heliostats[i].id).actuators]).mean(axis=1)


def calls_to(svc, name, hid):
    return [args for n, args in svc.calls if n == name and args[0] == hid]


def with_move_args(nm, *args):
    """The map with other move arguments, built in code (past the loader's checks)."""
    move = nm.commands.move.model_copy(update={"args": list(args)})
    return nm.model_copy(update={"commands": nm.commands.model_copy(update={"move": move})})


def test_a_float_stroke_at_the_drives_limit_stays_inside_it(served):
    """100.7 and 1500.3 are no 32-bit floats: the nearest ones lie outside [100.7, 1500.3]."""
    cfg, _plant, svc = served
    i, hid = 11, cfg.heliostats[11].id
    limits = CommandGuard.from_config(cfg).stroke_limits_mm.copy()
    limits[i] = [[100.7, 1800.0], [200.0, 1500.3]]
    nm = with_move_args(svc.map, "sequence", "stroke_1_mm:Float", "stroke_2_mm:Float")
    with client(cfg, svc, nm, limits) as op:
        op.move_to(i, [100.7, 1500.3])
    _hid, _seq, s1, s2 = calls_to(svc, "MoveTo", hid)[-1]
    assert 100.7 <= s1 < 100.7 + 1e-5 and 1500.3 - 1e-4 < s2 <= 1500.3
    assert np.float32(s1) == s1 and np.float32(s2) == s2


def test_an_integer_its_argument_cannot_carry_is_refused_before_sending(served):
    """A map built in code with ``sequence:Byte`` and the plant at sequence 300: refused, named, and
    the link is not taken for lost (the next read goes through at once)."""
    cfg, plant, svc = served
    i, hid = 12, cfg.heliostats[12].id
    with svc.lock:
        plant.sequence_done[i] = 300
    nm = with_move_args(svc.map, "sequence:Byte", "stroke_1_mm", "stroke_2_mm")
    with client(cfg, svc, nm) as op:
        with pytest.raises(PlantError) as err:
            op.move_to(i, mid_strokes(cfg, i))
        assert not isinstance(err.value, PlantUnreachableError)
        msg = str(err.value)
        assert "\n" not in msg and f"heliostat {i} ({hid})" in msg
        assert "not sent: argument sequence 301 does not fit the argument's type Byte (0..255)" in msg
        assert op.status(i).sequence_done == 300
    assert calls_to(svc, "MoveTo", hid) == []


def test_an_encoding_error_is_not_a_lost_link(served):
    """A UaError that is not raised on the wire is the request's fault: no retry, no outage."""
    cfg, _plant, svc = served
    tries = []

    async def job(client_, link):
        tries.append(1)
        ua.ua_binary.variant_to_binary(ua.Variant(70000, ua.VariantType.Int16))

    with client(cfg, svc) as op:
        op.heliostat_count()
        with pytest.raises(PlantError) as err:
            op.link.call("test request", job)
        assert not isinstance(err.value, PlantUnreachableError) and len(tries) == 1
        assert "\n" not in str(err.value) and "test request not sent: Cannot pack VariantType.Int16" in str(err.value)
        assert op.weather().dni_wm2 >= 0


def test_a_command_whose_answer_is_lost_is_taken_once(served):
    cfg, plant, svc = served
    i, hid = 13, cfg.heliostats[13].id
    with client(cfg, svc) as op:
        svc.lose_next_call("answer")
        seq = op.move_to(i, mid_strokes(cfg, i))
        assert op.status(i).sequence_done == seq == int(plant.sequence_done[i])
        assert [c[1] for c in calls_to(svc, "MoveTo", hid)] == [seq]
        assert op.move_to(i, mid_strokes(cfg, i)) == seq + 1      # the link is back


def test_a_command_lost_before_the_plant_acted_is_an_error_and_not_resent(served):
    cfg, plant, svc = served
    i, hid = 14, cfg.heliostats[14].id
    with client(cfg, svc) as op:
        svc.lose_next_call("request")
        with pytest.raises(PlantError) as err:
            op.stow(i)
        msg = str(err.value)
        assert not isinstance(err.value, PlantUnreachableError) and "\n" not in msg
        assert f"STOW command to heliostat {i} ({hid}) (sequence 1) may or may not have been taken; not resent" in msg
        assert "sequence done reads 0" in msg
        assert calls_to(svc, "Stow", hid) == [] and int(plant.sequence_done[i]) == 0
        assert op.stow(i) == 2                       # a fresh number: 1 may still arrive
        assert [c[1] for c in calls_to(svc, "Stow", hid)] == [2]


def test_a_field_command_whose_answer_is_lost_is_not_resent(served):
    cfg, plant, svc = served
    with client(cfg, svc) as op:
        before = len([c for c in svc.calls if c[0] == "Command"])
        svc.lose_next_call("answer")
        with pytest.raises(PlantError, match=r"field command STOW_ALL may or may not have been taken; not resent"):
            op.field_command(FieldCommand.STOW_ALL)
        assert len([c for c in svc.calls if c[0] == "Command"]) == before + 1 and plant.field_stow
        assert op.stowed                             # on the safe side: moves and tracks held back
        op.field_command(FieldCommand.RESUME_TRACKING)
        assert not op.stowed and not plant.field_stow


def test_a_plant_gone_after_a_command_is_unreachable_and_the_command_not_resent(demo_field_path):
    cfg = load_field_config(demo_field_path)
    plant = SimulatedPlant(cfg, start_s=START, rate=RATE)
    svc = OpcUaPlantService(plant, RateClock(START, RATE, lambda: 100.0)).start()
    try:
        with client(cfg, svc, timeout_s=1.0) as op:
            svc.lose_next_call("plant")
            with pytest.raises(PlantUnreachableError) as err:
                op.move_to(2, mid_strokes(cfg, 2))
        msg = str(err.value)
        assert "\n" not in msg and "MOVE command to heliostat 2 (H0003) (sequence 1) may or may not have been " \
            "taken; not resent" in msg and "read of heliostat 2 (H0003) sequence done failed" in msg
        assert len(calls_to(svc, "MoveTo", "H0003")) == 1 and int(plant.sequence_done[2]) == 1
    finally:
        svc.stop()


def test_closing_the_client_closes_its_event_loop(served):
    cfg, _plant, svc = served
    op = client(cfg, svc)
    op.status(0)
    op.close()
    assert op.link._loop.is_closed() and not op.link._thread.is_alive()
    op.close()                                       # twice is harmless
