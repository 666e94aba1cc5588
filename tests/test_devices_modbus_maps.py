"""Plants of other register maps, over real loopback sockets: the simulated plant served in a map's
layout (pymodbus server) and read and commanded by :class:`ModbusPlant` and by a plain pymodbus
client whose registers the test decodes itself with ``struct``.

Plant time comes from a fake monotonic source the test moves; nothing waits on the wall clock.
"""

from __future__ import annotations

import contextlib
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from pymodbus.client import ModbusTcpClient

from helicalib.config import load_field_config
from helicalib.devices.modbus import ModbusPlant
from helicalib.devices.registers import FieldCommand, HeliostatState
from helicalib.devices.regmap import MAPS_DIR, load_register_map
from helicalib.errors import PlantError
from helicalib.geometry.sun import to_unix_seconds
from helicalib.sim.clock import RateClock
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario
from helicalib.sim.server import PlantServer

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))
FIELD = Path(__file__).resolve().parents[1] / "field_config" / "scs_b_demo.yaml"
UNIT = 17
BASE, STRIDE = 10000, 40
FMT = {"u16": ">H", "i16": ">h", "u32": ">I", "i32": ">i", "f32": ">f", "f64": ">d"}


class FakeSource:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def words_to(kind: str, regs, word: str, byte: str) -> float:
    """Independent decoding of ``regs`` as ``kind`` (not the package's codec)."""
    ws = [int(r).to_bytes(2, "big") for r in regs]
    if byte == "little":
        ws = [w[::-1] for w in ws]
    if word == "low_first":
        ws = ws[::-1]
    return struct.unpack(FMT[kind], b"".join(ws))[0]


def variant(tmp_path, name: str, edit) -> str:
    doc = yaml.safe_load((MAPS_DIR / "scs-b.yaml").read_text())
    doc["name"] = name
    edit(doc)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


@contextlib.contextmanager
def serve(register_map, scenario=None, field=FIELD):
    """The simulated plant of ``field`` served in ``register_map``'s layout: (cfg, plant, server, a
    plain pymodbus client, the :class:`ModbusPlant`, the fake time source)."""
    cfg = load_field_config(field)
    source = FakeSource()
    plant = SimulatedPlant(cfg, scenario, start_s=START, rate=600.0)
    rmap = load_register_map(register_map)
    server = PlantServer(plant, RateClock(START, 600.0, source), modbus_port=0, camera_port=0,
                         register_map=rmap).start()
    raw = ModbusTcpClient("127.0.0.1", port=server.modbus_port, timeout=5, retries=0)
    assert raw.connect()
    limits = np.array([[a.stroke_range_mm for a in cfg.drive_of(h.id).actuators] for h in cfg.heliostats])
    endpoint = cfg.plant.scs.model_copy(update={"port": server.modbus_port})
    mp = ModbusPlant(endpoint, None, len(cfg.heliostats), armed=True, heliostat_ids=[h.id for h in cfg.heliostats],
                     stroke_limits_mm=limits, register_map=rmap, sleep=lambda _s: None)
    try:
        yield cfg, plant, server, raw, mp, source
    finally:
        mp.close()
        raw.close()
        server.stop()


def regs(raw, table, address, count):
    fn = raw.read_input_registers if table == "input" else raw.read_holding_registers
    r = fn(address, count=count, device_id=UNIT)
    assert not r.isError(), (table, address, count, r)
    return r.registers


def _high_little(doc):
    doc["defaults"].update(word_order="high_first", byte_order="little")


def _floats(doc):
    h = doc["heliostats"]
    for section in ("command", "status"):
        for key in ("strokes_mm", "corrections_mm") if section == "command" else ("strokes_mm",):
            for q in h[section][key]:
                q.update(type="f32", scale=1.0)
    doc["plant"]["clock"]["time"] = {"address": 30, "type": "f64", "unit": "s"}
    doc["weather"]["temperature_c"].update(type="f32", scale=1.0, address=106)


def _doubles(doc):
    h = doc["heliostats"]
    h["command"]["strokes_mm"] = [{"offset": 1, "type": "f64"}, {"offset": 10, "type": "f64"}]
    h["command"]["corrections_mm"] = [{"offset": 14, "type": "i16", "scale": 0.01}, {"offset": 15, "type": "i16", "scale": 0.01}]
    h["status"]["strokes_mm"] = [{"offset": 10, "type": "f64"}, {"offset": 14, "type": "f64"}]
    h["status"]["cleanliness"]["offset"] = 6
    h["command"]["handshake"]["done"]["offset"] = 7


VARIANTS = {  # name: (edit, stroke type and resolution, word order, byte order)
    "scs-b": (None, ("i32", 0.01), "low_first", "big"),
    "high-little": (_high_little, ("i32", 0.01), "high_first", "little"),
    "floats": (_floats, ("f32", 1e-3), "low_first", "big"),
    "doubles": (_doubles, ("f64", 1e-9), "low_first", "big"),
}


@pytest.mark.parametrize("name", list(VARIANTS))
def test_every_encoding_reads_and_commands_over_the_wire(tmp_path, name):
    edit, (kind, resolution), word, byte = VARIANTS[name]
    rmap = "scs-b" if edit is None else variant(tmp_path, name, edit)
    with serve(rmap) as (cfg, plant, server, raw, mp, source):
        m = server.registers.map
        sq = m.q["heliostats.status.strokes_mm[0]"]
        i = 3
        base = m.block_address(i)
        got = words_to(kind, regs(raw, sq.table, base + sq.start, sq.width), word, byte) * sq.scale
        assert got == pytest.approx(plant.strokes_mm[i, 0], abs=max(resolution, 1e-4 * plant.strokes_mm[i, 0]))
        st = mp.status(i)
        assert st.strokes_mm == pytest.approx(tuple(plant.strokes_mm[i]), abs=max(resolution, 1e-3))
        assert st.state == HeliostatState.TRACKING and st.cleanliness == pytest.approx(plant.cleanliness_of(i), abs=1e-3)
        w = mp.weather()
        truth = plant.weather()
        assert w.temperature_c == pytest.approx(truth.temperature_c, abs=0.05 + 1e-5)
        assert w.wind_ms == pytest.approx(truth.wind_ms, abs=0.005 + 1e-9)
        t, rate = mp.plant_time()
        assert t == pytest.approx(plant.t_s, abs=1e-3) and rate == 600.0
        # move: the demand lands in the registers as the map encodes it, and the plant holds there
        target = np.array([812.3456, 654.321])
        token = mp.move_to(i, target)
        cq = m.q["heliostats.command.strokes_mm[0]"]
        sent = words_to(kind, regs(raw, "holding", base + cq.start, cq.width), word, byte) * cq.scale
        assert sent == pytest.approx(target[0], abs=resolution / 2 + 1e-9)
        source.t += 30
        st = mp.status(i)
        assert st.sequence_done == token and st.state == HeliostatState.HOLDING
        assert np.allclose(plant.goal_cmd_mm[i], target, atol=resolution / 2 + 1e-9)
        # negative corrections (signed types) reach the plant
        token = mp.track(i, np.array([-1.23, 0.5]))
        assert np.allclose(plant.corrections_mm[i], [-1.23, 0.5], atol=1e-6)
        assert mp.status(i).sequence_done == token


def test_status_bits_and_fault_codes_on_the_wire():
    scenario = parse_scenario({"faults": {"offline": ["H0040"]}})
    with serve("scs-b", scenario) as (cfg, plant, server, raw, mp, source):
        status = lambda i: regs(raw, "input", BASE + STRIDE * i, 8)  # noqa: E731
        assert status(0)[0] == 1 << 0 and status(39)[0] == 1 << 5          # tracking; offline
        assert mp.status(39).state == HeliostatState.OFFLINE
        mp.move_to(0, [900.0, 800.0])
        assert status(0)[0] == 1 << 1                                      # moving
        source.t += 30
        assert status(0)[0] == 1 << 2                                      # in position
        mp.stow(1)
        source.t += 60
        assert status(1)[0] == 1 << 3 and mp.status(1).state == HeliostatState.STOWED
        # a demand out of the actuator's range, sent around the client's guard: bit 4 and fault 11
        b = BASE + STRIDE * 2
        demand = list(struct.unpack(">HH", struct.pack(">i", 1_600_000)))[::-1]              # 16 000.00 mm, CDAB
        assert not raw.write_registers(b + 1, demand, device_id=UNIT).isError()
        assert not raw.write_register(b, 20, device_id=UNIT).isError()
        assert not raw.write_register(b + 9, 1, device_id=UNIT).isError()
        s = status(2)
        assert s[0] == 1 << 4 and s[1] == 11
        st = mp.status(2)
        assert st.state == HeliostatState.FAULT and st.fault == 1                        # helicalib's stroke_out_of_range
        # an unknown mode: fault 13
        assert not raw.write_register(b, 77, device_id=UNIT).isError()
        assert not raw.write_register(b + 9, 1, device_id=UNIT).isError()
        assert status(2)[1] == 13 and mp.status(2).fault == 3


def test_execute_handshake_counts_commands_and_sets_execute_back():
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        b = BASE + STRIDE * 4
        before = regs(raw, "input", b + 7, 1)[0]
        token = mp.move_to(4, [700.0, 600.0])
        assert token == (before + 1) & 0xFFFF
        assert regs(raw, "holding", b + 9, 1) == [0]                        # the SCS took it
        assert regs(raw, "input", b + 7, 1) == [token] and mp.status(4).sequence_done == token
        assert regs(raw, "holding", b, 1) == [20]
        plant.sequence_done[4] = 65535                                      # the counter wraps at 65536
        assert mp.stow(4) == 0 and regs(raw, "input", b + 7, 1) == [0]


def test_an_execute_still_set_refuses_the_next_command(monkeypatch):
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        monkeypatch.setattr(server.registers, "_act", lambda i, path: None)  # a plant busy with the last command
        b = BASE + STRIDE * 3
        assert not raw.write_register(b + 9, 1, device_id=UNIT).isError()
        with pytest.raises(PlantError) as err:
            mp.move_to(3, [700.0, 600.0])
        msg = str(err.value)
        assert "\n" not in msg and f"holding {b + 9} (heliostats.command.handshake.execute)" in msg
        assert "heliostat 3 (H0004)" in msg and "has not taken the last command" in msg
        assert regs(raw, "holding", b, 5) == [0, 0, 0, 0, 0]                # nothing of the command was written


def test_tables_reads_and_writes_outside_the_map_are_refused():
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        def refused(r):
            return r.isError() and r.exception_code == 2

        assert refused(raw.read_input_registers(4, count=1, device_id=UNIT))           # between clock and count
        assert refused(raw.read_input_registers(0, count=11, device_id=UNIT))          # through the gap
        assert len(regs(raw, "input", 0, 4)) == 4 and regs(raw, "input", 10, 1) == [40]
        assert refused(raw.read_input_registers(BASE + 8, count=1, device_id=UNIT))    # past the status block
        assert refused(raw.read_holding_registers(BASE + 10, count=1, device_id=UNIT))  # past the command block
        assert refused(raw.read_input_registers(BASE + STRIDE * 40, count=1, device_id=UNIT))  # no heliostat 41
        assert refused(raw.read_holding_registers(10, count=1, device_id=UNIT))         # the count is an input register
        assert refused(raw.write_register(10, 5, device_id=UNIT))
        assert refused(raw.write_registers(BASE + 8, [1, 1, 1], device_id=UNIT))       # spans past the block: refused whole
        assert regs(raw, "holding", BASE + 8, 2) == [0, 0]
        assert not raw.write_registers(BASE + 1, [1, 0], device_id=UNIT).isError()     # a demand, no execute: stored
        assert regs(raw, "holding", BASE, 10)[:3] == [0, 1, 0] and plant.sequence_done[0] == 0
        # field command (holding 20) and field state (input 20): one address, two tables
        mp.field_command(FieldCommand.STOW_ALL)
        assert regs(raw, "holding", 20, 1) == [1] and regs(raw, "input", 20, 1) == [1]   # stowing
        source.t += 120
        assert regs(raw, "input", 20, 1) == [2] and mp.field_state().name == "STOWED"
        mp.field_command(FieldCommand.RESUME_TRACKING)
        assert regs(raw, "input", 20, 1) == [0] and not plant.field_stow


def test_strokes_round_to_the_registers_but_never_out_of_range():
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        mp.guard.stroke_limits_mm[0] = [[0.005, 1000.0], [0.0, 999.995]]
        mp.move_to(0, [0.005, 999.995])                  # 0.00 and 1000.00 would lie outside
        r = regs(raw, "holding", BASE + 1, 4)
        assert words_to("i32", r[0:2], "low_first", "big") == 1 and words_to("i32", r[2:4], "low_first", "big") == 99999
        with pytest.raises(PlantError, match=r"outside its stroke ranges"):
            mp.move_to(0, [0.004, 500.0])                # the range check comes first


def test_a_field_command_in_a_coil(tmp_path):
    def coil(doc):
        doc["plant"]["field_command"] = {"table": "coil", "address": 0, "values": {"stow": 1, "resume": 0}}

    with serve(variant(tmp_path, "coil", coil)) as (cfg, plant, server, raw, mp, source):
        mp.field_command(FieldCommand.STOW_ALL)
        assert plant.field_stow and raw.read_coils(0, count=1, device_id=UNIT).bits[0]
        mp.field_command(FieldCommand.RESUME_TRACKING)
        assert not plant.field_stow and not raw.read_coils(0, count=1, device_id=UNIT).bits[0]
        r = raw.write_coil(1, True, device_id=UNIT)
        assert r.isError() and r.exception_code == 2


def test_a_short_campaign_against_an_scs_b_plant():
    """Move, hold, track, stow, field stow and release through the client, as a visit does."""
    with serve("scs-b") as (cfg, plant, server, raw, mp, source):
        assert mp.heliostat_count() == 40 and mp.interface_version() is None
        for i in (5, 6, 7):
            mid = np.array([a.stroke_range_mm for a in cfg.drive_of(cfg.heliostats[i].id).actuators]).mean(axis=1)
            token = mp.move_to(i, mid)
            source.t += 20
            st = mp.status(i)
            assert (st.state, st.sequence_done) == (HeliostatState.HOLDING, token)
            assert st.strokes_mm == pytest.approx(tuple(mid), abs=0.02)
            mp.track(i, np.array([0.2, -0.1]))
        source.t += 20
        assert [mp.status(i).state for i in (5, 6, 7)] == [HeliostatState.TRACKING] * 3
        mp.field_command(FieldCommand.STOW_ALL)
        with pytest.raises(PlantError, match="stowed for wind"):
            mp.move_to(5, [700.0, 600.0])
        source.t += 120
        assert mp.status(5).state == HeliostatState.STOWED
        mp.field_command(FieldCommand.RESUME_TRACKING)
        source.t += 120
        assert mp.status(5).state == HeliostatState.TRACKING and mp.field_state().name == "TRACKING"


def test_the_client_takes_the_field_configs_map_or_the_override(tmp_path):
    cfg = load_field_config(FIELD)
    assert ModbusPlant.from_config(cfg).map.name == "scs-b"
    assert ModbusPlant.from_config(cfg, register_map="plant-interface-1").map.name == "plant-interface-1"
    text = FIELD.read_text().replace("register_map: scs-b", "register_map: maps/scs-b.yaml")
    (tmp_path / "maps").symlink_to(MAPS_DIR)
    (tmp_path / "field.yaml").write_text(text)
    assert ModbusPlant.from_config(load_field_config(tmp_path / "field.yaml")).map.source.endswith("maps/scs-b.yaml")


def test_sim_plant_refuses_a_bad_register_map_in_one_line(tmp_path, capsys):
    from helicalib.cli import main

    assert main(["sim-plant", str(FIELD), "--register-map", "scs-c", "--port", "0", "--camera-port", "0"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "register map 'scs-c': no shipped map of that name" in err[0]
    bad = variant(tmp_path, "bad", lambda doc: doc["heliostats"].update(stride=4))
    assert main(["sim-plant", str(FIELD), "--register-map", bad, "--port", "0", "--camera-port", "0"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.yaml: heliostats.stride: 4 is smaller than the block's extent" in err[0]


def test_an_explicit_block_address_table(tmp_path):
    starts = [20000 + 16 * (39 - i) for i in range(40)]   # the plant lists its heliostats backwards

    def table(doc):
        h = doc["heliostats"]
        del h["base"], h["stride"]
        h["addresses"] = starts

    with serve(variant(tmp_path, "table", table)) as (cfg, plant, server, raw, mp, source):
        assert regs(raw, "input", starts[3], 8)[0] == 1                      # tracking
        token = mp.move_to(3, [750.0, 650.0])
        assert regs(raw, "holding", starts[3], 1) == [20] and regs(raw, "input", starts[3] + 7, 1) == [token]
        source.t += 30
        assert mp.status(3).state == HeliostatState.HOLDING and plant.state[3] == HeliostatState.HOLDING
        assert plant.state[36] == HeliostatState.TRACKING                   # the block next to it is another heliostat
        r = raw.read_input_registers(starts[0] + 8, count=1, device_id=UNIT)  # between two blocks
        assert r.isError() and r.exception_code == 2


def test_an_identity_register_that_does_not_match_refuses_the_plant(tmp_path):
    doc = yaml.safe_load((MAPS_DIR / "plant-interface-1.yaml").read_text())
    doc["identity"][0]["equals"] = 2
    (tmp_path / "v2.yaml").write_text(yaml.safe_dump(doc))
    cfg = load_field_config(FIELD)
    with serve("plant-interface-1") as (_cfg, plant, server, raw, mp, source):
        endpoint = cfg.plant.scs.model_copy(update={"port": server.modbus_port})
        with ModbusPlant(endpoint, None, 40, register_map=str(tmp_path / "v2.yaml"), sleep=lambda _s: None) as other:
            with pytest.raises(PlantError, match=r"interface version 1 at holding 0, the register map plant-interface-1 "
                                                 r"expects 2$"):
                other.heliostat_count()
        assert mp.interface_version() == 1 and mp.heliostat_count() == 40
