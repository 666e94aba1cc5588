"""Interface conformance of the served simulated plant (PLANT_INTERFACE.md, version 1).

A plain pymodbus client and urllib talk to the server over real loopback sockets, register by
register. Plant time comes from a fake monotonic source the test moves, so nothing depends on
the wall clock.
"""

from __future__ import annotations

import http.client
import struct
import urllib.error
import urllib.request

import cv2
import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from helicalib.config import load_field_config
from helicalib.devices import registers as R
from helicalib.geometry.sun import sun_at_site, to_unix_seconds
from helicalib.sim.clock import RateClock
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.sim.server import FaultInjector, PlantServer

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))   # 12:17 local solar time at Dunhuang
RATE = 600.0
UNIT = 1


class FakeSource:
    """Monotonic source in 'real' seconds that only moves when the test says so."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def f32(regs):  # independent decoding (not the package's helper)
    return struct.unpack(">f", struct.pack(">HH", *regs))[0]


def f64(regs):
    return struct.unpack(">d", struct.pack(">HHHH", *regs))[0]


def to_regs(x):
    return list(struct.unpack(">HH", struct.pack(">f", x)))


@pytest.fixture()
def served(demo_field_path):
    cfg = load_field_config(demo_field_path)
    scenario = parse_scenario({
        "faults": {"offline": [cfg.heliostats[39].id]},
        "weather": {"events": [{"start": "2026-03-21T05:00:00Z", "end": "2026-03-21T06:00:00Z", "wind_ms": 20.0}]},
    })
    source = FakeSource()
    clock = RateClock(START, RATE, source)
    plant = SimulatedPlant(cfg, scenario, start_s=START, rate=RATE)
    server = PlantServer(plant, clock, modbus_port=0, camera_port=0, faults=FaultInjector()).start()
    client = ModbusTcpClient("127.0.0.1", port=server.modbus_port, timeout=5, retries=0)
    assert client.connect()
    yield cfg, plant, server, client, source
    client.close()
    server.stop()


def read(client, address, count):
    r = client.read_holding_registers(address, count=count, device_id=UNIT)
    assert not r.isError(), r
    return r.registers


def block(client, i):
    return read(client, R.heliostat_address(i), 20)


def command(client, i, cmd, seq, strokes=None, corr=None):
    base = 1000 + 32 * i
    if strokes is not None:
        assert not client.write_registers(base + 6, to_regs(strokes[0]) + to_regs(strokes[1]), device_id=UNIT).isError()
    if corr is not None:
        assert not client.write_registers(base + 14, to_regs(corr[0]) + to_regs(corr[1]), device_id=UNIT).isError()
    assert not client.write_register(base + 0, cmd, device_id=UNIT).isError()
    assert not client.write_register(base + 1, seq, device_id=UNIT).isError()


def test_field_block_version_counts_time_and_rate(served):
    cfg, _, _, client, source = served
    regs = read(client, 0, 14)
    assert regs[0] == 1 and regs[1] == 40 and regs[2] == 2
    assert f64(regs[8:12]) == pytest.approx(START, abs=1e-6)
    assert f32(regs[12:14]) == pytest.approx(RATE)
    source.t += 2.5                     # 2.5 real seconds = 1500 plant seconds
    assert f64(read(client, 8, 4)) == pytest.approx(START + 1500.0, abs=1e-6)


def test_weather_block(served):
    cfg, _, _, client, _ = served
    regs = read(client, 100, 10)
    wind, direction, dni, temp, pressure = (f32(regs[k:k + 2]) for k in range(0, 10, 2))
    assert 0.0 <= wind < 15.0
    assert 0.0 <= direction < 360.0
    elev = float(sun_at_site(cfg.site, START).elevation_deg)
    assert elev > 40 and 600.0 < dni < 1100.0     # clear spring noon at 1270 m
    assert -20.0 < temp < 40.0
    assert pressure == pytest.approx(872.0, abs=15.0)


def test_move_and_hold_with_sequence_numbers(served):
    cfg, plant, _, client, source = served
    lo = np.array([a.stroke_range_mm for a in cfg.drives["tr20"].actuators])
    target = lo.mean(axis=1)
    command(client, 3, 3, 17, strokes=target)
    b = block(client, 3)
    assert b[3] == 17 and b[2] == 2 and b[4] == 0          # seq processed, MOVING, no fault
    source.t += 1.0                                          # 600 plant s: far longer than the travel
    b = block(client, 3)
    assert b[2] == 3                                          # HOLDING
    assert f32(b[10:12]) == pytest.approx(target[0], abs=1e-3)
    assert f32(b[12:14]) == pytest.approx(target[1], abs=1e-3)
    assert f32(b[6:8]) == pytest.approx(target[0], abs=1e-3)  # written command reads back
    assert 0.0 < f32(b[18:20]) <= 1.0                         # cleanliness
    # new strokes with the SAME sequence number: not acted on
    command(client, 3, 3, 17, strokes=target + 50.0)
    source.t += 1.0
    b = block(client, 3)
    assert b[2] == 3 and f32(b[10:12]) == pytest.approx(target[0], abs=1e-3)
    # the command fields and a new sequence number in one write
    base = R.heliostat_address(3)
    regs = [3, 18, 0, 0, 0, 0] + to_regs(target[0] - 40) + to_regs(target[1])
    assert not client.write_registers(base + 6, regs[6:], device_id=UNIT).isError()
    assert not client.write_registers(base, regs[:2], device_id=UNIT).isError()
    b = block(client, 3)
    assert b[3] == 18 and b[2] == 2


def test_move_takes_travel_time_then_settles(served):
    cfg, plant, _, client, source = served
    speed = plant.scenario.actuators.speed_mm_s
    start = np.array(plant.strokes_mm[5])
    goal = start + np.array([-100.0, 0.0])
    command(client, 5, 3, 1, strokes=goal)
    source.t += (100.0 / speed - 1.0) / RATE                  # 1 s before arrival
    assert block(client, 5)[2] == 2
    source.t += (1.0 + plant.scenario.actuators.settle_s + 0.5) / RATE
    assert block(client, 5)[2] == 3


def test_out_of_range_and_unknown_commands(served):
    cfg, _, _, client, _ = served
    command(client, 0, 3, 1, strokes=(5000.0, 100.0))
    b = block(client, 0)
    assert (b[2], b[3], b[4]) == (5, 1, 1)                    # FAULT, seq done, code 1
    command(client, 0, 9, 2)
    b = block(client, 0)
    assert b[3] == 2 and b[4] == 3                            # unknown command, code 3
    command(client, 0, 3, 3, strokes=(900.0, 800.0))          # a good command clears the fault
    b = block(client, 0)
    assert b[3] == 3 and b[4] == 0 and b[2] == 2


def test_track_uses_nominal_model_plus_corrections(served):
    cfg, plant, _, client, source = served
    corr = (4.0, -3.0)
    command(client, 7, 1, 1, corr=corr)
    source.t += 1.0
    b = block(client, 7)
    assert b[2] == 1 and b[3] == 1
    t = f64(read(client, 8, 4))
    from helicalib.geometry.heliostat import HeliostatModel
    nominal = HeliostatModel.from_config(cfg, [cfg.heliostats[7].id])
    sun = sun_at_site(cfg.site, t).vector_enu
    want = nominal.strokes_for_aim(sun, np.array(cfg.tower.receiver_aim_enu_m)).strokes_mm[0] + corr
    # the plant follows the sun step by step: within what the sun moves in one internal step
    assert f32(b[10:12]) == pytest.approx(want[0], abs=0.5)
    assert f32(b[12:14]) == pytest.approx(want[1], abs=0.5)


def test_stow_points_mirror_up(served):
    cfg, plant, _, client, source = served
    command(client, 2, 4, 1)
    assert block(client, 2)[2] == 2
    source.t += 1.0
    b = block(client, 2)
    assert b[2] == 4
    from helicalib.geometry.heliostat import HeliostatModel
    n = HeliostatModel.from_config(cfg, [cfg.heliostats[2].id]).normal(np.array([[f32(b[10:12]), f32(b[12:14])]]))
    assert n[0, 2] == pytest.approx(1.0, abs=1e-6)


def test_field_stow_refuses_commands_then_resume(served):
    cfg, plant, _, client, source = served
    assert not client.write_register(3, 1, device_id=UNIT).isError()
    assert read(client, 4, 1)[0] == 1                         # stowing
    command(client, 1, 3, 1, strokes=(900.0, 800.0))
    b = block(client, 1)
    assert b[3] == 1 and b[4] == 2                            # refused during stow
    source.t += 2.0
    assert read(client, 4, 1)[0] == 2                         # stowed
    assert all(block(client, i)[2] == 4 for i in range(39))
    assert not client.write_register(3, 2, device_id=UNIT).isError()
    assert read(client, 4, 1)[0] == 0
    source.t += 1.0
    assert block(client, 1)[2] == 1                           # tracking again


def test_wind_stow(served):
    cfg, plant, _, client, source = served
    goal = (float(to_unix_seconds("2026-03-21T05:10:00Z")) - START) / RATE + source.t
    while source.t < goal:                 # a day of plant time in 2-hour requests (each well within the timeout)
        source.t = min(goal, source.t + 7200.0 / RATE)
        read(client, 0, 1)
    wind = f32(read(client, 100, 2))
    assert wind == pytest.approx(20.0)
    assert read(client, 4, 1)[0] in (1, 2)
    command(client, 4, 1, 1, corr=(0.0, 0.0))
    assert block(client, 4)[4] == 2


def test_offline_heliostat_does_not_answer(served):
    cfg, _, _, client, _ = served
    command(client, 39, 3, 5, strokes=(900.0, 800.0))
    b = block(client, 39)
    assert b[2] == 6 and b[3] == 0


def test_read_only_writes_refused_whole(served):
    cfg, _, _, client, _ = served
    for address in (0, 1, 4, 8, 12, 100, 104, 1002, 1003, 1004, 1005, 1010, 1018, 1020):
        r = client.write_register(address, 1, device_id=UNIT)
        assert r.isError() and r.exception_code == 2, address
    # a write spanning writable command/sequence AND the read-only state register: nothing stored
    r = client.write_registers(1000 + 32 * 6, [3, 9, 0], device_id=UNIT)
    assert r.isError() and r.exception_code == 2
    b = block(client, 6)
    assert b[0] == 0 and b[1] == 0 and b[3] == 0


def test_out_of_map_read_refused(served):
    _, _, _, client, _ = served
    r = client.read_holding_registers(R.heliostat_address(40), count=1, device_id=UNIT)
    assert r.isError() and r.exception_code == 2
    r = client.read_holding_registers(R.heliostat_address(39), count=32, device_id=UNIT)
    assert not r.isError()


def test_camera_frame_png_with_capture_time(served):
    cfg, _, server, client, source = served
    source.t += 0.5
    t_plant = f64(read(client, 8, 4))
    for cam in cfg.cameras:
        with urllib.request.urlopen(server.camera_url(cam.id), timeout=10) as resp:
            assert resp.status == 200
            assert resp.headers["Content-Type"] == "image/png"
            capture = float(resp.headers["X-Capture-Time"])
            body = resp.read()
        assert body[:8] == b"\x89PNG\r\n\x1a\n"
        img = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and img.ndim == 2
        assert img.shape == (cam.resolution_px[1], cam.resolution_px[0])
        assert capture == pytest.approx(t_plant, abs=1e-6)


def test_injected_camera_faults(served):
    cfg, _, server, _, _ = served
    url = server.camera_url("C1")
    server.faults.camera_503_probability = 1.0
    with pytest.raises(urllib.error.HTTPError) as exc:
        urllib.request.urlopen(url, timeout=10)
    assert exc.value.code == 503
    server.faults.camera_503_probability = 0.0
    server.faults.camera_truncate_probability = 1.0
    with pytest.raises(http.client.IncompleteRead):
        with urllib.request.urlopen(url, timeout=10) as resp:
            resp.read()


def test_injected_modbus_drop(served):
    _, _, server, client, _ = served
    server.faults.modbus_drop_probability = 1.0
    try:
        r = client.read_holding_registers(0, count=1, device_id=UNIT)
        failed = r.isError()
    except Exception:  # noqa: BLE001 - a dropped connection may surface as an exception
        failed = True
    assert failed
    server.faults.modbus_drop_probability = 0.0
    client.close()
    assert client.connect()
    assert read(client, 0, 1) == [1]


def test_wrong_unit_is_not_answered_as_unit_1(served):
    _, _, _, client, _ = served
    r = client.read_holding_registers(0, count=1, device_id=7)
    assert r.isError()
