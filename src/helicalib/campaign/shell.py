"""What the outside reads of a running campaign: the runner's names over its state and parts.

:class:`RunnerShell` gives the composition roots (:mod:`helicalib.app`), the web console and the
tests the names they use (``runner.book``, ``runner.stowed``, ``runner.event(...)``,
``runner.plant_failed(...)``, ...), each a plain pass-through to the
:class:`~.state.CampaignState`, the :class:`~.state.CampaignDevices` or one of the parts
(:mod:`.journal`, :mod:`.field`, :mod:`.tracking`, :mod:`.operation.checks`). It holds no state
of its own. It is also the narrow interface operation's checks and the crew's desk work through
(:class:`~.operation.checks.CheckHost`, :class:`~.operation.crew.CrewHost`).
"""

from __future__ import annotations

import numpy as np

from helicalib.geometry.heliostat import HeliostatModel


def _of(part: str, name: str, doc: str = "", writable: bool = True) -> property:
    """A property reading (and writing) ``self.<part>.<name>``."""
    def get(self):
        return getattr(getattr(self, part), name)

    def put(self, value):
        setattr(getattr(self, part), name, value)

    return property(get, put if writable else None, doc=doc or f"``{part}.{name}``")


class RunnerShell:
    """The public names of a campaign runner (module docstring). Subclassed by
    :class:`~.loop.CampaignRunner`, which sets ``state``, ``devices``, ``journal``, ``field``,
    ``tracking`` and ``ops``."""

    # the devices
    plant = _of("devices", "plant", writable=False)
    clock = _of("devices", "clock", writable=False)
    store = _of("devices", "store", writable=False)
    sensors = _of("devices", "sensors", writable=False)
    # what was asked
    ids = _of("state", "ids", writable=False)
    armed = _of("state", "armed", writable=False)
    recheck = _of("state", "recheck", writable=False)
    operation = _of("state", "operation", writable=False)
    planner_kind = _of("state", "planner_kind", writable=False)
    spots_per_board = _of("state", "spots_per_board", writable=False)
    settings = _of("state", "settings", writable=False)
    check_settings = _of("state", "check_settings", writable=False)
    # what it knows and holds
    sun_table = _of("state", "sun_table", writable=False)
    nominal = _of("state", "nominal", writable=False)
    models = _of("state", "models", writable=False)
    book = _of("state", "book", writable=False)
    boards = _of("state", "boards", writable=False)
    corrections = _of("state", "corrections", writable=False)
    stats = _of("state", "stats", writable=False)
    active = _of("state", "active", writable=False)
    returning = _of("state", "returning", writable=False)
    _home = _of("state", "home", writable=False)
    _guests = _of("state", "guests", writable=False)
    stowed = _of("state", "stowed")
    last_weather = _of("state", "last_weather")
    weather_time_s = _of("state", "weather_time_s")
    last_poll_s = _of("state", "last_poll_s")
    _last_gate = _of("state", "last_gate")
    operator = _of("state", "operator")
    stopping = _of("state", "stopping")
    retention = _of("state", "retention")
    state_lock = _of("state", "lock", writable=False)
    # faults
    plant_unreachable_since_s = _of("_faults", "plant_unreachable_since_s")
    job_fault = _of("_faults", "job_fault", writable=False)
    clock_jump = _of("_faults", "clock_jump")
    clock_jump_hint = _of("_faults", "clock_jump_hint")
    storage_errors = _of("_faults", "storage_errors")
    storage_lost = _of("_faults", "storage_lost")
    listeners = _of("journal", "listeners", writable=False)

    @property
    def _faults(self):
        return self.state.faults

    # ------------------------------------------------------------------ time, sun, events, faults
    def sun(self, t_s: float):
        """(vector_enu, azimuth_deg, elevation_deg, rising) at plant time ``t_s`` (SPA, tabulated)."""
        return self.state.sun_table.position(t_s)

    def now(self) -> float:
        return self.journal.now()

    def safe_now(self) -> tuple[float, str]:
        return self.journal.safe_now()

    def event(self, kind: str, reason: str, heliostat_id: str | None = None, target_id: str | None = None,
              data: dict | None = None, time_s: float | None = None):
        return self.journal.event(kind, reason, heliostat_id, target_id, data=data, time_s=time_s)

    def plant_failed(self, err, link: str = "scs") -> bool:
        return self.journal.plant_failed(err, link)

    def plant_answered(self, now: float, link: str = "scs") -> None:
        self.journal.plant_answered(now, link)

    def job_failed(self, job: str, reason: str, time_s: float | None = None) -> None:
        self.journal.job_failed(job, reason, time_s)

    def said_once(self, job: str) -> bool:
        return self.journal.said_once(job)

    def probe_scs(self, now: float) -> None:
        self.journal.probe_scs(now)

    def storage_fault(self, err: BaseException) -> bool:
        return self.journal.storage_fault(err)

    def storage_failed(self, err) -> None:
        self.journal.storage_failed(err)

    def clock_jumped(self, err) -> None:
        self.journal.clock_jumped(err)

    # ------------------------------------------------------------------ jobs the live clock calls
    def _poll_weather(self, now: float, preempt: bool = False) -> None:
        self.field.poll_weather(now, preempt)

    def _refresh_tracking(self, now: float) -> None:
        self.tracking.refresh(now)

    def _send_back(self, hid: str, corrections, now: float, why: str) -> None:
        self.tracking.send_back(hid, corrections, now, why)

    def _reaches(self, hid: str, target_id: str, now: float) -> bool:
        return self.reaches(hid, target_id, now)

    # ------------------------------------------------------------------ models and operation
    def nominal_of(self, hid: str) -> HeliostatModel:
        return self.state.nominal_of(hid)

    def nominal_rows(self, hids) -> HeliostatModel:
        return self.state.nominal_rows(hids)

    def cleanliness_of_rows(self, rows: np.ndarray, now: float) -> np.ndarray:
        return self.field.cleanliness_of_rows(rows, now)

    @property
    def drifts(self) -> list[dict]:
        """Confirmed drifts (this process and, from the store, earlier ones)."""
        return self.ops.drifts

    @property
    def checks(self) -> int:
        """Operation checks started by this process."""
        return self.ops.checks

    def prior_mean(self, hid: str) -> np.ndarray | None:
        """The centre of the priors of ``hid``'s fits (:meth:`.checks.OperationChecks.prior_mean`)."""
        return self.ops.prior_mean(hid)

    # ------------------------------------------------------------------ summary
    def rechecked(self) -> bool:
        """Re-check mode: every heliostat has been visited and no visit is under way."""
        st = self.state
        return not st.active and all(st.book.h[hid].visits > 0 for hid in st.ids)

    def accepted(self) -> list[str]:
        st = self.state
        return [hid for hid in st.ids if st.book.accepted(hid)]

    def calibrated_model(self) -> HeliostatModel:
        st = self.state
        params = np.vstack([st.models[hid].params for hid in st.ids])
        return st.nominal.with_params(params)
