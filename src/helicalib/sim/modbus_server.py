"""The simulated plant's Modbus TCP server: a pymodbus server context backed by
:class:`~helicalib.sim.modbus_map.PlantRegisters`, with injected faults (dropped or slow answers)."""

from __future__ import annotations

import asyncio

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

from helicalib.sim.modbus_map import ILLEGAL_ADDRESS, PlantRegisters

TABLES = {1: "coil", 5: "coil", 15: "coil", 3: "holding", 6: "holding", 16: "holding", 22: "holding", 23: "holding",
          4: "input"}
"""The register table a Modbus function code addresses (discrete inputs, 2, are not served)."""


class PlantContext(ModbusServerContext):
    """pymodbus 3.16 server context backed by :class:`PlantRegisters` (bypasses the data blocks);
    the function code of each request says which table it reads or writes."""

    def __init__(self, registers: PlantRegisters, units: set[int]):  # noqa: D107  (no super().__init__)
        self.old_simulator = True      # pymodbus then calls our async_getValues/async_setValues
        self.simdevices = []
        self._devices = {u: None for u in units}
        self.registers = registers
        self.units = units

    def _check(self, device_id: int) -> None:
        if device_id not in self.units:
            raise NoSuchIdException(f"device_id {device_id}: this plant answers on unit(s) {sorted(self.units)}")

    async def async_getValues(self, device_id, func_code, address, count=1):
        self._check(device_id)
        table = TABLES.get(func_code)
        out = ILLEGAL_ADDRESS if table is None else self.registers.read(address, count, table)
        if isinstance(out, int):
            return ExcCodes(out)
        return [bool(v) for v in out] if table == "coil" else out

    async def async_setValues(self, device_id, func_code, address, values):
        self._check(device_id)
        table = TABLES.get(func_code)
        rc = ILLEGAL_ADDRESS if table is None else self.registers.write(address, [int(v) for v in values], table)
        return None if rc is None else ExcCodes(rc)

    def device_ids(self):
        return sorted(self.units)


class FaultyHandler(ServerRequestHandler):
    """Drops or delays a request as the server's fault injector decides."""

    async def handle_request(self):
        faults = self.server.faults
        if self.last_pdu and faults.happens(faults.modbus_drop_probability):
            self.last_pdu = None
            self.close()           # the connection drops without an answer
            return
        if faults.happens(faults.modbus_slow_probability):
            await asyncio.sleep(faults.modbus_slow_s)
        await super().handle_request()


class FaultyTcpServer(ModbusTcpServer):
    """A pymodbus TCP server whose connections go through :class:`FaultyHandler`."""

    faults: object  # helicalib.sim.server.FaultInjector

    def callback_new_connection(self):
        return FaultyHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)
