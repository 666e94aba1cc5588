"""What the controller needs from a plant, a camera and a clock.

Real devices (Modbus TCP + HTTP) and the in-process simulated plant both implement these
protocols; the controller cannot tell them apart. Times are plant time in UTC seconds.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from helicalib.devices.registers import FieldState, HeliostatState
from helicalib.errors import MeasurementError, PlantError


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
    """Read-back of one heliostat: ``sequence_done`` is the token of the last command the plant took
    or refused (the last sequence number processed, or its command counter)."""

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
    exposure_ms: float | None = None
    """The exposure the camera applied [ms] (PLANT_INTERFACE 1.1 ``X-Exposure-Ms``); None: a camera
    that cannot set its exposure."""


@runtime_checkable
class Clock(Protocol):
    """Plant time. ``sleep`` waits for plant seconds (a virtual clock just advances).

    ``estimate_s`` never asks the plant (the controller's own extrapolation, for records made
    while the plant does not answer); ``uncertainty_s`` is how far ``now_s`` may be off [plant s];
    ``rate`` is plant seconds per real second (0: a virtual clock that runs as fast as it can)."""

    uncertainty_s: float
    rate: float

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
        """Command strokes (mm, actuator 1 and 2) and hold; returns the command's token: the value
        :meth:`status` shows in ``sequence_done`` once the plant took (or refused) it (the sequence
        number sent, or the plant's command counter after it, by the plant's handshake)."""
        ...

    def track(self, index: int, corrections_mm: np.ndarray | None) -> int:
        """Return to tracking with these stroke corrections [mm] (None: keep the plant's); returns the token."""
        ...

    def stow(self, index: int) -> int: ...


@runtime_checkable
class Camera(Protocol):
    """A target camera."""

    def grab(self, exposure_ms: float | None = None) -> Frame:
        """The current frame, taken at ``exposure_ms`` when given and the camera can set its exposure
        (clamped to its range; ``Frame.exposure_ms`` says what was applied; a camera that cannot
        ignores it); raises :class:`helicalib.errors.MeasurementError` or ``PlantError`` on failure."""
        ...


# ---------------------------------------------------------------------------------------------
# The spot sensor: where a visit gets its spot measurements from (a camera and the vision, or a
# simulated sensor without frames); :mod:`helicalib.campaign.sensor` holds the camera-backed one
# ---------------------------------------------------------------------------------------------


@dataclass
class Before:
    """The reference taken with the beam at standby: its capture time, its frame (to store; None
    for a sensor without frames) and what the sensor keeps for the measurement (``state``)."""

    capture_time_s: float
    data: bytes | None = None
    state: object = None


@dataclass(frozen=True)
class Reading:
    """One spot measurement.

    ``offset_m`` is the spot centre (u, v) on the board from its centre [m, target frame], also
    for a ``clipped`` spot (the visible part's centroid, which leads a search); None when there is
    no spot. ``frames`` are the after frames to store with the observation.
    """

    valid: bool
    reason: str
    message: str
    capture_time_s: float
    offset_m: tuple[float, float] | None = None
    spot_px: tuple[float, float] | None = None
    spot_area_px: float | None = None
    threshold: float | None = None
    frames: tuple[bytes, ...] = ()
    before_beam: bool = False
    """The before frame held another beam (an ``ambient_change`` a new before frame may mend)."""
    state: object = field(default=None, compare=False)


@runtime_checkable
class SpotSensor(Protocol):
    """What a visit measures with. ``ctx`` is the visit's :class:`~helicalib.campaign.visit_types.VisitContext`."""

    def before(self, ctx) -> Before:
        """The reference with the beam off the board. Raises :class:`MeasurementError` (reason
        code in ``.reason``) when there is none to be had."""

    def after(self, ctx, before: Before) -> Generator[float, None, Reading]:
        """The spot with the heliostat holding on the board; yields the plant seconds it waits
        between frames; never raises for a bad frame (an invalid reading says why)."""

    def cleanliness(self, ctx, before: Before, reading: Reading, held_mm: np.ndarray, weather,
                    sun_enu: np.ndarray) -> float | None:
        """The mirror's present cleanliness from a valid reading, or None when it cannot be told."""

    def retake(self, ctx, before: Before, reading: Reading) -> tuple[Before, Reading]:
        """A new before frame, taken with the beam at its standby point, and ``reading``'s after
        frames judged against it (a reading whose before frame held another beam)."""


class CaptureTimeError(MeasurementError):
    """A frame whose capture time disagrees with the plant clock; the frame is kept for the record."""

    reason = "capture_time"

    def __init__(self, message: str, frame):
        super().__init__(message)
        self.frame = frame


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
class ParallelTracking(Protocol):
    """A plant client that sends the track commands of many heliostats several at a time (the Modbus
    client, over connections of its own): each the same command as :meth:`Plant.track`."""

    def send_tracks(self, items):
        """Track commands for distinct heliostats ``items`` ``[(index, corrections_mm), ...]`` sent
        while the caller goes on; the answer's ``done()`` says whether all were answered, its
        ``results()`` (waiting for them) per item, in order, None (taken) or the
        :class:`~helicalib.errors.PlantError` that refused it, and its ``direct`` why they went one
        at a time on the plant's own connection (None: they did not)."""
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
    parallel_tracking: bool = False
    bulk_cleanliness: bool = False
    hurries: bool = False


def abilities_of(plant: object) -> PlantAbilities:
    """The optional abilities ``plant`` declares (its methods, by the protocols above)."""
    return PlantAbilities(bulk_tracking=isinstance(plant, BulkTracking),
                          parallel_tracking=isinstance(plant, ParallelTracking),
                          bulk_cleanliness=isinstance(plant, BulkCleanliness),
                          hurries=isinstance(plant, Hurries))
