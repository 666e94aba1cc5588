"""What a running campaign tells its crew: events, and snapshots of its state.

The runner publishes every event to its listeners after the fact (the live terminal view, the
JSON-lines stream of ``--json``, the plain log lines of a service); the lasting ones also go to
the store's ``events`` table (:data:`STORED`), the rest are already rows of their own (visits,
observations, verdicts). A :class:`Snapshot` is the state a view draws: boards, gate, counts.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import asdict, dataclass, field
from typing import Any

from helicalib.devices.clock import iso_utc  # noqa: F401 - the one UTC formatter, re-exported for the views

STORED = frozenset({"stow", "resume", "gated", "ungated", "fault", "note", "tracking_written", "off_tracking",
                    "back_to_tracking", "campaign", "operator", "drift", "check", "plant_lost", "plant_back"})
"""Event kinds written to the store's events table (the others live in their own tables)."""

KINDS = {
    "campaign": "the campaign starts, resumes or stops",
    "opening": "how far a resumed campaign's reading back has come (every 5 s while it takes longer)",
    "stow": "the field is stowed for wind",
    "resume": "the field tracks again after a stow",
    "gated": "calibration paused (wind, DNI): the reason says which",
    "ungated": "calibration allowed again",
    "note": "a decision recorded (e.g. what a run without --arm would have sent)",
    "fault": "something failed; the reason names the heliostat, register or camera",
    "visit": "a heliostat goes onto a board",
    "measurement": "one spot measured (valid or not, with its reason)",
    "visit_end": "a visit ended: converged, not_converged, invalid, refused, fault or aborted",
    "verdict": "a heliostat's acceptance changed",
    "tracking_written": "tracking corrections written to the plant (after the plant took them)",
    "off_tracking": "a heliostat could not be returned to tracking: retried until the plant confirms",
    "back_to_tracking": "the plant confirms a heliostat tracks again after a failed return",
    "check": "operation: a visit is a check of a calibrated heliostat (its visit id and after frames)",
    "drift": "operation: a heliostat's checks lie outside its model's band: drift confirmed, calibration reopened",
    "operator": "a crew's action from the console applied (pause, resume, re-check, repaired, out of service)",
    "plant_lost": "the plant stopped answering: no visit starts, the readings shown grow old (one line per loss)",
    "plant_back": "the plant answers again after a loss (one line, with how long it was lost)",
    "status": "a periodic snapshot (JSON lines only)",
    "summary": "the final summary (JSON lines only)",
}
"""Every event kind, with what it means (``docs/running.md`` lists them)."""


@dataclass(frozen=True)
class RunEvent:
    """One thing that happened, stamped with plant time.

    ``clock`` is ``"plant"``, or ``"controller"`` when the plant's clock could not be read and the
    controller's own extrapolation of it was used instead.
    """

    time_s: float
    kind: str
    reason: str
    heliostat_id: str | None = None
    target_id: str | None = None
    data: dict[str, Any] = field(default_factory=dict)
    clock: str = "plant"

    def to_json(self, tz: dt.tzinfo | None = None) -> dict[str, Any]:
        """A flat dict for one JSON line: ``event``, ``time`` (ISO UTC), ``local`` (site time), ``time_s``, ..."""
        out: dict[str, Any] = {"event": self.kind, "time": iso_utc(self.time_s)}
        if tz is not None:
            out["local"] = iso_local(self.time_s, tz)
        out.update(time_s=round(self.time_s, 3), reason=self.reason)
        if self.heliostat_id is not None:
            out["heliostat"] = self.heliostat_id
        if self.target_id is not None:
            out["target"] = self.target_id
        if self.clock != "plant":
            out["clock"] = self.clock
        out.update({k: _jsonable(v) for k, v in self.data.items()})
        return out


@dataclass(frozen=True)
class BoardState:
    """One board (target) as a view draws it."""

    target_id: str
    heliostat_id: str | None = None
    iteration: int | None = None
    last_error_mrad: float | None = None
    since_s: float | None = None
    others: tuple[str, ...] = ()
    """The other visits on the board at the same time (waiting at its standby point or leaving)."""


@dataclass(frozen=True)
class Snapshot:
    """The campaign's state at one plant time (a view's frame; a ``status`` JSON line)."""

    time_s: float
    campaign_id: int
    armed: bool
    rate: float
    boards: tuple[BoardState, ...]
    wind_ms: float | None
    dni_wm2: float | None
    stowed: bool
    gate_open: bool | None
    gate_reason: str
    night: bool
    sun_elevation_deg: float
    heliostats: int
    accepted: int
    in_progress: int
    waiting: int
    visits: int
    valid_visits: int
    next_band: str
    off_tracking: tuple[str, ...] = ()
    plant_unreachable_since_s: float | None = None
    """Plant time (the controller's estimate) since which the plant has not answered; None while it answers."""
    weather_time_s: float | None = None
    """Plant time of the weather reading behind ``wind_ms``, ``dni_wm2`` and the gate (its age is shown)."""

    def to_json(self, tz: dt.tzinfo | None = None) -> dict[str, Any]:
        out = {"event": "status", "time": iso_utc(self.time_s)}
        if tz is not None:
            out["local"] = iso_local(self.time_s, tz)
        body = asdict(self)
        body["boards"] = [asdict(b) for b in self.boards]
        body["off_tracking"] = list(self.off_tracking)
        out.update({k: _jsonable(v) for k, v in body.items()})
        return out


def iso_local(t_s: float, tz: dt.tzinfo) -> str:
    return dt.datetime.fromtimestamp(float(t_s), tz=tz).isoformat(timespec="seconds")


def _jsonable(v):
    if isinstance(v, float):
        return None if not math.isfinite(v) else round(v, 4)
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if hasattr(v, "item"):  # numpy scalars
        return _jsonable(v.item())
    return v
