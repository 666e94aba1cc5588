"""The Modbus plant client against the simulated plant served on loopback (real sockets).

Plant time comes from a fake monotonic source the test moves; retries sleep through an injected
no-op, so nothing waits on the wall clock except the one timeout test.
"""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.config import Endpoint, load_field_config
from helicalib.devices import registers as R
from helicalib.devices.clock import PlantClock, SystemClock
from helicalib.devices.modbus import ModbusPlant
from helicalib.devices.protocols import Plant
from helicalib.errors import PlantError
from helicalib.geometry.sun import to_unix_seconds
from helicalib.sim.clock import RateClock
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.server import FaultInjector, PlantServer

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))
RATE = 600.0


class FakeSource:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def no_sleep(_seconds):
    pass


@pytest.fixture()
def served(demo_field_path):
    cfg = load_field_config(demo_field_path)
    source = FakeSource()
    clock = RateClock(START, RATE, source)
    plant = SimulatedPlant(cfg, start_s=START, rate=RATE)
    faults = FaultInjector()
    server = PlantServer(plant, clock, modbus_port=0, camera_port=0, faults=faults).start()
    endpoint = Endpoint(host="127.0.0.1", port=server.modbus_port, unit=cfg.plant.scs.unit, timeout_s=2.0)
    yield cfg, plant, server, endpoint, source, faults
    server.stop()


def client(cfg, endpoint, armed=True, **kw):
    limits = np.array([[a.stroke_range_mm for a in cfg.drive_of(h.id).actuators] for h in cfg.heliostats])
    kw.setdefault("sleep", no_sleep)
    return ModbusPlant(endpoint, None, len(cfg.heliostats), armed=armed, heliostat_ids=[h.id for h in cfg.heliostats],
                       stroke_limits_mm=limits, **kw)


def mid_strokes(cfg, i):
    return np.array([a.stroke_range_mm for a in cfg.drive_of(cfg.heliostats[i].id).actuators]).mean(axis=1)


def test_reads_match_the_plant(served):
    cfg, plant, _, endpoint, source, _ = served
    with client(cfg, endpoint, armed=False) as mp:
        assert isinstance(mp, Plant)
        assert mp.interface_version() == R.INTERFACE_VERSION
        assert mp.heliostat_count() == len(cfg.heliostats)
        source.t += 1.0
        t, rate = mp.plant_time()
        assert t == pytest.approx(START + RATE, abs=1e-6) and rate == pytest.approx(RATE)
        w = mp.weather()
        truth = plant.weather()
        assert w.wind_ms == pytest.approx(truth.wind_ms, rel=1e-6) and w.dni_wm2 == pytest.approx(truth.dni_wm2, rel=1e-6)
        assert mp.field_state() == R.FieldState.TRACKING
        st = mp.status(5)
        assert st.index == 5 and st.state == R.HeliostatState(int(plant.state[5]))
        assert st.strokes_mm == pytest.approx(tuple(plant.strokes_mm[5]), abs=1e-3)
        assert 0.0 <= st.cleanliness <= 1.0


def test_unarmed_client_writes_nothing(served):
    cfg, plant, _, endpoint, _, _ = served
    before = (plant.sequence_done.copy(), plant.state.copy(), plant.field_stow)
    with client(cfg, endpoint, armed=False) as mp:
        for call in (lambda: mp.move_to(2, mid_strokes(cfg, 2)), lambda: mp.track(2, [0.0, 0.0]),
                     lambda: mp.stow(2), lambda: mp.field_command(R.FieldCommand.STOW_ALL)):
            with pytest.raises(PlantError, match="read-only mode"):
                call()
    assert np.array_equal(plant.sequence_done, before[0]) and np.array_equal(plant.state, before[1])
    assert plant.field_stow == before[2] and np.all(plant.reg_command == 0)


def test_move_hold_track_and_stow_with_new_sequence_numbers(served):
    cfg, plant, _, endpoint, source, _ = served
    with client(cfg, endpoint) as mp:
        goal = mid_strokes(cfg, 3)
        seq1 = mp.move_to(3, goal)
        assert plant.sequence_done[3] == seq1
        assert plant.reg_strokes_cmd[3] == pytest.approx(goal, abs=1e-3)
        source.t += 2.0  # 1200 plant seconds: arrived and settled
        st = mp.status(3)
        assert st.state == R.HeliostatState.HOLDING and st.sequence_done == seq1
        assert st.strokes_mm == pytest.approx(tuple(goal), abs=0.5)
        seq2 = mp.move_to(3, goal + [1.0, -1.0])
        assert seq2 != seq1 and plant.sequence_done[3] == seq2
        seq3 = mp.track(3, [1.5, -2.25])
        assert plant.sequence_done[3] == seq3 and plant.corrections_mm[3] == pytest.approx([1.5, -2.25])
        seq4 = mp.stow(3)
        assert plant.sequence_done[3] == seq4 and len({seq1, seq2, seq3, seq4}) == 4
    # a fresh client (a restarted campaign) still sends a number the plant sees as new
    with client(cfg, endpoint) as mp2:
        seq5 = mp2.move_to(3, goal)
        assert seq5 != seq4 and plant.sequence_done[3] == seq5


def test_field_command_stows_and_resumes(served):
    cfg, plant, _, endpoint, source, _ = served
    with client(cfg, endpoint) as mp:
        mp.field_command(R.FieldCommand.STOW_ALL)
        assert mp.field_state() in (R.FieldState.STOWING, R.FieldState.STOWED)
        source.t += 5.0
        assert mp.field_state() == R.FieldState.STOWED
        mp.field_command(R.FieldCommand.RESUME_TRACKING)
        assert mp.field_state() == R.FieldState.TRACKING


def test_out_of_range_and_non_finite_strokes_never_leave_the_client(served):
    cfg, plant, _, endpoint, _, _ = served
    lim = np.array([a.stroke_range_mm for a in cfg.drive_of(cfg.heliostats[4].id).actuators])
    with client(cfg, endpoint) as mp:
        for bad in ([lim[0, 1] + 0.01, lim[1].mean()], [lim[0].mean(), lim[1, 0] - 0.01], [np.nan, 1.0]):
            with pytest.raises(PlantError, match="refusing"):
                mp.move_to(4, bad)
        # the range edges themselves are allowed
        mp.move_to(4, [lim[0, 1], lim[1, 0]])
    assert plant.fault[4] == R.FaultCode.NONE
    assert np.all(plant.reg_strokes_cmd[4] == pytest.approx([lim[0, 1], lim[1, 0]], abs=1e-3))


def test_wrong_heliostat_count_and_index_are_refused(served):
    cfg, _, _, endpoint, _, _ = served
    with ModbusPlant(endpoint, heliostat_count=len(cfg.heliostats) - 1, sleep=no_sleep) as mp:
        with pytest.raises(PlantError, match="reports 40 heliostats, the field config has 39"):
            mp.heliostat_count()
    with client(cfg, endpoint) as mp:
        with pytest.raises(PlantError, match="index 40 outside"):
            mp.status(40)
        with pytest.raises(PlantError, match=r"address 2280.*refused: Modbus exception 2"):
            mp.scs.read(R.heliostat_address(40), 1, "beyond the last block")


def test_write_to_read_only_register_names_the_register(served):
    cfg, _, _, endpoint, _, _ = served
    with client(cfg, endpoint) as mp:
        with pytest.raises(PlantError, match=r"write of state \(address 1002\) refused: Modbus exception 2"):
            mp.scs.write(R.heliostat_address(0, R.OFF_STATE), [1], "state")


def test_dropped_connections_are_retried_and_reconnected(served):
    cfg, plant, _, endpoint, source, faults = served
    faults.modbus_drop_probability = 0.4
    waits = []
    with client(cfg, endpoint, retries=8, sleep=waits.append) as mp:
        for _ in range(15):
            assert mp.status(1).index == 1
        seq = mp.move_to(1, mid_strokes(cfg, 1))
        assert plant.sequence_done[1] == seq
        assert mp.scs.reconnects > 0 and waits
        assert waits[0] == pytest.approx(0.2)  # back-off starts at backoff_s and doubles
        if len(waits) > 1:
            assert max(waits) <= 5.0
    faults.modbus_drop_probability = 1.0
    waits.clear()
    with client(cfg, endpoint, retries=3, sleep=waits.append) as mp:
        with pytest.raises(PlantError, match=r"read of interface version and heliostat count \(address 0, 2 registers\) "
                                             r"failed after 4 attempts"):
            mp.heliostat_count()
    assert waits == pytest.approx([0.2, 0.4, 0.8])


def test_slow_answers_time_out(served):
    cfg, _, _, endpoint, _, faults = served
    faults.modbus_slow_probability = 1.0
    faults.modbus_slow_s = 1.5
    slow = Endpoint(host=endpoint.host, port=endpoint.port, unit=endpoint.unit, timeout_s=0.3)
    with ModbusPlant(slow, retries=1, sleep=no_sleep) as mp:
        with pytest.raises(PlantError, match="failed after 2 attempts"):
            mp.plant_time()


def test_no_server_is_a_plant_error():
    import socket

    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with ModbusPlant(Endpoint(host="127.0.0.1", port=port, timeout_s=0.5), retries=2, sleep=no_sleep) as mp:
        with pytest.raises(PlantError, match=f"127.0.0.1:{port} unit 1: read of weather block"):
            mp.weather()


def test_plant_clock_follows_the_served_plant(served):
    cfg, _, _, endpoint, source, _ = served
    real = FakeSource()
    slept = []
    with client(cfg, endpoint, armed=False) as mp:
        clock = PlantClock(mp, resync_s=10.0, source=real, sleeper=slept.append)
        assert clock.now_s() == pytest.approx(START, abs=1e-6)
        real.t += 2.0  # extrapolated at the plant's rate, without a read
        source.t += 3.0  # the plant moves on further, seen only at the next resync
        assert clock.now_s() == pytest.approx(START + 2.0 * RATE, abs=1e-6)
        real.t += 10.0
        assert clock.now_s() == pytest.approx(START + 3.0 * RATE, abs=1e-6)
        clock.sleep(1200.0)
        assert slept == [pytest.approx(2.0)]


def test_plant_clock_refuses_time_going_backwards():
    class Fake:
        t = 1000.0

        def plant_time(self):
            return self.t, 1.0

    plant, real = Fake(), FakeSource()
    clock = PlantClock(plant, resync_s=1.0, source=real, sleeper=no_sleep)
    clock.now_s()
    plant.t = 900.0
    real.t += 5.0
    with pytest.raises(PlantError, match="backwards"):
        clock.now_s()
    slept_list = []
    sc = SystemClock(source=lambda: 42.0, sleeper=slept_list.append)
    sc.sleep(3.0)
    assert sc.now_s() == 42.0 and slept_list == [3.0]
