"""Plant moves as statuses (campaign/status.py) on the in-process simulated plant, and the optional
abilities each plant declares (devices/protocols.py), read once when a campaign is built."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from helicalib.app.simulated import default_start_s
from helicalib.campaign import status
from helicalib.config import load_field_config
from helicalib.devices.modbus import ModbusPlant
from helicalib.devices.protocols import PlantAbilities, abilities_of
from helicalib.devices.registers import FieldCommand, HeliostatState
from helicalib.sim.plant import SimulatedPlant
from helicalib.sim.scenario import parse_scenario

FIELD = Path(__file__).resolve().parents[1] / "field_config" / "demo_north.yaml"


@pytest.fixture(scope="module")
def cfg():
    return load_field_config(FIELD)


def _plant(cfg, **faults) -> SimulatedPlant:
    scenario = parse_scenario({"seed": 3, **({"faults": faults} if faults else {})})
    return SimulatedPlant(cfg, scenario, start_s=default_start_s(cfg) + 9 * 3600)


def _drive(plant: SimulatedPlant, gen) -> tuple[object, list[float]]:
    """Run a status's wait on the plant's own time: each yielded wait advances the plant."""
    waits = []
    try:
        while True:
            dt = next(gen)
            waits.append(dt)
            plant.advance_to(plant.t_s + dt)
    except StopIteration as stop:
        return stop.value, waits


def _a_short_move(plant: SimulatedPlant, index: int, mm: float = 5.0) -> np.ndarray:
    now = np.asarray(plant.status(index).strokes_mm, dtype=float)
    return now + np.array([mm, -mm])


def test_a_move_completes_with_the_read_back_strokes_polled_every_poll_s(cfg):
    plant = _plant(cfg)
    goal = _a_short_move(plant, 0)
    st = status.start_move(plant, 0, cfg.heliostats[0].id, goal, timeout_s=600.0)
    assert st.sequence is not None and not st.done
    strokes, waits = _drive(plant, status.wait(st))
    assert st.success and st.failure is None
    assert np.allclose(strokes, goal, atol=0.05)
    assert plant.status(0).state == HeliostatState.HOLDING
    assert waits and set(waits) == {status.POLL_S}
    assert st.waited_s == pytest.approx(status.POLL_S * len(waits))


def test_a_move_that_does_not_hold_in_time_fails_as_a_settle_timeout(cfg):
    plant = _plant(cfg)
    goal = _a_short_move(plant, 0, mm=200.0)  # far: the drive needs many seconds to get there
    st = status.start_move(plant, 0, cfg.heliostats[0].id, goal, timeout_s=2 * status.POLL_S)
    with pytest.raises(status.MoveFailed) as err:
        _drive(plant, status.wait(st))
    assert err.value.code == status.SETTLE_TIMEOUT and not err.value.refused
    assert st.done and not st.success and st.waited_s == pytest.approx(2 * status.POLL_S)
    assert cfg.heliostats[0].id in str(err.value)


def test_a_move_into_a_stowed_field_fails_as_refused_by_the_plant(cfg):
    plant = _plant(cfg)
    plant.field_command(FieldCommand.STOW_ALL)
    plant.advance_to(plant.t_s + 600.0)
    st = status.start_move(plant, 1, cfg.heliostats[1].id, _a_short_move(plant, 1), timeout_s=600.0)
    with pytest.raises(status.MoveFailed) as err:
        _drive(plant, status.wait(st))
    assert err.value.code == status.PLANT_REFUSED and "stowed" in str(err.value) and not err.value.refused


def test_a_move_the_plant_faults_fails_as_a_plant_fault(cfg):
    plant = _plant(cfg)
    far = np.asarray(plant.status(2).strokes_mm, dtype=float) + 1e4  # the plant's own range check faults it
    st = status.start_move(plant, 2, cfg.heliostats[2].id, far, timeout_s=600.0)
    with pytest.raises(status.MoveFailed) as err:
        _drive(plant, status.wait(st))
    assert err.value.code == status.PLANT_FAULT and st.waited_s == 0.0


def test_a_declined_move_sends_nothing_and_reads_nothing(cfg):
    plant = _plant(cfg)
    before = (int(plant.reg_sequence[0]), plant.status(0).sequence_done)
    reads = []
    real_status = plant.status
    plant.status = lambda i: reads.append(i) or real_status(i)
    st = status.refuse(plant, 0, cfg.heliostats[0].id, status.STROKE_OUT_OF_RANGE, "not sent")
    with pytest.raises(status.MoveFailed) as err:
        _drive(plant, status.wait(st))
    assert err.value.refused and err.value.code == status.STROKE_OUT_OF_RANGE
    assert reads == [] and st.sequence is None
    plant.status = real_status
    assert (int(plant.reg_sequence[0]), plant.status(0).sequence_done) == before


def test_the_simulated_plant_declares_bulk_writes_and_reads_and_the_modbus_client_hurries(cfg):
    sim = _plant(cfg)
    assert abilities_of(sim) == PlantAbilities(bulk_tracking=True, bulk_cleanliness=True, hurries=False)
    client = ModbusPlant.from_config(cfg, armed=False)
    try:
        assert abilities_of(client) == PlantAbilities(bulk_tracking=False, parallel_tracking=True, bulk_cleanliness=True,
                                                      hurries=True)
    finally:
        client.close()
    assert abilities_of(object()) == PlantAbilities()
