"""The OPC UA plant client against the simulated plant served by a real asyncua server on loopback.

One server for the module (an asyncua server takes seconds to start); plant time comes from a fake
source the tests move. Each test commands its own heliostats, so the order of the tests does not
matter. The node map's validation is tested on files written to tmp_path.
"""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from helicalib.config import load_field_config
from helicalib.devices.guard import CommandGuard
from helicalib.devices.nodemap import MAPS_DIR, load_node_map
from helicalib.devices.opcua import OpcUaPlant
from helicalib.devices.protocols import FieldStowedError, Hurries, Plant
from helicalib.devices.registers import FaultCode, FieldCommand, FieldState, HeliostatState
from helicalib.errors import ConfigError, PlantError
from helicalib.geometry.sun import to_unix_seconds
from helicalib.sim.clock import RateClock
from helicalib.sim.opcua_server import OpcUaPlantService
from helicalib.sim.plant import SimulatedPlant

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))
RATE = 600.0


@pytest.fixture(scope="module")
def served(demo_field_path):
    cfg = load_field_config(demo_field_path)
    source = SimpleNamespace(t=100.0)            # the monotonic source the tests move
    plant = SimulatedPlant(cfg, start_s=START, rate=RATE)
    svc = OpcUaPlantService(plant, RateClock(START, RATE, lambda: source.t)).start()
    yield cfg, plant, svc, source
    svc.stop()


def client(cfg, svc, armed=True, node_map=None) -> OpcUaPlant:
    g = CommandGuard.from_config(cfg, armed)
    return OpcUaPlant(svc.endpoint, node_map or load_node_map(), g.heliostat_ids, len(cfg.heliostats),
                      armed=armed, stroke_limits_mm=g.stroke_limits_mm, timeout_s=2.0)


def mid_strokes(cfg, i):
    return np.array([a.stroke_range_mm for a in cfg.drive_of(cfg.heliostats[i].id).actuators]).mean(axis=1)


def write_map(tmp_path, edit, name="map.yaml"):
    data = yaml.safe_load((MAPS_DIR / "opcua-default.yaml").read_text())
    edit(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_reads_equal_the_plants_truth(served):
    cfg, plant, svc, source = served
    with client(cfg, svc, armed=False) as op:
        assert isinstance(op, Plant) and isinstance(op, Hurries)
        assert op.heliostat_count() == len(cfg.heliostats)
        source.t += 1.0
        t, rate = op.plant_time()
        assert t == pytest.approx(START + RATE * (source.t - 100.0), abs=1e-5) and rate == pytest.approx(RATE)
        w, truth = op.weather(), plant.weather()
        for key in ("wind_ms", "wind_direction_deg", "dni_wm2", "temperature_c", "pressure_hpa"):
            assert getattr(w, key) == pytest.approx(getattr(truth, key), rel=1e-12)
        assert op.field_state() == FieldState(plant.field_state())
        for i in range(len(cfg.heliostats)):
            st = op.status(i)
            assert st.index == i and st.state == HeliostatState(int(plant.state[i]))
            assert st.sequence_done == int(plant.sequence_done[i]) and st.fault == int(plant.fault[i])
            assert st.strokes_mm == pytest.approx(tuple(plant.strokes_mm[i]), abs=1e-9)
            assert st.cleanliness == pytest.approx(float(plant.cleanliness_of(i)), abs=1e-12)


def test_a_read_is_as_fresh_as_the_plant_clock(served):
    """Plant time moves between two reads without any refresh task: each read advances the plant."""
    cfg, _plant, svc, source = served
    with client(cfg, svc, armed=False) as op:
        t0, _ = op.plant_time()
        source.t += 0.5
        t1, _ = op.plant_time()
        assert t1 - t0 == pytest.approx(0.5 * RATE, abs=1e-5)


def test_move_track_and_stow_reach_the_plant(served):
    cfg, plant, svc, source = served
    i = 3
    with client(cfg, svc) as op:
        s = mid_strokes(cfg, i)
        seq = op.move_to(i, s)
        assert op.status(i).sequence_done == seq and int(plant.sequence_done[i]) == seq
        source.t += 1.0          # 600 plant s: the drive arrives and settles
        st = op.status(i)
        assert st.state == HeliostatState.HOLDING and st.strokes_mm == pytest.approx(tuple(s), abs=1e-6)
        seq2 = op.track(i, np.array([1.5, -2.0]))
        assert seq2 != seq and op.status(i).sequence_done == seq2
        assert plant.corrections_mm[i] == pytest.approx([1.5, -2.0])
        seq3 = op.track(i, None)               # the plant's own corrections stay
        assert op.status(i).sequence_done == seq3 and plant.corrections_mm[i] == pytest.approx([1.5, -2.0])
        seq4 = op.stow(i)
        source.t += 1.0
        st = op.status(i)
        assert st.sequence_done == seq4 and st.state == HeliostatState.STOWED
    names = [c[0] for c in svc.calls if c[1][0] == cfg.heliostats[i].id]
    assert names[-4:] == ["MoveTo", "Track", "Resume", "Stow"]


def test_a_stroke_outside_the_range_is_refused_before_anything_is_sent(served):
    cfg, plant, svc, _ = served
    i = 5
    before = len(svc.calls)
    with client(cfg, svc) as op:
        hi = np.array([a.stroke_range_mm[1] for a in cfg.drive_of(cfg.heliostats[i].id).actuators])
        with pytest.raises(PlantError, match=r"refusing to send strokes .* heliostat 5 \(H0006\): outside"):
            op.move_to(i, hi + 10.0)
        with pytest.raises(PlantError, match="non-finite"):
            op.move_to(i, [np.nan, 100.0])
    assert len(svc.calls) == before and int(plant.sequence_done[i]) == 0


def test_an_unarmed_client_calls_no_method(served):
    cfg, plant, svc, _ = served
    before = len(svc.calls)
    with client(cfg, svc, armed=False) as op:
        for call in (lambda: op.move_to(6, mid_strokes(cfg, 6)), lambda: op.track(6, [0.0, 0.0]),
                     lambda: op.track(6, None), lambda: op.stow(6), lambda: op.field_command(FieldCommand.STOW_ALL)):
            with pytest.raises(PlantError, match="read-only mode"):
                call()
        op.status(6)
    assert len(svc.calls) == before and not plant.field_stow


def test_the_stow_gate_holds_moves_and_tracks_until_resume(served):
    cfg, plant, svc, source = served
    i = 7
    with client(cfg, svc) as op:
        op.field_command(FieldCommand.STOW_ALL)
        assert op.stowed and plant.field_stow
        before = len(svc.calls)
        with pytest.raises(FieldStowedError):
            op.move_to(i, mid_strokes(cfg, i))
        with pytest.raises(FieldStowedError):
            op.track(i, [0.0, 0.0])
        assert len(svc.calls) == before
        seq = op.stow(i)                       # a stow always passes
        assert op.status(i).sequence_done == seq
        source.t += 1.0
        assert op.field_state() == FieldState.STOWED
        op.field_command(FieldCommand.RESUME_TRACKING)
        assert not op.stowed and not plant.field_stow
        seq = op.move_to(i, mid_strokes(cfg, i))
        assert op.status(i).sequence_done == seq


def test_a_map_by_browse_paths_reads_the_same_nodes(served, tmp_path):
    cfg, _plant, svc, _ = served

    def by_path(d):
        d["heliostat"]["state"]["node"] = "2:Plant/2:Heliostats/2:{id}/2:State"
        d["heliostat"]["stroke_1_mm"] = "2:Plant/2:Heliostats/2:{id}/2:Stroke1"
        d["weather"]["dni_wm2"] = "2:Plant/2:Weather/2:DNI"

    nm = load_node_map(write_map(tmp_path, by_path))
    with client(cfg, svc, armed=False, node_map=nm) as op, client(cfg, svc, armed=False) as ref:
        a, b = op.status(9), ref.status(9)
        assert (a.state, a.strokes_mm, a.sequence_done) == (b.state, b.strokes_mm, b.sequence_done)
        assert op.weather().dni_wm2 == pytest.approx(ref.weather().dni_wm2)


def test_a_node_the_server_lacks_is_a_one_line_error_naming_node_and_heliostat(served, tmp_path):
    cfg, _plant, svc, _ = served
    nm = load_node_map(write_map(tmp_path, lambda d: d["heliostat"].update(cleanliness="ns=2;s=Heliostats.{id}.Dust")))
    with client(cfg, svc, armed=True, node_map=nm) as op:
        with pytest.raises(PlantError) as err:
            op.status(2)
    msg = str(err.value)
    assert "\n" not in msg and "ns=2;s=Heliostats.H0003.Dust" in msg and "H0003" in msg and "BadNodeIdUnknown" in msg
    nm = load_node_map(write_map(tmp_path, lambda d: d["commands"]["stow"].update(method="ns=2;s=Heliostats.{id}.Park"),
                                 "m2.yaml"))
    with client(cfg, svc, armed=True, node_map=nm) as op:
        with pytest.raises(PlantError) as err:
            op.stow(2)
    msg = str(err.value)
    assert "\n" not in msg and "ns=2;s=Heliostats.H0003.Park" in msg and "H0003" in msg and "Bad" in msg


def test_a_heliostat_count_other_than_the_configs_is_refused(served):
    cfg, _plant, svc, _ = served
    g = CommandGuard.from_config(cfg)
    with OpcUaPlant(svc.endpoint, load_node_map(), g.heliostat_ids, 39) as op:
        with pytest.raises(PlantError, match="reports 40 heliostats, the field config has 39"):
            op.status(0)


def test_a_fault_code_maps_to_helicalibs(served, tmp_path):
    """A plant whose fault values differ: the map translates them both ways (the simulated server
    serves the map's raw value, the client reads it as helicalib's code); a value outside the map
    is no code at all."""
    cfg, plant, _svc, source = served
    edit = lambda d: d["heliostat"]["fault"].update(values={0: "NONE", 11: "STROKE_OUT_OF_RANGE",  # noqa: E731
                                                            12: "REFUSED_DURING_STOW", 13: "UNKNOWN_COMMAND"})
    nm = load_node_map(write_map(tmp_path, edit))
    svc2 = OpcUaPlantService(plant, RateClock(START, RATE, lambda: source.t), node_map=nm)
    assert svc2.map.raw_fault(FaultCode.STROKE_OUT_OF_RANGE) == 11 and nm.fault_of(12) == FaultCode.REFUSED_DURING_STOW
    assert nm.fault_of(1) is None


@pytest.mark.parametrize("edit, expect", [
    (lambda d: d["heliostat"].update(sequence_done="ns=2;s=Heliostats.{name}.Seq"),
     r"heliostat\.sequence_done: .*unknown placeholder \{name\}"),
    (lambda d: d["heliostat"].update(sequence_done="ns=2;s=Heliostats.Seq"),
     r"heliostat\.sequence_done: .*needs a placeholder"),
    (lambda d: d["heliostat"]["state"]["values"].update({7: "PARKED"}),
     r"heliostat\.state\.values: 7: 'PARKED' is not a helicalib heliostat state"),
    (lambda d: d["commands"]["move"].update(args=["stroke_1_mm", "stroke_2_mm"]),
     r"commands\.move: args: .*sequence number"),
    (lambda d: d["commands"]["track"].update(args=["sequence", "speed"]),
     r"commands\.track\.args: .*'speed': not one of"),
    (lambda d: d["weather"].update(dni_wm2={"node": "ns=2;s=Weather.DNI", "scale": 0}),
     r"weather\.dni_wm2\.scale: .*scale of 0"),
    (lambda d: d["field"].pop("plant_time"), r"field\.plant_time: "),
    (lambda d: d["field"].update(heliostat_count="Plant.Count"), r"field\.heliostat_count: .*neither a node id"),
    (lambda d: d["commands"]["move"].update(args=["sequence", "stroke_1_mm:Int32", "stroke_2_mm"]),
     r"commands\.move\.args: .*'stroke_1_mm:Int32': an OPC UA method takes strokes in mm as Float or Double"),
    (lambda d: d["commands"]["track"].update(args=["sequence", "correction_1_mm", "correction_2_mm:Int16"]),
     r"commands\.track\.args: .*'correction_2_mm:Int16': an OPC UA method takes strokes in mm as Float or Double"),
    (lambda d: d["commands"]["stow"].update(args=["sequence:Byte"]),
     r"commands\.stow: .*sequence:Byte cannot carry sequence_modulus 65536: 65535 does not fit .*Byte \(0\.\.255\)"),
    (lambda d: d["commands"]["stow"].update(args=["sequence:Double"]), r"commands\.stow\.args: .*sequence is an integer"),
    (lambda d: d["commands"]["stow"].update(args=["sequence", "id:Int32"]),
     r"commands\.stow\.args: .*'id:Int32': a heliostat's id is a String"),
    (lambda d: d["commands"]["field"].update(args=["command:Byte"], values={"STOW_ALL": 300, "RESUME_TRACKING": 2}),
     r"commands\.field: .*STOW_ALL: 300 does not fit .*Byte"),
])
def test_a_bad_node_map_is_refused_naming_file_and_key(tmp_path, edit, expect):
    path = write_map(tmp_path, edit)
    with pytest.raises(ConfigError) as err:
        load_node_map(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg
    assert re.search(expect, msg), msg


def test_a_sequence_type_that_holds_the_modulus_is_taken(tmp_path):
    def small(d):
        d["commands"].update(sequence_modulus=256)
        d["commands"]["stow"].update(args=["sequence:Byte", "index:Int16"])

    nm = load_node_map(write_map(tmp_path, small))
    assert nm.commands.stow.typed_args() == [("sequence", "Byte"), ("index", "Int16")]


def test_a_shipped_map_is_named_by_its_bare_name():
    assert load_node_map("opcua-default").heliostat.sequence_done == "ns=2;s=Heliostats.{id}.SequenceDone"
    with pytest.raises(ConfigError, match="node map 'opcua-nope': no shipped map of that name .*opcua-default"):
        load_node_map("opcua-nope")
