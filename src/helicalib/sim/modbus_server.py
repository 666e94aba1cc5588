"""The simulated plant's Modbus TCP server: a pymodbus server context backed by
:class:`~helicalib.sim.modbus_map.PlantRegisters`, with injected faults
(dropped requests, slow answers, answers lost after the request was handled)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

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
        out = ILLEGAL_ADDRESS if table is None else self.registers.read(address, count, table, unit=device_id)
        if isinstance(out, int):
            return ExcCodes(out)
        return [bool(v) for v in out] if table == "coil" else out

    async def async_setValues(self, device_id, func_code, address, values):
        self._check(device_id)
        table = TABLES.get(func_code)
        rc = ILLEGAL_ADDRESS if table is None else self.registers.write(address, [int(v) for v in values], table,
                                                                          unit=device_id)
        return None if rc is None else ExcCodes(rc)

    def device_ids(self):
        return sorted(self.units)


class FaultyHandler(ServerRequestHandler):
    """Drops, delays or answers nothing to a request as the server's fault injector decides (or the
    server's :attr:`FaultyTcpServer.request_fault`, which picks the fault of one request)."""

    _lose_answer = False

    async def handle_request(self):
        faults, pdu = self.server.faults, self.last_pdu
        chosen = self.server.request_fault(pdu) if pdu and self.server.request_fault else None
        if pdu and (chosen == "drop" or faults.happens(faults.modbus_drop_probability)):
            self.last_pdu = None
            self.close()           # the connection drops without an answer
            return
        if faults.happens(faults.modbus_slow_probability):
            await asyncio.sleep(faults.modbus_slow_s)
        self._lose_answer = chosen == "lose_answer"
        await super().handle_request()

    def server_send(self, pdu, addr):
        if self._lose_answer:      # the request was handled; its answer is lost with the connection
            self._lose_answer = False
            self.close()
            return
        super().server_send(pdu, addr)


class FaultyTcpServer(ModbusTcpServer):
    """A pymodbus TCP server whose connections go through :class:`FaultyHandler`."""

    faults: object  # helicalib.sim.server.FaultInjector
    request_fault: Callable[[object], str | None] | None = None
    """The fault of one request (its pdu: ``function_code``, ``address``, ...): ``"drop"`` (the
    connection drops before the request is handled), ``"lose_answer"`` (the request is handled, then
    the connection drops without its answer) or None (the fault injector decides)."""

    def callback_new_connection(self):
        return FaultyHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)
