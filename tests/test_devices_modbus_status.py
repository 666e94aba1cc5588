"""Heliostat status values the register map cannot vouch for, over real loopback sockets: a fault
code the map does not list, and a stroke that is not a finite number. Each is one PlantError line
naming the register's address (not its offset in the block) and the heliostat.
"""

from __future__ import annotations

import math
import struct

import pytest
from test_devices_modbus_maps import BASE, STRIDE, UNIT, regs, serve, variant

from helicalib.devices.modbus import ModbusPlant
from helicalib.devices.registers import HeliostatState
from helicalib.errors import PlantError


def _fault_one_is_range(doc):
    """A plant that reports a demand out of range as fault 1 (helicalib's own code for it)."""
    doc["heliostats"]["status"]["fault"]["values"] = {0: "none", 1: "stroke_out_of_range", 12: "refused_during_stow",
                                                      13: "unknown_command"}


def test_a_fault_code_the_map_does_not_list_is_refused_not_passed_on(tmp_path):
    with serve(variant(tmp_path, "fault-one", _fault_one_is_range)) as (cfg, plant, server, raw, mp, source):
        i = 2
        b = BASE + STRIDE * i
        demand = list(struct.unpack(">HH", struct.pack(">i", 1_600_000)))[::-1]       # 16 000.00 mm: out of range
        assert not raw.write_registers(b + 1, demand, device_id=UNIT).isError()
        assert not raw.write_register(b, 20, device_id=UNIT).isError()
        assert not raw.write_register(b + 9, 1, device_id=UNIT).isError()
        assert regs(raw, "input", b, 2) == [1 << 4, 1]                               # fault bit, plant code 1
        assert mp.status(i).fault == 1                                               # the map that lists it
        endpoint = cfg.plant.scs.model_copy(update={"port": server.modbus_port})
        with ModbusPlant(endpoint, None, 40, register_map="scs-b", sleep=lambda _s: None) as scs_b:
            with pytest.raises(PlantError) as err:
                scs_b.status(i)                    # SCS-B lists 11 for it: an unlisted 1 is no code of helicalib's
            msg = str(err.value)
            assert "\n" not in msg and "heliostat 2" in msg
            assert msg.endswith(f"fault code 1 at input {b + 1} (heliostats.status.fault) is not in the register "
                                "map scs-b ([0, 11, 12, 13])")
            assert scs_b.status(3).state == HeliostatState.TRACKING                 # other heliostats read on


def _float_strokes(doc):
    for q in doc["heliostats"]["status"]["strokes_mm"]:
        q.update(type="f32", scale=1.0)


def test_a_stroke_that_is_not_a_number_names_its_address_and_heliostat(tmp_path):
    with serve(variant(tmp_path, "f32", _float_strokes)) as (cfg, plant, server, raw, mp, source):
        i = 3
        plant.strokes_mm[i, 1] = math.nan
        with pytest.raises(PlantError) as err:
            mp.status(i)
        msg = str(err.value)
        assert "\n" not in msg and "heliostat 3 (H0004)" in msg
        assert f"nan at input {BASE + STRIDE * i + 4} (heliostats.status.strokes_mm[1]): not a finite number" in msg
