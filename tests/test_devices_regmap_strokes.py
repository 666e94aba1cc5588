"""Stroke demand registers and the drives' stroke ranges: a register that cannot hold a drive's whole
range is refused when the map meets the field config (one line naming the key and the drive), and
a float demand at the edge of the range is never encoded just outside it (f32 rounds 999.9 up).
"""

from __future__ import annotations

import dataclasses
import struct

import numpy as np
import pytest
from test_devices_modbus_maps import BASE, FIELD, regs, serve, variant, words_to

from helicalib.config import load_field_config
from helicalib.devices.modbus import ModbusPlant
from helicalib.devices.regcodec import decode, encode_raw, raw_within
from helicalib.devices.regmap import load_register_map, register_map_of
from helicalib.errors import ConfigError


def _u16_strokes(doc):
    doc["heliostats"]["command"]["strokes_mm"][1] = {"offset": 3, "type": "u16", "scale": 0.01, "unit": "mm"}


def test_a_stroke_register_too_small_for_the_drive_is_refused_with_the_field_config(tmp_path, capsys):
    cfg = load_field_config(FIELD)                       # drive tr20: actuator 2 strokes 0..1590 mm
    small = variant(tmp_path, "small", _u16_strokes)
    assert load_register_map(small).name == "small"      # alone, the map is well formed
    with pytest.raises(ConfigError) as err:
        register_map_of(cfg, small)
    assert str(err.value) == (f"{small}: heliostats.command.strokes_mm[1]: a u16 with scale 0.01 holds 0..655.35 mm, "
                              "drive tr20's actuator 2 strokes 0..1590 mm")
    with pytest.raises(ConfigError, match="strokes_mm\\[1\\]: a u16 with scale 0.01"):
        ModbusPlant.from_config(cfg, register_map=small)
    from helicalib.cli import main

    assert main(["sim-plant", str(FIELD), "--register-map", small, "--port", "0", "--camera-port", "0"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "drive tr20's actuator 2 strokes 0..1590 mm" in err[0]
    wide = variant(tmp_path, "wide", lambda d: d["heliostats"]["command"]["strokes_mm"][1].update(
        type="u16", scale=0.1, value_offset=-100.0))     # -100..6453.5 mm holds 0..1590
    assert register_map_of(cfg, wide).name == "wide"


@pytest.mark.parametrize("kind, value, lo, hi", [
    ("f32", 999.9, 0.0, 999.9),        # f32(999.9) = 999.9000244: one step down
    ("f32", 612.3, 612.3, 900.0),      # f32(612.3) = 612.2999878: one step up
    ("f32", 0.1, -5.0, 0.1),
    ("f64", 0.3, 0.0, 0.3),
])
def test_float_demands_at_the_edge_stay_inside(kind, value, lo, hi):
    m = load_register_map("plant-interface-1")
    q = m.q["heliostats.command.strokes_mm[0]"]
    q = q if kind == "f32" else dataclasses.replace(q, type="f64", width=4)
    got = decode(q, encode_raw(q, raw_within(q, value, lo, hi)))
    assert lo <= got <= hi and got == pytest.approx(value, rel=1e-6)


def test_a_scaled_f32_demand_steps_inside_too():
    q = load_register_map("plant-interface-1").q["heliostats.command.strokes_mm[0]"]
    q = dataclasses.replace(q, scale=0.1)         # tenths of mm in an f32
    for hi in (999.9, 1234.57, 77.77):
        got = decode(q, encode_raw(q, raw_within(q, hi, 0.0, hi)))
        assert got <= hi and got == pytest.approx(hi, rel=1e-6)


def _f32_demands(doc):
    for q in doc["heliostats"]["command"]["strokes_mm"]:
        q.update(type="f32", scale=1.0)


def test_f32_strokes_touching_the_range_land_inside_over_the_wire(tmp_path):
    with serve(variant(tmp_path, "f32", _f32_demands)) as (cfg, plant, server, raw, mp, source):
        mp.guard.stroke_limits_mm[0] = [[612.3, 999.9], [0.1, 800.0]]
        mp.move_to(0, [999.9, 0.1])
        r = regs(raw, "holding", BASE + 1, 4)
        a1, a2 = words_to("f32", r[0:2], "low_first", "big"), words_to("f32", r[2:4], "low_first", "big")
        assert a1 <= 999.9 and a1 == pytest.approx(999.9, abs=1e-4)
        assert a2 >= 0.1 and a2 == pytest.approx(0.1, abs=1e-6)
        mp.move_to(0, [612.3, 800.0])
        a1 = words_to("f32", regs(raw, "holding", BASE + 1, 2), "low_first", "big")
        assert a1 >= 612.3 and struct.pack(">f", a1) != struct.pack(">f", 612.3)   # not the nearest f32: inside
        assert np.isclose(a1, 612.3, atol=1e-4)
