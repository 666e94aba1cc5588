"""What the controller needs from a plant, a camera and a clock.

Real devices (Modbus TCP + HTTP) and the in-process simulated plant both implement these
protocols; the controller cannot tell them apart. Times are plant time in UTC seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from helicalib.devices.registers import FieldState, HeliostatState
from helicalib.errors import PlantError


class PlantUnreachableError(PlantError):
    """The plant did not answer (connection refused or lost, timeouts, every attempt failed). A
    plant that answered with a refusal (a Modbus exception reply) raises a plain
    :class:`~helicalib.errors.PlantError`: it is reachable."""


class FieldStowedError(PlantError):
    """A move or track command the plant client refused because this controller stowed the field
    for wind (the plant answered nothing: nothing was sent)."""


@dataclass(frozen=True)
class Weather:
    """One weather reading (PLANT_INTERFACE weather block)."""

    wind_ms: float
    wind_direction_deg: float
    dni_wm2: float
    temperature_c: float
    pressure_hpa: float


@dataclass(frozen=True)
class HeliostatStatus:
    """Read-back of one heliostat block."""

    index: int
    state: HeliostatState
    sequence_done: int
    fault: int
    strokes_mm: tuple[float, float]
    cleanliness: float


@dataclass(frozen=True)
class Frame:
    """One camera frame: the raw body, the capture time in plant time, and where it came from."""

    data: bytes
    capture_time_s: float
    source: str


@runtime_checkable
class Clock(Protocol):
    """Plant time. ``sleep`` waits for plant seconds (a virtual clock just advances).

    ``estimate_s`` never asks the plant (the controller's own extrapolation, for records made
    while the plant does not answer); ``uncertainty_s`` is how far ``now_s`` may be off [plant s]."""

    uncertainty_s: float

    def now_s(self) -> float: ...

    def estimate_s(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


@runtime_checkable
class Plant(Protocol):
    """The solar field control system and its weather station."""

    def heliostat_count(self) -> int: ...

    def plant_time(self) -> tuple[float, float]:
        """(plant time [UTC s], rate)."""
        ...

    def weather(self) -> Weather: ...

    def field_state(self) -> FieldState: ...

    def field_command(self, command: int) -> None: ...

    def status(self, index: int) -> HeliostatStatus: ...

    def move_to(self, index: int, strokes_mm: np.ndarray) -> int:
        """Command strokes (mm, actuator 1 and 2) and hold; returns the sequence number sent."""
        ...

    def track(self, index: int, corrections_mm: np.ndarray | None) -> int:
        """Return to tracking with these stroke corrections [mm] (None: keep the plant's); returns the sequence number."""
        ...

    def stow(self, index: int) -> int: ...


@runtime_checkable
class Camera(Protocol):
    """A target camera."""

    def grab(self) -> Frame:
        """The current frame; raises :class:`helicalib.errors.MeasurementError` or ``PlantError`` on failure."""
        ...


# ---------------------------------------------------------------------------------------------
# Optional abilities a plant declares (checked once when a campaign is built, never in its loop)
# ---------------------------------------------------------------------------------------------


@runtime_checkable
class BulkTracking(Protocol):
    """A plant that takes the track command of many heliostats in one write (the in-process
    simulated plant): the same registers and state as one :meth:`Plant.track` per heliostat."""

    def track_many(self, indices, corrections_mm: np.ndarray) -> np.ndarray:
        """Track commands for distinct ``indices`` (k,) with ``corrections_mm`` (k, 2) [mm];
        returns the sequence numbers (k,)."""
        ...


@runtime_checkable
class BulkCleanliness(Protocol):
    """A plant that reads the cleanliness registers of many heliostats in one read: what
    :meth:`Plant.status` gives for each."""

    def cleanliness_many(self, indices) -> np.ndarray:
        """Cleanliness (k,) of heliostats ``indices`` (k,) now."""
        ...


@runtime_checkable
class Hurries(Protocol):
    """A plant link whose retries can be cut short when the controller is stopping."""

    def hurry(self) -> None:
        """From now on few attempts per request and no back-off."""
        ...


@dataclass(frozen=True)
class PlantAbilities:
    """What a plant offers beyond :class:`Plant`, read once from the object (``abilities_of``)."""

    bulk_tracking: bool = False
    bulk_cleanliness: bool = False
    hurries: bool = False


def abilities_of(plant: object) -> PlantAbilities:
    """The optional abilities ``plant`` declares (its methods, by the protocols above)."""
    return PlantAbilities(bulk_tracking=isinstance(plant, BulkTracking),
                          bulk_cleanliness=isinstance(plant, BulkCleanliness),
                          hurries=isinstance(plant, Hurries))
