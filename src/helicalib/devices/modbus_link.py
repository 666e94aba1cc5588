"""One Modbus TCP endpoint: timeouts, retries with back-off, reconnection, and a short "down"
window after a request failed every attempt (the only place that calls pymodbus's client).

A Modbus exception answer (a refused read or write) is not retried and raises
:class:`~helicalib.errors.PlantError`; a plant that did not answer at all raises its subclass
:class:`~helicalib.devices.protocols.PlantUnreachableError`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from helicalib.devices.protocols import PlantUnreachableError
from helicalib.errors import PlantError

log = logging.getLogger(__name__)


def quiet_pymodbus() -> None:
    """Silence pymodbus's own log (its "Connection ... refused" and "Repeating...." lines would reach
    stderr through Python's last-resort handler): a failure is one :class:`PlantError` line of ours."""
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "device failure",
                   6: "device busy", 10: "gateway path unavailable", 11: "gateway target failed to respond"}

class ModbusLink:
    """One Modbus TCP endpoint with timeouts, retries with back-off and reconnection (thread-safe).

    Parameters
    ----------
    host, port, unit : str, int, int
        Endpoint and Modbus unit (device) id.
    timeout_s : float
        Per-request timeout [s].
    retries : int
        Extra attempts after a failed one (connection lost, timeout, garbled answer).
    backoff_s, backoff_max_s : float
        First wait before a retry [s], doubled each time up to ``backoff_max_s``.
    sleep : callable
        Waits real seconds between retries (injected; ``time.sleep``).
    down_s : float
        After a request failed all its attempts, further requests fail at once for this many real
        seconds (the plant is down: a tick that asks 500 heliostats must not wait 500 timeouts),
        then the next one tries again.
    monotonic : callable
        Real time source for ``down_s`` (injected; ``time.monotonic``).

    :meth:`hurry` (a stopping controller): from then on two attempts per request (one reconnect:
    a reset connection is not a dead plant), no back-off, and a 1 s down window.
    """

    def __init__(self, host: str, port: int, unit: int = 1, timeout_s: float = 2.0, retries: int = 3,
                 backoff_s: float = 0.2, backoff_max_s: float = 5.0, sleep: Callable[[float], None] = time.sleep,
                 down_s: float = 5.0, monotonic: Callable[[], float] = time.monotonic):
        self.host, self.port, self.unit = host, int(port), int(unit)
        self.timeout_s, self.retries = float(timeout_s), int(retries)
        self.backoff_s, self.backoff_max_s = float(backoff_s), float(backoff_max_s)
        self.down_s = float(down_s)
        self._monotonic = monotonic
        self._down_until = -math.inf
        self._down_reason = ""
        self._hurry = False
        self._sleep = sleep
        self._lock = threading.RLock()
        self._client: ModbusTcpClient | None = None
        self.reconnects = 0
        """How many times the connection was reopened after a failure."""
        self.answered = False
        """Whether the plant has answered a request on this link (it has connected once)."""

    @property
    def name(self) -> str:
        return f"{self.host}:{self.port} unit {self.unit}"

    def _connected(self) -> ModbusTcpClient:
        if self._client is None:
            quiet_pymodbus()  # before the client exists: its first failed connect logs too
            self._client = ModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0,
                                           reconnect_delay=0, name=f"helicalib-{self.port}")
        if not self._client.connected and not self._client.connect():
            raise ConnectionError(f"cannot connect to {self.host}:{self.port}")
        return self._client

    def _drop(self) -> None:
        if self._client is not None:
            try:
                self._client.close()
            except Exception:
                pass
            self._client = None
            self.reconnects += 1

    def hurry(self) -> None:
        """From now on two attempts per request, no back-off, a 1 s down window (the controller is stopping)."""
        self._hurry = True
        self.down_s = min(self.down_s, 1.0)
        self._down_until = min(self._down_until, self._monotonic() + self.down_s)

    def _call(self, what: str, fn: Callable[[ModbusTcpClient], object], retry: bool = True):
        """One request, attempted up to ``retries + 1`` times (once without ``retry``: a request the
        plant must not take twice; its failure then leaves the down window closed)."""
        if self._monotonic() < self._down_until:
            raise PlantUnreachableError(f"plant {self.name}: {what} not sent: the plant did not answer a moment ago "
                             f"({self._down_reason})")
        delay = self.backoff_s
        last = "no attempt"
        attempts = 1 if not retry else min(2, self.retries + 1) if self._hurry else self.retries + 1
        for attempt in range(attempts):
            if attempt and not self._hurry:
                self._sleep(delay)
                delay = min(delay * 2, self.backoff_max_s)
            with self._lock:
                try:
                    rr = fn(self._connected())
                except (ModbusException, ConnectionError, OSError, TimeoutError) as exc:
                    last = " ".join(f"{type(exc).__name__}: {exc}".split())   # one line: pymodbus's text may hold newlines
                    log.debug("%s: %s failed (attempt %d): %s", self.name, what, attempt + 1, last)
                    self._drop()
                    continue
            if rr is None:
                last = "no answer"
                self._drop()
                continue
            if rr.isError():
                code = int(getattr(rr, "exception_code", 0) or 0)
                name = EXCEPTION_NAMES.get(code, "unknown")
                raise PlantError(f"plant {self.name}: {what} refused: Modbus exception {code} ({name})")
            self._down_until = -math.inf
            self.answered = True
            return rr
        if retry:
            self._down_until = self._monotonic() + self.down_s
            self._down_reason = last
        raise PlantUnreachableError(f"plant {self.name}: {what} failed after {attempts} attempt{'s' * (attempts > 1)} ({last})")

    def _where(self, address: int, table: str, unit: int) -> str:
        where = f"address {address}" if table == "holding" else f"{table} address {address}"
        return where if unit == self.unit else f"unit {unit} {where}"

    def read(self, address: int, count: int, what: str, table: str = "holding", unit: int | None = None) -> list[int]:
        """``count`` registers of ``table`` (holding: function 3, input: 4, coil: 1) from ``address``;
        ``what`` names them in errors; ``unit``: another unit id behind this endpoint (a block of
        heliostats, ``heliostats.per_unit``), same connection."""
        device = self.unit if unit is None else int(unit)
        where = self._where(address, table, device)
        label = f"read of {what} ({where}, {count} registers)"
        if table == "coil":
            rr = self._call(label, lambda c: c.read_coils(address, count=count, device_id=device))
            regs = [int(b) for b in rr.bits]
        else:
            fn = "read_input_registers" if table == "input" else "read_holding_registers"
            rr = self._call(label, lambda c: getattr(c, fn)(address, count=count, device_id=device))
            regs = list(rr.registers)
        if len(regs) < count:
            raise PlantError(f"plant {self.name}: read of {what} ({where}) answered {len(regs)} of {count} registers")
        return regs[:count]

    def write(self, address: int, values: Sequence[int], what: str, table: str = "holding",
              retry: bool = True, unit: int | None = None) -> None:
        """Write holding registers (function 6 for one, 16 for several) or coils (5, 15).

        ``retry=False``: one attempt only, for a write the plant acts on every time (an execute
        handshake): a lost answer must not become a second command; the caller finds out whether
        the plant took it. ``unit``: as for :meth:`read`.
        """
        values = [int(v) & 0xFFFF for v in values]
        device = self.unit if unit is None else int(unit)
        label = f"write of {what} ({self._where(address, table, device)})"
        if table == "coil":
            bits = [bool(v) for v in values]
            if len(bits) == 1:
                self._call(label, lambda c: c.write_coil(address, bits[0], device_id=device), retry)
            else:
                self._call(label, lambda c: c.write_coils(address, bits, device_id=device), retry)
        elif len(values) == 1:
            self._call(label, lambda c: c.write_register(address, values[0], device_id=device), retry)
        else:
            self._call(label, lambda c: c.write_registers(address, values, device_id=device), retry)

    def close(self) -> None:
        with self._lock:
            if self._client is not None:
                self._client.close()
                self._client = None
