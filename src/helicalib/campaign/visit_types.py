"""What a visit is given and what it gives back: its settings, its context, its host, its outcome.

A visit (:mod:`.visit`) runs on a :class:`VisitContext`: the heliostat, its board, the devices it
talks to (the plant, the board's spot sensor), the plant clock and the sun, the model it aims with,
and what it has done so far (the last commanded and held strokes, the backlash side each actuator
sits on, whether the beam is on the board). What it needs from the campaign (store an
observation or a frame, refit the model, the tracking corrections to leave with) it asks of a
:class:`VisitHost`, which the campaign loop implements (:mod:`.loop`). It ends with a
:class:`VisitOutcome`, whose :class:`Left` says how the heliostat left the board.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from helicalib.campaign.board import Board
from helicalib.devices.protocols import Plant, SpotSensor
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.store.records import Observation


@dataclass(frozen=True)
class VisitSettings:
    """What a visit needs from the field config."""

    loop_threshold_mrad: float
    max_iterations: int
    after_frames: int
    spot_method: str
    settle_timeout_s: float
    search_steps: int = 6
    reflectivity_clean: float = 0.93
    approach_mm: float = 1.0
    """Length of the last move of each actuator in its tracking direction, to take up backlash
    (0 = arrive from wherever the previous hold was)."""
    max_jitter_mrad: float = 2.0
    """With several after frames: their spot centres' RMS spread, as an angle seen from the
    heliostat, above which the measurement is refused ("jitter")."""
    max_capture_skew_s: float = 5.0
    """A frame whose capture time lies further than this outside the plant time around its grab
    is refused ("capture_time") [plant s]: its sun would be another sun."""
    band_deg: tuple[float, float] | None = None
    """The acceptance's low band (sun elevation [deg]): a valid point taken while the sun is in it
    ends the visit (``band point``), the board's scarce band time going to the next heliostat's
    band point rather than to a second placement; None: every visit runs its loop to the end."""

    @classmethod
    def from_config(cls, cfg) -> VisitSettings:
        c = cfg.calibration
        return cls(c.loop_threshold_mrad, c.max_iterations, c.after_frames, c.spot_method, c.settle_timeout_s,
                   reflectivity_clean=c.reflectivity_clean, approach_mm=c.approach_mm,
                   max_jitter_mrad=c.max_jitter_mrad, max_capture_skew_s=c.max_capture_skew_s,
                   band_deg=tuple(float(x) for x in cfg.acceptance.low_band_deg))


@dataclass
class VisitContext:
    """Everything one visit touches. ``sun(t_s) -> (vector_enu (3,), azimuth_deg, elevation_deg, rising)``."""

    campaign_id: int
    visit_id: int
    heliostat_id: str
    index: int
    target: object
    sensor: SpotSensor
    plant: Plant
    now: Callable[[], float]
    sun: Callable[[float], tuple[np.ndarray, float, float, bool]]
    model: HeliostatModel
    settings: VisitSettings
    host: VisitHost
    """The campaign's side: the store's writes, the refits, the corrections to leave with."""
    last_strokes_mm: np.ndarray | None = None
    held_mm: np.ndarray | None = None
    """Read-back strokes of the last hold [mm] (None before the first)."""
    approach: np.ndarray | None = None
    """Direction (2,) of each actuator's last motion (±1; 0 not known) after the last hold: where
    the backlash left the mirror. Recorded with each observation for the error model's dead bands."""
    before_path: str | None = None
    time_slack_s: Callable[[], float] | None = None
    """How far the plant time read by ``now`` may be off [plant s] (the clock's uncertainty),
    added to the capture-time tolerance."""
    board: Board | None = None
    """The board shared with other visits (its frame lock); None: the visit is alone."""
    on_board: bool = False
    """True while the beam was last commanded onto the board (False at standby or tracking)."""


class VisitHost(Protocol):
    """What a visit asks of the campaign that runs it (the campaign loop implements it).

    Each call may raise (a database that cannot be written): the visit then records what it can
    and leaves the board."""

    def record(self, ctx: VisitContext, observation: Observation, frames: dict) -> int:
        """Store ``observation`` (its frames first: ``before_frame`` and/or ``after_frames``);
        returns its id."""

    def save_frame(self, ctx: VisitContext, data: bytes, iteration: int, capture_time_s: float, kind: str) -> str:
        """Store one frame of the visit; returns its stored path."""

    def refit(self, ctx: VisitContext, observation: Observation) -> HeliostatModel:
        """A valid observation of the visit's heliostat: add it to its points and refit; returns
        the model the visit goes on with."""

    def corrections(self, ctx: VisitContext, model: HeliostatModel, stopping: bool) -> np.ndarray | None:
        """The tracking stroke corrections [mm] to write with the track command as the visit
        leaves with ``model`` (``stopping``: the campaign stops; the corrections last written);
        None: the plant keeps its own."""


@dataclass(frozen=True)
class Left:
    """How a heliostat left the board: ``error`` is None when the plant took the command back to
    tracking (whether it reached state 1 is confirmed by the runner), else what failed;
    ``corrections_mm`` are the tracking corrections sent with that command (None: the plant keeps
    its own), written if ``error`` is None."""

    error: str | None = None
    corrections_mm: np.ndarray | None = None


@dataclass
class VisitOutcome:
    """How a visit ended: ``status`` is converged | not_converged | invalid | refused | fault,
    ``reason`` its reason code or one line; the placements with a valid measurement
    (``iterations``, ``valid_points``), the first and last tracking error [mrad], every
    observation recorded, the model the visit ended with, and how it left the board."""

    status: str
    reason: str
    iterations: int = 0
    valid_points: int = 0
    first_error_mrad: float | None = None
    final_error_mrad: float | None = None
    observations: list[Observation] = field(default_factory=list)
    model: HeliostatModel | None = None
    left: Left | None = None
    """How the heliostat left the board (None: the visit has not left it)."""

    def end(self, status: str, reason: str) -> None:
        """The visit ends with ``status`` for ``reason``."""
        self.status, self.reason = status, reason
