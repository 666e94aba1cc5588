"""Register maps with several unit ids (``heliostats.per_unit``): a field beyond one unit's 65536
registers, addressed over one connection. The reach and the checks of the map, then the simulated
plant served in the shipped ``plant-interface-1-units`` layout (shrunk to 4 heliostats per unit so
the demo field spans units 1..6) over real loopback sockets, read and commanded by
:class:`ModbusPlant` and by a plain pymodbus client that names the unit itself.

Plant time comes from a fake monotonic source; nothing waits on the wall clock.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import yaml

from helicalib.devices.registers import HeliostatState
from helicalib.devices.regmap import MAPS_DIR, load_register_map
from helicalib.errors import ConfigError, PlantError
from test_devices_modbus_maps import serve

FIELD = Path(__file__).resolve().parents[1] / "field_config" / "demo_north.yaml"
PER_UNIT = 4


def units_map(tmp_path, per_unit=PER_UNIT, **edit) -> str:
    doc = yaml.safe_load((MAPS_DIR / "plant-interface-1-units.yaml").read_text())
    doc["name"] = "few-per-unit"
    doc["heliostats"]["per_unit"] = per_unit
    doc["heliostats"].update(edit)
    path = tmp_path / "few-per-unit.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def test_the_shipped_units_map_reaches_ten_thousand_heliostats_where_one_unit_stops_at_2016():
    one, units = load_register_map("plant-interface-1"), load_register_map("plant-interface-1-units")
    one.check_count(2016)
    with pytest.raises(ConfigError, match=r"plant-interface-1.yaml: heliostats.stride: the holding blocks of 2017 "
                                          r"heliostats end at address 65543, beyond 65535"):
        one.check_count(2017)
    units.check_count(10_000)
    assert [units.unit_step(i) for i in (0, 1999, 2000, 9999)] == [0, 0, 1, 4]
    assert [units.block_address(i) for i in (0, 1999, 2000, 9999)] == [1000, 1000 + 32 * 1999, 1000, 1000 + 32 * 1999]
    assert units.unit_steps(10_000) == 5 and one.unit_steps(10_000) == 1 and one.unit_step(5000) == 0


def test_a_units_map_is_refused_with_addresses_beyond_247_units_or_a_unit_too_full(tmp_path):
    with pytest.raises(ConfigError, match=r"few-per-unit.yaml: heliostats.per_unit: blocks by unit id need base and "
                                          r"stride, not addresses"):
        load_register_map(units_map(tmp_path, base=None, stride=None, addresses=[1000, 1040]))
    m = load_register_map(units_map(tmp_path, per_unit=10))
    m.check_count(2470)
    with pytest.raises(ConfigError, match=r"heliostats.per_unit: 2471 heliostats at 10 per unit need 248 unit ids, "
                                          r"more than Modbus's 247"):
        m.check_count(2471)
    with pytest.raises(ConfigError, match=r"heliostats.stride: the holding blocks of 3000 heliostats end at address "
                                          r"65991, beyond 65535"):
        load_register_map(units_map(tmp_path, per_unit=2031)).check_count(3000)
    # from the SCS endpoint's own unit id: 10⁴ heliostats on 5 unit ids from unit 243 end at 247
    units = load_register_map("plant-interface-1-units")
    units.check_count(10_000, first_unit=243)
    with pytest.raises(ConfigError, match=r"^plant.scs.unit: 10000 heliostats at 2000 a unit id \(register map .*"
                                          r"plant-interface-1-units.yaml\) from unit 244 reach unit 248, beyond "
                                          r"Modbus's 247$"):
        units.check_count(10_000, first_unit=244)


def f32(regs) -> float:
    return struct.unpack(">f", b"".join(int(r).to_bytes(2, "big") for r in regs))[0]


def test_each_unit_answers_its_own_block_of_heliostats_and_commands_reach_only_theirs(tmp_path):
    with serve(units_map(tmp_path), field=FIELD) as (cfg, plant, server, raw, mp, source):
        n = len(cfg.heliostats)
        assert cfg.plant.scs.unit == 1 and server.units == set(range(1, 1 + -(-n // PER_UNIT)))
        # a plain client: unit 3's first block is heliostat 8, unit 1's is heliostat 0; the count on every unit
        for unit, i in ((1, 0), (3, 8), (3, 11)):
            r = raw.read_holding_registers(1000 + 32 * (i % PER_UNIT) + 10, count=2, device_id=unit)
            assert not r.isError() and f32(r.registers) == pytest.approx(plant.strokes_mm[i, 0], abs=1e-3)
        assert raw.read_holding_registers(1, count=1, device_id=4).registers == [n]
        # a block beyond the unit's heliostats (unit 1 holds 4) is refused, as an address past the field
        assert raw.read_holding_registers(1000 + 32 * PER_UNIT, count=2, device_id=1).isError()
        # the client: every heliostat's status is its own, across the units
        for i in range(n):
            assert mp.status(i).strokes_mm == pytest.approx(tuple(plant.strokes_mm[i]), abs=1e-3)
        # a move to heliostat 9 (unit 3, local block 1) moves it alone, not heliostat 1 or 5 (block 1 of units 1, 2)
        before = plant.strokes_mm.copy()
        target = before[9] + np.array([6.0, -4.0])
        token = mp.move_to(9, target)
        source.t += 0.5
        st = mp.status(9)
        assert st.sequence_done == token and st.state in (HeliostatState.MOVING, HeliostatState.HOLDING)
        for _ in range(20):
            source.t += 0.1
            if mp.status(9).state == HeliostatState.HOLDING:
                break
        assert mp.status(9).strokes_mm == pytest.approx(tuple(target), abs=1e-3)
        for other in (1, 5, 13):
            assert mp.status(other).state == HeliostatState.TRACKING and mp.status(other).sequence_done == 0
        # a track command with corrections lands in heliostat 9's own correction registers (unit 3)
        mp.track(9, [0.5, -0.25])
        r = raw.read_holding_registers(1000 + 32 * 1 + 14, count=4, device_id=3)
        assert (f32(r.registers[:2]), f32(r.registers[2:])) == (0.5, -0.25)
        r = raw.read_holding_registers(1000 + 32 * 1 + 14, count=4, device_id=1)
        assert (f32(r.registers[:2]), f32(r.registers[2:])) == (0.0, 0.0)


def test_a_failure_on_another_unit_names_the_unit_the_register_and_the_heliostat(tmp_path):
    with serve(units_map(tmp_path), field=FIELD) as (cfg, plant, server, raw, mp, source):
        server.units.discard(3)           # unit 3's gateway path is gone: the plant refuses it
        with pytest.raises(PlantError) as err:
            mp.status(9)
        line = str(err.value)
        assert "\n" not in line and "unit 3 address 1034" in line and cfg.heliostats[9].id in line
        assert mp.status(4).strokes_mm == pytest.approx(tuple(plant.strokes_mm[4]), abs=1e-3)


def test_the_cleanliness_of_many_heliostats_is_read_through_neighbouring_blocks_on_each_unit(tmp_path):
    with serve(units_map(tmp_path), field=FIELD) as (cfg, plant, server, raw, mp, source):
        rows = [0, 1, 2, 3, 9, 10, 13, 21]                      # units 1, 3, 4 and 6 (4 heliostats per unit)
        mp.heliostat_count()                                     # (read once per client, checked)
        reads = []
        read = mp.scs.read
        mp.scs.read = lambda *a, **kw: reads.append(kw.get("unit", 1)) or read(*a, **kw)
        got = mp.cleanliness_many(rows)
        assert sorted(reads) == [1, 3, 4, 6]                     # one request per unit, not one per heliostat
        mp.scs.read = read
        assert got.tolist() == pytest.approx([mp.status(i).cleanliness for i in rows], abs=1e-6)
        assert got.tolist() == pytest.approx([plant.cleanliness_of(i) for i in rows], abs=1e-6)
        server.units.discard(3)                                  # a unit that does not answer: NaN, the others read
        got = mp.cleanliness_many(rows)
        assert np.isnan(got[4:6]).all() and np.isfinite(np.delete(got, [4, 5])).all()
        beyond = mp.cleanliness_many([0, len(cfg.heliostats), 1])  # a heliostat the plant has not: NaN, as status
        assert np.isnan(beyond[1]) and np.isfinite(beyond[[0, 2]]).all()
