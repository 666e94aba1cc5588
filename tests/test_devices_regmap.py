"""Register maps as data: the shipped maps against their documents, the codec against an
independent encoding with ``struct``, and every refused map with its one-line message."""

from __future__ import annotations

import copy
import struct

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.devices import registers as R
from helicalib.devices.regcodec import decode, encode, plan_reads, state_name, state_raw
from helicalib.devices.regmap import MAPS_DIR, default_register_map, load_register_map, parse_register_map, shipped_maps
from helicalib.devices.regschema import Q
from helicalib.errors import ConfigError

H = "heliostats."


def test_default_map_reproduces_plant_interface_1():
    m = default_register_map()
    q = m.q
    assert m.name == "plant-interface-1" and load_register_map(None) is m
    assert (q["identity[0]"].start, q["identity[0]"].equals) == (R.REG_VERSION, R.INTERFACE_VERSION)
    plant_wide = {"plant.heliostat_count": (R.REG_HELIOSTAT_COUNT, "u16"), "plant.target_count": (R.REG_TARGET_COUNT, "u16"),
                  "plant.field_command": (R.REG_FIELD_COMMAND, "u16"), "plant.field_state": (R.REG_FIELD_STATE, "u16"),
                  "plant.clock.time": (R.REG_PLANT_TIME, "f64"), "plant.clock.rate": (R.REG_PLANT_TIME_RATE, "f32"),
                  "weather.wind_ms": (R.REG_WIND_SPEED, "f32"), "weather.wind_direction_deg": (R.REG_WIND_DIRECTION, "f32"),
                  "weather.dni_wm2": (R.REG_DNI, "f32"), "weather.temperature_c": (R.REG_TEMPERATURE, "f32"),
                  "weather.pressure_hpa": (R.REG_PRESSURE, "f32")}
    for path, (address, kind) in plant_wide.items():
        assert (q[path].start, q[path].type, q[path].table, q[path].block) == (address, kind, "holding", False), path
    block = {"command.mode": R.OFF_COMMAND, "command.handshake.sequence": R.OFF_SEQUENCE, "status.state": R.OFF_STATE,
             "command.handshake.done": R.OFF_SEQUENCE_DONE, "status.fault": R.OFF_FAULT,
             "command.strokes_mm[0]": R.OFF_STROKE_CMD_1, "command.strokes_mm[1]": R.OFF_STROKE_CMD_2,
             "status.strokes_mm[0]": R.OFF_STROKE_ACT_1, "status.strokes_mm[1]": R.OFF_STROKE_ACT_2,
             "command.corrections_mm[0]": R.OFF_TRACK_CORR_1, "command.corrections_mm[1]": R.OFF_TRACK_CORR_2,
             "status.cleanliness": R.OFF_CLEANLINESS}
    for path, offset in block.items():
        assert (q[H + path].start, q[H + path].block, q[H + path].table) == (offset, True, "holding"), path
    assert [m.block_address(i) for i in (0, 1, 39)] == [R.heliostat_address(i) for i in (0, 1, 39)]
    writable_block = {r for x in q.values() if x.writable and x.block for r in x.registers}
    writable_plant = {r for x in q.values() if x.writable and not x.block for r in x.registers}
    assert writable_block == R.WRITABLE_HELIOSTAT_OFFSETS and writable_plant == R.WRITABLE_FIELD
    assert {v: k for k, v in q[H + "command.mode"].values.items()} == {c.value: c.name.lower() for c in R.HeliostatCommand}
    assert q[H + "status.state"].values == {s.value: s.name.lower() for s in R.HeliostatState}
    assert q[H + "status.fault"].values == {f.value: f.name.lower() for f in R.FaultCode}
    assert q["plant.field_state"].values == {f.value: f.name.lower() for f in R.FieldState}
    assert q["plant.field_command"].values == {"none": 0, "stow": 1, "resume": 2}
    assert m.doc.heliostats.command.handshake.kind == "sequence"
    for x in (123.456, -0.1, 1850.0):
        assert encode(q[H + "command.strokes_mm[0]"], x) == R.encode_f32(x) == list(struct.unpack(">HH", struct.pack(">f", x)))
    t = 1774000000.123
    assert encode(q["plant.clock.time"], t) == R.encode_f64(t)


def test_scs_b_map_reproduces_its_register_document():
    m = load_register_map("scs-b")
    q = m.q
    doc = {  # SCS_B_REGISTERS.md, release 3: path: (table, address or offset, type, scale)
        "plant.heliostat_count": ("input", 10, "u16", 1), "plant.field_state": ("input", 20, "u16", 1),
        "plant.field_command": ("holding", 20, "u16", 1), "plant.clock.rate": ("input", 3, "u16", 1),
        "weather.wind_ms": ("input", 100, "u16", 0.01), "weather.wind_direction_deg": ("input", 101, "u16", 0.1),
        "weather.dni_wm2": ("input", 102, "u16", 1), "weather.temperature_c": ("input", 103, "i16", 0.1),
        "weather.pressure_hpa": ("input", 104, "u16", 0.1),
        H + "command.mode": ("holding", 0, "u16", 1), H + "command.strokes_mm[0]": ("holding", 1, "i32", 0.01),
        H + "command.strokes_mm[1]": ("holding", 3, "i32", 0.01), H + "command.corrections_mm[0]": ("holding", 5, "i32", 0.01),
        H + "command.corrections_mm[1]": ("holding", 7, "i32", 0.01), H + "command.handshake.execute": ("holding", 9, "u16", 1),
        H + "status.state": ("input", 0, "u16", 1), H + "status.fault": ("input", 1, "u16", 1),
        H + "status.strokes_mm[0]": ("input", 2, "i32", 0.01), H + "status.strokes_mm[1]": ("input", 4, "i32", 0.01),
        H + "status.cleanliness": ("input", 6, "u16", 0.001), H + "command.handshake.done": ("input", 7, "u16", 1),
    }
    for path, want in doc.items():
        assert (q[path].table, q[path].start, q[path].type, q[path].scale) == want, path
        assert q[path].word_order == "low_first"
    assert [m.block_address(n - 1) for n in (1, 2, 40)] == [10000, 10040, 10000 + 40 * 39]
    assert q[H + "command.mode"].values == {"track": 10, "move": 20, "stow": 30}
    assert q[H + "status.state"].bits == {0: "tracking", 1: "moving", 2: "holding", 3: "stowed", 4: "fault", 5: "offline"}
    assert q[H + "status.fault"].values == {0: "none", 11: "stroke_out_of_range", 12: "refused_during_stow",
                                            13: "unknown_command"}
    assert q["plant.field_command"].values == {"stow": 1, "resume": 2}
    assert m.doc.heliostats.command.handshake.kind == "execute" and "identity[0]" not in q
    # u32 seconds (low word first) + u16 milliseconds
    t = 1774000000.25
    seconds = list(struct.unpack(">HH", struct.pack(">I", 1774000000)))[::-1]
    assert encode(q["plant.clock.time"], t) == [*seconds, 250]
    assert decode(q["plant.clock.time"], [*seconds, 250]) == pytest.approx(t, abs=1e-9)
    # i32 low word first, 0.01 mm
    assert encode(q[H + "command.strokes_mm[0]"], -12.34) == list(struct.unpack(">HH", struct.pack(">i", -1234)))[::-1]
    assert encode(q["weather.temperature_c"], -7.3) == list(struct.unpack(">H", struct.pack(">h", -73)))


def _q(kind, word="high_first", byte="big", scale=1.0, offset=0.0, table="holding"):
    from helicalib.devices.regschema import WIDTH

    return Q("x", table, kind, 0, WIDTH[kind], False, False, word, byte, scale, offset)


@pytest.mark.parametrize("word", ["high_first", "low_first"])
@pytest.mark.parametrize("byte", ["big", "little"])
@pytest.mark.parametrize("kind, value, fmt", [("u16", 51234, ">H"), ("i16", -1234, ">h"), ("u32", 3_000_000_000, ">I"),
                                              ("i32", -2_000_000_000, ">i"), ("f32", -1.5e-3, ">f"), ("f64", -1e300, ">d")])
def test_codec_against_struct(kind, value, fmt, word, byte):
    data = struct.pack(fmt, value)
    words = [data[k:k + 2] for k in range(0, len(data), 2)]
    if word == "low_first":
        words.reverse()
    if byte == "little":
        words = [w[::-1] for w in words]
    want = [int.from_bytes(w, "big") for w in words]
    q = _q(kind, word, byte)
    assert encode(q, value) == want
    assert decode(q, want) == pytest.approx(value, rel=1e-7)


def test_scaled_integers_round_and_refuse_what_does_not_fit():
    q = _q("i16", scale=0.1, offset=-40.0)
    assert encode(q, -52.3) == list(struct.unpack(">H", struct.pack(">h", -123)))
    assert decode(q, encode(q, -52.3)) == pytest.approx(-52.3)
    with pytest.raises(ValueError, match="does not fit a i16 with scale 0.1"):
        encode(q, 4000.0)
    assert decode(q, encode(q, 4000.0, clamp=True)) == pytest.approx(32767 * 0.1 - 40)
    with pytest.raises(ValueError, match="not a finite number"):
        encode(_q("u16"), float("nan"))


def test_status_bits_priority_and_enumerations():
    q = load_register_map("scs-b").q[H + "status.state"]
    assert state_name(q, 0) == "idle"
    assert state_name(q, 0b1) == "tracking" and state_name(q, 0b110) == "moving"
    assert state_name(q, 0b111111) == "fault" and state_name(q, 0b101000) == "offline"
    assert state_name(q, 0b1001) == "stowed" and state_name(q, 0b1000000) == "idle"   # an unmapped bit alone
    assert [state_raw(q, n) for n in ("idle", "tracking", "holding", "offline")] == [0, 1, 4, 32]
    e = default_register_map().q[H + "status.state"]
    assert state_name(e, 3) == "holding" and state_name(e, 9) is None and state_raw(e, "fault") == 5


def test_plan_reads_groups_contiguous_registers_and_reads_through_readable_gaps():
    regs = [("holding", a) for a in (2, 3, 4, 10, 11, 18, 19)] + [("input", 7), ("input", 0)]
    assert plan_reads(regs, lambda t, a: t == "holding") == [("holding", 2, 18), ("input", 0, 1), ("input", 7, 1)]
    assert plan_reads(regs, lambda t, a: False) == [("holding", 2, 3), ("holding", 10, 2), ("holding", 18, 2),
                                                   ("input", 0, 1), ("input", 7, 1)]
    assert plan_reads([("holding", 0), ("holding", 200)], lambda t, a: True) == [("holding", 0, 1), ("holding", 200, 1)]


@settings(max_examples=150, deadline=None)
@given(kind=st.sampled_from(["u16", "i16", "u32", "i32", "f32", "f64"]), word=st.sampled_from(["high_first", "low_first"]),
       byte=st.sampled_from(["big", "little"]), scale=st.sampled_from([1.0, 0.01, 0.1, 0.001, 2.5, -0.5]),
       offset=st.sampled_from([0.0, -40.0, 1000.0]), u=st.floats(0, 1))
def test_codec_round_trip(kind, word, byte, scale, offset, u):
    from helicalib.devices.regschema import INT_RANGE

    q = _q(kind, word, byte, scale, offset)
    lo, hi = INT_RANGE.get(kind, (-1e6, 1e6))
    value = (lo + u * (hi - lo)) * scale + offset
    regs = encode(q, value)
    assert len(regs) == q.width and all(0 <= r <= 0xFFFF for r in regs)
    back = decode(q, regs)
    if kind == "f32":  # the register holds raw = (value - offset) / scale as a float32: half an ulp of it
        half_ulp = abs((value - offset) / scale) * 2.0 ** -24 * abs(scale)
        assert back == pytest.approx(value, rel=1e-6, abs=max(1e-3 * abs(scale), half_ulp))
    elif kind == "f64":
        assert back == pytest.approx(value, rel=1e-12, abs=1e-9)
    else:
        assert abs(back - value) <= abs(scale) / 2 + 1e-9 * max(1.0, abs(value))
        assert encode(q, back) == regs


def _scs_b() -> dict:
    return yaml.safe_load((MAPS_DIR / "scs-b.yaml").read_text())


def _key(node, k: str):
    if isinstance(node, list):
        return int(k)
    return int(k) if k.isdigit() and int(k) in node else k


def _set(doc: dict, path: str, value):
    """Put ``value`` at the dotted ``path`` of ``doc`` (list items and integer keys by number);
    :data:`DELETE` removes the key."""
    *keys, last = path.split(".")
    node = doc
    for k in keys:
        node = node[_key(node, k)]
    if value is DELETE:
        del node[_key(node, last)]
    else:
        node[_key(node, last)] = value


DELETE = object()
BROKEN = [  # (edits, the key path and words the one-line message must hold)
    ([("heliostats.status.colour", 1)], "heliostats.status.colour: unknown key"),
    ([("weather.dni_wm2.type", "u64")], "weather.dni_wm2.type: Input should be"),
    ([("weather.dni_wm2.address", 70000)], "weather.dni_wm2.address: Input should be less than or equal to 65535"),
    ([("heliostats.status.state.bits", {0: "tracking", 1: "moving", 2: "holding", 3: "stowed", 4: "fault", 7: "dancing"})],
     "heliostats.status.state.bits.7: unknown state 'dancing'"),
    ([("heliostats.status.state.bits", {0: "tracking", 1: "moving", 2: "holding", 3: "stowed", 16: "fault"})],
     "heliostats.status.state.bits.16: a u16 has bits 0..15"),
    ([("heliostats.status.state.bits", {0: "tracking", 1: "moving", 2: "holding", 3: "stowed", 4: "fault", 6: "tracking"})],
     "heliostats.status.state.bits.6: tracking is also bit 0"),
    ([("heliostats.status.state.bits", {0: "tracking", 1: "moving", 3: "stowed", 4: "fault"})],
     "heliostats.status.state: no plant value for holding"),
    ([("heliostats.status.state.values", {0: "idle"})], "heliostats.status.state: give either values or bits"),
    ([("heliostats.status.state.bits", DELETE)], "heliostats.status.state: give either values or bits"),
    ([("plant.field_state.values", {0: "tracking", 1: "stowing", 2: "stowed", 3: "parked"})],
     "plant.field_state.values.3: unknown name 'parked'"),
    ([("heliostats.command.mode.values", {"track": 10, "move": 20, "stow": 30, "jump": 40})],
     "heliostats.command.mode.values.jump: unknown command name"),
    ([("heliostats.command.mode.values", {"track": 10, "move": 10, "stow": 30})],
     "heliostats.command.mode.values.move: 10 is also the value of track"),
    ([("heliostats.command.mode.values", {"track": 10, "move": 20})], "heliostats.command.mode: no plant value for stow"),
    ([("heliostats.command.mode.values", {"track": 10, "move": 20, "stow": 70000})],
     "heliostats.command.mode.values.stow: 70000 does not fit a u16"),
    ([("heliostats.command.handshake.execute", DELETE)],
     "heliostats.command.handshake.execute: missing required key (a execute handshake needs execute and done)"),
    ([("heliostats.command.handshake.kind", "sequence"), ("heliostats.command.handshake.execute", DELETE)],
     "heliostats.command.handshake.sequence: missing required key (a sequence handshake needs sequence and done)"),
    ([("heliostats.command.handshake.execute.type", "u32")],
     "heliostats.command.handshake.execute.type: a handshake register is one u16 register"),
    ([("heliostats.status.fault.offset", 0)], "heliostats.status.fault: input offset 0 is also heliostats.status.state"),
    ([("heliostats.command.strokes_mm.0.type", "f64")],
     "heliostats.command.strokes_mm[1]: holding offset 3 is also heliostats.command.strokes_mm[0]"),
    ([("heliostats.stride", 8)], "heliostats.stride: 8 is smaller than the block's extent 10 (holding offsets 0..9)"),
    ([("heliostats.addresses", [10000, 10040])], "heliostats: give base and stride, or addresses"),
    ([("heliostats.base", DELETE), ("heliostats.stride", DELETE), ("heliostats.addresses", [10000, 10005])],
     "heliostats.addresses[1]: 10005 overlaps the block at 10000 (blocks span 10 registers)"),
    ([("plant.heliostat_count", {"offset": 10})], "plant.heliostat_count.offset: a plant-wide quantity takes an address"),
    ([("heliostats.status.cleanliness", {"address": 6})],
     "heliostats.status.cleanliness.address: a heliostat quantity takes an offset in its block"),
    ([("heliostats.status.cleanliness", {"type": "u16"})], "heliostats.status.cleanliness.offset: missing required key"),
    ([("heliostats.command.handshake.execute.table", "input")],
     "heliostats.command.handshake.execute.table: input registers cannot be written"),
    ([("weather.dni_wm2.scale", 0)], "weather.dni_wm2.scale: 0.0: expected a finite number other than 0"),
    ([("weather.temperature_c.table", "coil")], "weather.temperature_c.type: a coil holds one bit (type u16, no scale or value_offset), got i16"),
    ([("heliostats.status.fault.scale", 0.1)], "heliostats.status.fault.type: a coded quantity is one unscaled integer"),
    ([("weather.dni_wm2.values", {0: "none"})], "weather.dni_wm2.values: unknown key"),
    ([("plant.clock.time.parts.1.table", "holding")],
     "plant.clock.time.parts[1].table: holding: the parts of a quantity share one table (input)"),
    ([("plant.clock.time.address", 0)], "plant.clock.time: either parts or an address, not both"),
    ([("plant.clock.time.parts.0.parts", [{"address": 0}, {"address": 1}])],
     "plant.clock.time.parts[0].parts: parts cannot have parts"),
    ([("readable", [{"table": "input", "first": 9, "last": 3}])], "readable[0].last: 3 is before first (9)"),
    ([("heliostats.command.strokes_mm.1", {"parts": [{"offset": 3, "type": "i16"}, {"offset": 4, "scale": 0.01}]})],
     "heliostats.command.strokes_mm[1].parts: a stroke demand is one register quantity"),
    ([("plant.heliostat_count", DELETE)], "plant.heliostat_count: missing required key"),
]


@pytest.mark.parametrize("edits, message", BROKEN, ids=[m.split(":")[0] + f"-{k}" for k, (_, m) in enumerate(BROKEN)])
def test_a_broken_map_is_one_line_naming_the_file_and_key(edits, message):
    doc = _scs_b()
    for path, value in edits:
        _set(doc, path, value)
    with pytest.raises(ConfigError) as err:
        parse_register_map(copy.deepcopy(doc), "scs-b.yaml")
    lines = str(err.value).splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("scs-b.yaml: ") and message in lines[0], lines[0]


@pytest.mark.parametrize("n, edits, message", [
    (40, [("heliostats.base", 65000)], "heliostats.stride: the holding blocks of 40 heliostats end at address 66569, beyond 65535"),
    (40, [("heliostats.base", DELETE), ("heliostats.stride", DELETE), ("heliostats.addresses", [10000, 10040, 10080])],
     "heliostats.addresses: 3 block addresses for a field of 40 heliostats"),
    (40, [("plant.heliostat_count.address", 10044)], "plant.heliostat_count.address: 10044 lies inside the heliostat blocks (input 10000..11567)"),
])
def test_a_map_too_small_for_the_field_is_refused_when_the_count_is_known(n, edits, message):
    doc = _scs_b()
    for path, value in edits:
        _set(doc, path, value)
    m = parse_register_map(doc, "scs-b.yaml")
    with pytest.raises(ConfigError) as err:
        m.check_count(n)
    assert str(err.value) == f"scs-b.yaml: {message}"


def test_loading_by_name_file_and_the_errors_of_both(tmp_path):
    assert shipped_maps() == ["plant-interface-1", "plant-interface-1-units", "scs-b"]
    assert load_register_map("scs-b").name == "scs-b"
    with pytest.raises(ConfigError, match=r"register map 'scs-c': no shipped map of that name \(shipped: "
                                          r"plant-interface-1, plant-interface-1-units, scs-b"):
        load_register_map("scs-c")
    (tmp_path / "mine.yaml").write_text((MAPS_DIR / "scs-b.yaml").read_text().replace("name: scs-b", "name: mine"))
    assert load_register_map("mine.yaml", tmp_path).name == "mine"
    with pytest.raises(ConfigError, match="nowhere.yaml"):
        load_register_map("nowhere.yaml", tmp_path)
    (tmp_path / "twice.yaml").write_text("name: a\nname: b\n")
    with pytest.raises(ConfigError, match=r"twice.yaml: line 2"):
        load_register_map(str(tmp_path / "twice.yaml"))
    (tmp_path / "list.yaml").write_text("- 1\n")
    with pytest.raises(ConfigError, match=r"list.yaml: expected a mapping"):
        load_register_map(str(tmp_path / "list.yaml"))


def test_field_config_maps_folder_is_the_shipped_one():
    from pathlib import Path

    link = Path(__file__).resolve().parents[1] / "field_config" / "maps"
    assert link.is_symlink() and (link / "scs-b.yaml").read_text() == (MAPS_DIR / "scs-b.yaml").read_text()
