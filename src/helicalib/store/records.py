"""Frozen records the store writes and reads back: one dataclass per table row.

Every field carries its unit in its name. Rows read back from the store are the same
dataclasses with ``id`` (and, for observations, the frame paths) filled in.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Campaign:
    """One calibration campaign (a ``run``, ``check`` or ``simulate``).

    Attributes
    ----------
    id : int
        Row id.
    name : str
        Free label (e.g. the field config's file name).
    mode : str
        ``'live'``, ``'check'``, ``'simulate'`` or any label the caller chooses.
    started_s, ended_s : float, float or None
        Plant time [UTC s]; ``ended_s`` is None while the campaign is unfinished.
    status : str
        ``'running'`` until :meth:`Store.finish_campaign` sets ``'finished'`` (or another word).
    config_path, config_sha256 : str
        The field config the campaign was started with and the SHA-256 of its text.
    settings : dict
        JSON-serialisable settings of the run (seed, --heliostats, armed, ...).
    """

    id: int
    name: str
    mode: str
    started_s: float
    ended_s: float | None
    status: str
    config_path: str
    config_sha256: str
    settings: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class CampaignHeliostat:
    """A heliostat enrolled in a campaign: its plant block index and calibration target."""

    heliostat_id: str
    block_index: int
    target_id: str


@dataclass(frozen=True)
class Visit:
    """One heliostat's stay on one target (paper 2.3.2): one or more loop iterations.

    ``outcome`` is ``'running'`` until :meth:`Store.end_visit`; then one of the visit loop's
    outcomes (``docs/running.md``): ``'converged'``, ``'not_converged'``, ``'invalid'``,
    ``'refused'``, ``'fault'``, ``'aborted'`` (stow, campaign stop) or ``'interrupted'`` (the
    process died during the visit; set on resume).
    """

    id: int
    campaign_id: int
    heliostat_id: str
    target_id: str
    started_s: float
    ended_s: float | None
    outcome: str
    reason: str
    iterations: int
    first_error_mrad: float | None
    final_error_mrad: float | None


@dataclass(frozen=True)
class Observation:
    """One measurement attempt, valid or not: everything needed to refit or audit it later.

    Attributes
    ----------
    campaign_id, heliostat_id, target_id : int, str, str
    visit_id : int or None
        The visit it belongs to.
    iteration : int
        0 for the model's first placement, 1.. for each loop correction.
    capture_time_s : float
        Capture time of the "after" frame, plant time [UTC s]. The measurement belongs to this
        time and to ``strokes_read_mm``.
    strokes_cmd_mm, strokes_read_mm : (float, float), (float, float) or None
        Strokes commanded and read back (actuator 1, 2) [mm].
    approach : (int, int) or None
        Direction of each actuator's last motion before this hold (+1 extending, −1 retracting, 0
        not known): where the backlash left the mirror. None when not recorded.
    sun_enu : (float, float, float)
        Unit sun vector at ``capture_time_s``, ENU.
    sun_azimuth_deg, sun_elevation_deg : float
        Apparent sun position [deg].
    sun_rising : bool or None
        True before solar noon (elevation increasing), False after, None if unknown.
    wind_ms, wind_direction_deg, dni_wm2, temperature_c, cleanliness : float or None
        Conditions at the capture [m/s, deg from north, W/m², °C, 0..1]; ``cleanliness`` is the
        plant's register.
    cleanliness_measured : float or None
        The mirror's cleanliness measured from this observation's spot (measured against expected
        power, :func:`helicalib.flux.visit.cleanliness_from_visit`) [-]; None when not estimated.
    exposure_ms : float or None
        The exposure the camera applied to the reading's frames [ms] (PLANT_INTERFACE 1.1); None for
        a camera that cannot set its exposure.
    valid : bool
        Whether the spot gave a usable tracking error.
    reason : str
        Reason code (``'ok'`` when valid; e.g. ``'no_spot'``, ``'camera_timeout'``, ``'plant_fault'``).
    message : str
        One readable sentence about the result.
    offset_u_m, offset_v_m : float or None
        Spot centre minus aim point in the target frame [m].
    spot_x_px, spot_y_px, spot_area_px, threshold, jitter_px : float or None
        Spot centre in the image [px], its area [px²], the segmentation threshold [grey level],
        the centre's jitter over the "after" frames [px].
    spot_enu_m : (float, float, float) or None
        Spot centre on the target plane, ENU [m].
    error_mrad : float or None
        Tracking error (T/GRLM 02-2014 formula 1) [mrad].
    before_frame_path, after_frame_paths : str or None, tuple of str
        Frame files relative to the store's images directory (filled by the store).
    id : int or None
        Row id (filled by the store).
    """

    campaign_id: int
    heliostat_id: str
    target_id: str
    visit_id: int | None
    iteration: int
    capture_time_s: float
    strokes_cmd_mm: tuple[float, float]
    strokes_read_mm: tuple[float, float] | None
    sun_enu: tuple[float, float, float]
    sun_azimuth_deg: float
    sun_elevation_deg: float
    valid: bool
    reason: str = "ok"
    message: str = ""
    sun_rising: bool | None = None
    wind_ms: float | None = None
    wind_direction_deg: float | None = None
    dni_wm2: float | None = None
    temperature_c: float | None = None
    cleanliness: float | None = None
    cleanliness_measured: float | None = None
    exposure_ms: float | None = None
    offset_u_m: float | None = None
    offset_v_m: float | None = None
    spot_x_px: float | None = None
    spot_y_px: float | None = None
    spot_area_px: float | None = None
    threshold: float | None = None
    jitter_px: float | None = None
    spot_enu_m: tuple[float, float, float] | None = None
    error_mrad: float | None = None
    before_frame_path: str | None = None
    after_frame_paths: tuple[str, ...] = ()
    approach: tuple[int, int] | None = None
    id: int | None = None

    @property
    def after_frame_path(self) -> str | None:
        """The first "after" frame's path, or None."""
        return self.after_frame_paths[0] if self.after_frame_paths else None


@dataclass(frozen=True)
class Fit:
    """One error-model fit of a heliostat: named parameters, their 1-sigma, residual RMS."""

    id: int
    campaign_id: int
    heliostat_id: str
    time_s: float
    model: str
    params: dict[str, float]
    sigma: dict[str, float]
    rms_mrad: float
    n_points: int


@dataclass(frozen=True)
class Verdict:
    """One acceptance verdict (paper 2.4) with the reasons it was (not) accepted."""

    id: int
    campaign_id: int
    heliostat_id: str
    time_s: float
    accepted: bool
    n_points: int
    rms_mrad: float | None
    reasons: tuple[str, ...]
    details: dict[str, Any] = field(default_factory=dict)


EVENT_KINDS = ("start", "stop", "stow", "resume", "gated", "ungated", "fault", "note", "tracking_written")
"""Usual event kinds; any short word is accepted."""


@dataclass(frozen=True)
class Event:
    """A campaign event (stow, resume, gated, fault, ...) at a plant time, with its reason."""

    id: int
    campaign_id: int
    time_s: float
    kind: str
    reason: str
    heliostat_id: str | None = None
    data: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class OperatorAction:
    """A crew's request from the console (:mod:`helicalib.console`), applied by the runner.

    ``kind`` is ``'pause'``, ``'resume'``, ``'recheck'``, ``'repaired'``, ``'out_of_service'`` or
    ``'in_service'``; ``who`` the name the operator gave with the address the request came from;
    ``requested_wall_s`` the controller's wall clock, ``requested_s`` plant time (None when the
    plant clock could not be read); ``done_s`` the plant time the runner applied it (None while
    pending) and ``outcome`` what it did."""

    id: int
    campaign_id: int
    kind: str
    heliostat_ids: tuple[str, ...]
    who: str
    requested_wall_s: float
    requested_s: float | None
    done_s: float | None = None
    outcome: str = ""


def off_tracking(events) -> list[str]:
    """Heliostats left off tracking: those whose newest ``off_tracking`` event has no
    ``back_to_tracking`` recorded after it (a run that stopped before the plant confirmed their
    return; the next run sends them back first).

    "After" is the order the events were recorded (their row ids; the given order for events
    without one), never their plant times: a plant restarted with its clock earlier stamps the
    confirming ``back_to_tracking`` events before the ``off_tracking`` ones they answer."""
    last: dict[str, str] = {}
    order = sorted(enumerate(events), key=lambda ie: (0, ie[1].id, ie[0]) if ie[1].id is not None else (1, 0, ie[0]))
    for _i, e in order:
        if e.kind in ("off_tracking", "back_to_tracking") and e.heliostat_id:
            last[e.heliostat_id] = e.kind
    return sorted(h for h, k in last.items() if k == "off_tracking")
