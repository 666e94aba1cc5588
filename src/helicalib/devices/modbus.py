"""The plant over Modbus TCP (``PLANT_INTERFACE.md`` version 1): the only client-side pymodbus user.

:class:`ModbusPlant` implements :class:`helicalib.devices.protocols.Plant`. Every request has the
endpoint's timeout; a lost connection, a timeout or a garbled answer is retried with exponential
back-off after closing and reopening the connection; a Modbus exception answer (a refused read or
write) is not retried. Failures raise :class:`~helicalib.errors.PlantError` naming the endpoint,
the register (address and meaning) and the heliostat; a plant that did not answer at all raises
its subclass :class:`~helicalib.devices.protocols.PlantUnreachableError`. Writes are refused unless ``armed=True``:
an unarmed client reads and plans but never writes to the plant.

A heliostat command is written as the contract asks: the command fields first, then a sequence
number different from the one in the register, which the plant acts on.

The client is the field's stow gate: once it has sent STOW ALL, it refuses every move and track
command (:class:`~helicalib.devices.protocols.FieldStowedError`) until it sends RESUME TRACKING.
Field commands and heliostat commands take one lock, so a stow sent from another thread (the
weather job) never lands between a command's fields and its sequence number, and no command
already waiting is sent after it.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from helicalib.devices import registers as R
from helicalib.devices.guard import CommandGuard
from helicalib.devices.protocols import HeliostatStatus, PlantUnreachableError, Weather
from helicalib.errors import PlantError

log = logging.getLogger(__name__)


def quiet_pymodbus() -> None:
    """Silence pymodbus's own log (its "Connection ... refused" and "Repeating...." lines would reach
    stderr through Python's last-resort handler): a failure is one :class:`PlantError` line of ours."""
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "device failure",
                   6: "device busy", 10: "gateway path unavailable", 11: "gateway target failed to respond"}

_OFFSET_NAMES = {R.OFF_COMMAND: "command", R.OFF_SEQUENCE: "sequence number", R.OFF_STATE: "state",
                 R.OFF_STROKE_CMD_1: "stroke command", R.OFF_TRACK_CORR_1: "tracking corrections",
                 R.OFF_CLEANLINESS: "cleanliness"}


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
            except Exception:  # noqa: BLE001 - closing a broken socket may fail; it is dropped anyway
                pass
            self._client = None
            self.reconnects += 1

    def hurry(self) -> None:
        """From now on two attempts per request, no back-off, a 1 s down window (the controller is stopping)."""
        self._hurry = True
        self.down_s = min(self.down_s, 1.0)
        self._down_until = min(self._down_until, self._monotonic() + self.down_s)

    def _call(self, what: str, fn: Callable[[ModbusTcpClient], object]):
        if self._monotonic() < self._down_until:
            raise PlantUnreachableError(f"plant {self.name}: {what} not sent: the plant did not answer a moment ago "
                             f"({self._down_reason})")
        delay = self.backoff_s
        last = "no attempt"
        attempts = min(2, self.retries + 1) if self._hurry else self.retries + 1
        for attempt in range(attempts):
            if attempt and not self._hurry:
                self._sleep(delay)
                delay = min(delay * 2, self.backoff_max_s)
            with self._lock:
                try:
                    rr = fn(self._connected())
                except (ModbusException, ConnectionError, OSError, TimeoutError) as exc:
                    last = f"{type(exc).__name__}: {exc}".strip()
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
            return rr
        self._down_until = self._monotonic() + self.down_s
        self._down_reason = last
        raise PlantUnreachableError(f"plant {self.name}: {what} failed after {attempts} attempt{'s' * (attempts > 1)} ({last})")

    def read(self, address: int, count: int, what: str) -> list[int]:
        """``count`` holding registers from ``address``; ``what`` names them in errors."""
        rr = self._call(f"read of {what} (address {address}, {count} registers)",
                        lambda c: c.read_holding_registers(address, count=count, device_id=self.unit))
        regs = list(rr.registers)
        if len(regs) < count:
            raise PlantError(f"plant {self.name}: read of {what} (address {address}) answered {len(regs)} of {count} registers")
        return regs[:count]

    def write(self, address: int, values: Sequence[int], what: str) -> None:
        """Write holding registers (function 6 for one, 16 for several)."""
        values = [int(v) & 0xFFFF for v in values]
        label = f"write of {what} (address {address})"
        if len(values) == 1:
            self._call(label, lambda c: c.write_register(address, values[0], device_id=self.unit))
        else:
            self._call(label, lambda c: c.write_registers(address, values, device_id=self.unit))

    def close(self) -> None:
        with self._lock:
            if self._client is not None:
                self._client.close()
                self._client = None


class ModbusPlant:
    """The plant's SCS and weather station over Modbus TCP; implements ``devices.protocols.Plant``.

    Parameters
    ----------
    endpoint : helicalib.config.Endpoint
        SCS ``host``, ``port``, ``unit``, ``timeout_s``.
    weather_endpoint : helicalib.config.Endpoint, optional
        Weather station (default: the SCS endpoint, same connection).
    heliostat_count : int, optional
        Expected number of heliostats (the field config's); a plant reporting another is refused.
    armed : bool
        Allow writes. False (default): every write raises :class:`PlantError` before anything is sent.
    heliostat_ids : sequence of str, optional
        Ids by block index, for messages.
    stroke_limits_mm : array_like, shape (N, 2, 2), optional
        ``[i, actuator, (min, max)]``: a stroke command outside is refused before it is sent (a
        second guard behind the controller's own check).
    retries, backoff_s, backoff_max_s, sleep :
        See :class:`ModbusLink`.
    """

    def __init__(self, endpoint, weather_endpoint=None, heliostat_count: int | None = None, *, armed: bool = False,
                 heliostat_ids: Sequence[str] | None = None, stroke_limits_mm=None, retries: int = 3,
                 backoff_s: float = 0.2, backoff_max_s: float = 5.0, sleep: Callable[[float], None] = time.sleep):
        kw = dict(retries=retries, backoff_s=backoff_s, backoff_max_s=backoff_max_s, sleep=sleep)
        self.scs = ModbusLink(endpoint.host, endpoint.port, endpoint.unit, endpoint.timeout_s, **kw)
        w = weather_endpoint
        if w is None or (w.host, w.port, w.unit) == (endpoint.host, endpoint.port, endpoint.unit):
            self.weather_link = self.scs
        else:
            self.weather_link = ModbusLink(w.host, w.port, w.unit, getattr(w, "timeout_s", endpoint.timeout_s), **kw)
        self.guard = CommandGuard(armed, heliostat_ids, stroke_limits_mm)
        self._expected_count = heliostat_count
        self._count: int | None = None
        self._last_sent: dict[int, int] = {}

    @classmethod
    def from_config(cls, cfg, *, armed: bool = False, register_map=None, **kw) -> "ModbusPlant":
        """The client of the plant a field config names, with its heliostat ids and stroke ranges."""
        g = CommandGuard.from_config(cfg, armed)
        return cls(cfg.plant.scs, cfg.plant.weather_endpoint, len(cfg.heliostats), armed=armed,
                   heliostat_ids=g.heliostat_ids, stroke_limits_mm=g.stroke_limits_mm, **kw)

    @property
    def armed(self) -> bool:
        return self.guard.armed

    def hurry(self) -> None:
        """Two attempts per request from now on, no back-off (a stopping controller must not wait out retries)."""
        self.scs.hurry()
        self.weather_link.hurry()

    def close(self) -> None:
        self.scs.close()
        if self.weather_link is not self.scs:
            self.weather_link.close()

    def __enter__(self) -> "ModbusPlant":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ helpers
    def _label(self, index: int) -> str:
        return self.guard.label(index)

    def _check_index(self, index: int) -> None:
        n = self.heliostat_count()
        if not 0 <= int(index) < n:
            raise PlantError(f"heliostat index {index} outside the plant's 0..{n - 1}")

    # ------------------------------------------------------------------ reads
    def interface_version(self) -> int:
        return self.scs.read(R.REG_VERSION, 1, "interface version")[0]

    def heliostat_count(self) -> int:
        """Heliostats the plant reports (checked once against the version and the expected count)."""
        if self._count is None:
            version, count = self.scs.read(R.REG_VERSION, 2, "interface version and heliostat count")
            if version != R.INTERFACE_VERSION:
                raise PlantError(f"plant {self.scs.name}: interface version {version}, helicalib speaks {R.INTERFACE_VERSION}")
            if self._expected_count is not None and count != self._expected_count:
                raise PlantError(f"plant {self.scs.name}: reports {count} heliostats, the field config has "
                                 f"{self._expected_count}; the block order must match the config")
            self._count = count
        return self._count

    def plant_time(self) -> tuple[float, float]:
        """(plant time [UTC s], rate)."""
        regs = self.scs.read(R.REG_PLANT_TIME, 6, "plant time and rate")
        t, rate = R.decode_f64(regs[0:4]), R.decode_f32(regs[4:6])
        if not (math.isfinite(t) and math.isfinite(rate) and rate > 0):
            raise PlantError(f"plant {self.scs.name}: plant time {t!r} / rate {rate!r} outside the contract")
        return t, rate

    def weather(self) -> Weather:
        """Wind, direction, DNI, temperature, pressure (weather block 100-109)."""
        regs = self.weather_link.read(R.WEATHER_BLOCK[0], R.WEATHER_BLOCK[1], "weather block")
        v = [R.decode_f32(regs[k:k + 2]) for k in range(0, 10, 2)]
        return Weather(wind_ms=v[0], wind_direction_deg=v[1], dni_wm2=v[2], temperature_c=v[3], pressure_hpa=v[4])

    def field_state(self) -> R.FieldState:
        value = self.scs.read(R.REG_FIELD_STATE, 1, "field state")[0]
        try:
            return R.FieldState(value)
        except ValueError:
            raise PlantError(f"plant {self.scs.name}: field state {value} outside the contract (0-2)") from None

    def _block(self, index: int) -> list[int]:
        self._check_index(index)
        return self.scs.read(R.heliostat_address(index), R.HELIOSTAT_USED, f"{self._label(index)} block")

    def status(self, index: int) -> HeliostatStatus:
        """State, last sequence processed, fault code, actual strokes, cleanliness of one heliostat."""
        regs = self._block(index)
        try:
            state = R.HeliostatState(regs[R.OFF_STATE])
        except ValueError:
            raise PlantError(f"plant {self.scs.name}: {self._label(index)} state {regs[R.OFF_STATE]} outside the contract (0-6)") from None
        s1 = R.decode_f32(regs[R.OFF_STROKE_ACT_1:R.OFF_STROKE_ACT_1 + 2])
        s2 = R.decode_f32(regs[R.OFF_STROKE_ACT_2:R.OFF_STROKE_ACT_2 + 2])
        clean = R.decode_f32(regs[R.OFF_CLEANLINESS:R.OFF_CLEANLINESS + 2])
        return HeliostatStatus(index=int(index), state=state, sequence_done=regs[R.OFF_SEQUENCE_DONE],
                               fault=regs[R.OFF_FAULT], strokes_mm=(s1, s2), cleanliness=clean)

    # ------------------------------------------------------------------ writes
    @property
    def stowed(self) -> bool:
        """Whether this client sent STOW ALL and no RESUME TRACKING since (moves and tracks are refused)."""
        return self.guard.stowed

    def field_command(self, command: int) -> None:
        """Field command: 1 stow all (from then on every move and track command is refused), 2 resume
        tracking all (the gate opens again)."""
        cmd = R.FieldCommand(int(command))
        self.guard.refuse_unarmed(f"field command {cmd.name}")
        with self.guard.lock:  # after the heliostat command in flight, before any waiting one
            self.scs.write(R.REG_FIELD_COMMAND, [int(cmd)], f"field command {cmd.name}")
            self.guard.field_sent(cmd)

    def _next_sequence(self, index: int, regs: list[int]) -> int:
        """A sequence number the plant sees as new: one past the register's value (and past ours)."""
        written, done = regs[R.OFF_SEQUENCE], regs[R.OFF_SEQUENCE_DONE]
        taken = {written, done, self._last_sent.get(index, -1)}
        seq = (written + 1) & 0xFFFF
        while seq in taken:
            seq = (seq + 1) & 0xFFFF
        return seq

    def _command(self, index: int, command: R.HeliostatCommand, fields: list[tuple[int, list[int], str]]) -> int:
        what = f"{command.name} command to {self._label(index)}"
        self.guard.refuse_unarmed(what)
        with self.guard.lock:
            self.guard.gate(command, what)
            regs = self._block(index)
            seq = self._next_sequence(index, regs)
            base = R.heliostat_address(index)
            for offset, values, name in fields:
                self.scs.write(base + offset, values, f"{self._label(index)} {name}")
            self.scs.write(base + R.OFF_COMMAND, [int(command)], f"{self._label(index)} command {command.name}")
            self.scs.write(base + R.OFF_SEQUENCE, [seq], f"{self._label(index)} sequence number")
            self._last_sent[index] = seq
        return seq

    def move_to(self, index: int, strokes_mm) -> int:
        """Command strokes (actuator 1, 2) [mm] and hold; returns the sequence number sent.

        Non-finite strokes, and strokes outside ``stroke_limits_mm`` when given, are refused
        with a :class:`PlantError` before anything is written.
        """
        s = self.guard.strokes(index, strokes_mm)
        return self._command(index, R.HeliostatCommand.MOVE,
                             [(R.OFF_STROKE_CMD_1, R.encode_f32(s[0]) + R.encode_f32(s[1]), "stroke command")])

    def track(self, index: int, corrections_mm) -> int:
        """Return to tracking with these stroke corrections (actuator 1, 2) [mm]; returns the sequence number.

        ``corrections_mm=None`` leaves the correction registers as they are: the plant tracks with
        the corrections it already has (never wipe a plant's corrections by accident).
        """
        if corrections_mm is None:
            return self._command(index, R.HeliostatCommand.TRACK, [])
        c = self.guard.corrections(index, corrections_mm)
        return self._command(index, R.HeliostatCommand.TRACK,
                             [(R.OFF_TRACK_CORR_1, R.encode_f32(c[0]) + R.encode_f32(c[1]), "tracking corrections")])

    def stow(self, index: int) -> int:
        """Send one heliostat to stow; returns the sequence number."""
        return self._command(index, R.HeliostatCommand.STOW, [])
