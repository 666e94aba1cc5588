"""The campaign's state: one typed object the loop and its helpers work on.

:class:`CampaignOptions` is what a command asks of a campaign (planner, re-check, armed, operation,
spots per board, ...), :class:`CampaignDevices` what it runs on (plant, spot sensors, clock, store,
and the plant's declared abilities, read once here), and :class:`CampaignState` what it knows and
holds as it runs: the book of points, the models, the corrections written, the boards and the
visits under way, the heliostats returning to tracking or flagged off it, the weather, stow and
gate, and the faults of the plant, its clock and the storage (:class:`Faults`). The loop
(:mod:`.loop`) and the field's side (:mod:`.field`, :mod:`.tracking`) change it; a view reads it
through a :class:`~.events.Snapshot`.
"""

from __future__ import annotations

import errno
import math
import sqlite3
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from helicalib.campaign import book as books
from helicalib.campaign import choice as choices
from helicalib.campaign.board import AUTO_SPOTS, Board
from helicalib.campaign.events import BoardState, RunEvent
from helicalib.campaign.operation import rules as op_rules
from helicalib.campaign.visit_types import VisitContext, VisitSettings
from helicalib.devices.protocols import Clock, Plant, PlantAbilities, SpotSensor
from helicalib.errors import StorageError
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.geometry.sun import SunTable
from helicalib.store.sqlite import Store

RETURN_CHECK_S = 10.0
"""Plant seconds after a track command before the plant's state is read to confirm tracking."""
RETURN_RETRY_S = 30.0
"""Plant seconds before the first new attempt to bring back to tracking a heliostat the plant has
not confirmed; the wait doubles with each attempt, up to :data:`RETURN_RETRY_MAX_S`."""
RETURN_RETRY_MAX_S = 600.0
STATS_KEPT = 200_000
"""Visits whose iterations and first placements the runner's statistics keep in memory."""


@dataclass(frozen=True)
class CampaignOptions:
    """What a command asks of a campaign.

    Parameters
    ----------
    planner : ``"gaps"`` (fill acceptance gaps fastest), ``"round-robin"`` (the paper's "in turn",
        each heliostat on its own board) or ``"round-robin-shared"`` (in turn over the whole field,
        boards shared as for gaps: a benchmark baseline).
    recheck : visit every heliostat once regardless of acceptance (operators' re-check).
    model : the starting models of the campaign's heliostats (default nominal).
    armed : False: read the plant and plan, but write nothing (each decision is an event).
    refine : gaps planner: spend target time no acceptance gap asks for on the heliostats whose
        model is most uncertain at the present sun (accepted ones included).
    listeners : called with every :class:`~.events.RunEvent` after the fact (views, JSON lines).
    operation : year-round operation (:mod:`.operation`): ``"ranked"`` or ``"rota"`` checks of
        accepted heliostats with the board time no gap needs; None: a campaign, no checks.
    rota_days : ``rota``: days between checks of each heliostat.
    spots_per_board : visits under way on one board at once (gaps planner; :mod:`.board`), or
        ``"auto"`` (:data:`~.board.AUTO_SPOTS`).
    flux : target id → (Fe, atmosphere) of each board's camera for the cleanliness measured from
        the spot (default each camera's FLUX.yaml from the config).
    """

    planner: str = "gaps"
    recheck: bool = False
    model: HeliostatModel | None = None
    armed: bool = True
    refine: bool = False
    listeners: tuple[Callable[[RunEvent], None], ...] = ()
    operation: str | None = None
    rota_days: float = 14.0
    spots_per_board: int | str | None = 1
    flux: dict | None = None

    def __post_init__(self):
        sp = self.spots_per_board
        if sp not in (None, "auto") and int(sp) < 1:
            raise ValueError(f"spots per board: {sp} (at least 1, or 'auto')")
        if self.operation is not None and self.operation not in op_rules.OPERATION_MODES:
            raise ValueError(f"operation {self.operation!r}: choose one of {', '.join(op_rules.OPERATION_MODES)}")


@dataclass
class CampaignDevices:
    """What a campaign runs on: the plant (and the abilities it declares, read once), each board's
    spot sensor (target id → :class:`~helicalib.devices.protocols.SpotSensor`), the plant clock and
    the store."""

    plant: Plant
    sensors: dict[str, SpotSensor]
    clock: Clock
    store: Store
    abilities: PlantAbilities = PlantAbilities()


@dataclass
class Returning:
    """A heliostat sent back to tracking whose state 1 the plant has not confirmed yet."""

    since_s: float
    next_check_s: float
    corrections_mm: object = None
    attempts: int = 1
    failed: bool = False
    """True once a return failed (then its confirmation is news: an event says so)."""
    last_error: str = ""

    def retry_at(self, now: float) -> float:
        """When to try again: 30 s after the first attempt, doubling up to 10 min (a heliostat the
        plant reports faulted or offline is not sent a command every 30 s for a night)."""
        return now + min(RETURN_RETRY_S * 2.0 ** max(self.attempts - 1, 0), RETURN_RETRY_MAX_S)


@dataclass
class RunningVisit:
    """A visit under way: its generator and when it next wants a step."""

    heliostat_id: str
    target_id: str
    gen: object
    ctx: VisitContext
    wake_s: float
    frame: bool = False
    """Whether it waits for a frame on its way (:class:`~.frames.FrameWait`)."""


@dataclass
class RunnerStats:
    visits: int = 0
    valid_visits: int = 0
    gated_s: float = 0.0
    stowed_s: float = 0.0
    night_s: float = 0.0
    # the newest STATS_KEPT of each (a service runs for years; the summaries read the last day)
    iterations: deque = field(default_factory=lambda: deque(maxlen=STATS_KEPT))
    first_errors: deque = field(default_factory=lambda: deque(maxlen=STATS_KEPT))  # (time, mrad, had a model)
    outcomes: dict[str, int] = field(default_factory=dict)
    shared_visits: int = 0
    """Visits that started while another visit was under way on the same board."""
    peak_on_board: int = 0
    """The most visits under way on one board at once."""


@dataclass
class Faults:
    """What failed around the campaign: the plant's links, its clock, the storage, the jobs."""

    plant_unreachable_since_s: float | None = None
    """Plant time (the controller's estimate) since which the plant has not answered (its clock or
    weather could not be read); None while it answers. No visit starts meanwhile."""
    lost_links: dict[str, float] = field(default_factory=dict)
    """Each link that does not answer (``"scs"``: the plant's clock and commands, ``"weather"``) and
    since when; a link is back only when a read over that same link succeeds."""
    said_lost: set[str] = field(default_factory=set)
    """Jobs that said the plant failed them during this loss."""
    job_fault: dict[str, str] = field(default_factory=dict)
    """Each job's last fault line, until the job succeeds."""
    clock_jump: str | None = None
    """Set (one line) when the plant's clock jumped during the run: no visit starts, a live run stops."""
    clock_jump_hint: str = "; to go on from the plant's time, restart with --accept-clock-jump"
    """What the clock-jump line tells the crew to do after checking the plant's clock (a command
    without that option, ``check``, sets it empty)."""
    storage_errors: int = 0
    """Failed writes to the database or its frames folder with no observation stored with its
    frames since (a fault line the database takes is no proof that frames can be written)."""
    storage_fault_open: bool = False
    """The storage's fault line is being written (its own failure is the same one)."""
    storage_lost: str | None = None
    """Set (one line) after too many failed writes in a row: a live run stops."""


@dataclass
class RefreshRound:
    """A tracking refresh round going out a slice per tick: the corrections computed when it was
    due (``due_s``, plant time), those not yet written, and the writes the plant refused."""

    due_s: float
    queue: deque
    """(heliostat id, corrections (2,) [mm]) in the order they go out."""
    failed: list = field(default_factory=list)
    """(heliostat id, the plant's error) of each write that failed."""
    visited: set = field(default_factory=set)
    """Heliostats that began a visit since the round was due: their visits' corrections are newer."""
    flight: list = field(default_factory=list)
    """(heliostat id, corrections) of the batch on its way (a plant that sends several at a time)."""
    sent: object | None = None
    """That batch's answers to come (``done()``, ``results()``); None: none on its way."""


@dataclass
class CampaignState:
    """Everything a running campaign knows and holds (module docstring)."""

    cfg: object
    campaign_id: int
    ids: list[str]
    index: dict[str, int]
    """Heliostat id → its row in :attr:`ids` (and in :attr:`nominal`)."""
    plant_index: np.ndarray
    """Plant index (k,) of each heliostat of :attr:`ids`."""
    home: dict[str, list[str]]
    """Target id → the campaign's heliostats whose own board it is."""
    guests: dict
    """Target id → heliostats that may borrow it (:func:`.choice.shared_targets`)."""
    options: CampaignOptions
    planner_kind: str
    refine: bool
    operation: str | None
    settings: VisitSettings
    check_settings: VisitSettings
    """An operation check's settings: more after frames (:data:`.operation.rules.CHECK_AFTER_FRAMES`)."""
    sun_table: SunTable
    nominal: HeliostatModel
    models: dict[str, HeliostatModel]
    book: books.Book
    boards: dict[str, Board]
    corrections: dict[str, np.ndarray | None]
    spots_per_board: int | str
    stats: RunnerStats = field(default_factory=RunnerStats)
    active: dict[str, RunningVisit] = field(default_factory=dict)
    """Visits under way, by heliostat id."""
    returning: dict[str, Returning] = field(default_factory=dict)
    flagged: set[str] = field(default_factory=set)
    """Heliostats whose newest stored off_tracking is not yet followed by back_to_tracking."""
    board_states: dict[str, BoardState] = field(default_factory=dict)
    """What each board shows: its heliostat, placement and last error."""
    stowed: bool = False
    last_weather: object = None
    weather_time_s: float | None = None
    """Plant time of the weather reading behind :attr:`last_weather`."""
    last_poll_s: float = -math.inf
    last_gate: object = None
    gate_said: tuple | None = None
    """(open, night) of the gate last said with a ``gated``/``ungated`` event."""
    last_refresh_s: float = -math.inf
    refresh_round: RefreshRound | None = None
    """The tracking refresh still going out over a plant without bulk tracking (:mod:`.tracking`)."""
    band_cache: tuple[float, str] = (-math.inf, "")
    nominal_one: dict[str, HeliostatModel] = field(default_factory=dict)
    clean_cache: dict[str, tuple[float, float | None]] = field(default_factory=dict)
    clean_rows: tuple[np.ndarray, np.ndarray] | None = None
    """(values, read at) of the plant's cleanliness registers by row of :attr:`ids`."""
    faults: Faults = field(default_factory=Faults)
    operator: object = None
    """Operator actions: a :class:`.operation.crew.OperatorDesk` (armed live runs: the console)."""
    stopping: bool = False
    """Set by a live run's stop: jobs still queued do nothing more."""
    retention: tuple[int, bool] | None = None
    """(keep_last, keep_invalid): every night the frames of all but each heliostat's newest
    ``keep_last`` observations (and, with keep_invalid, the rejected ones) are deleted
    (:func:`helicalib.store.retention.retain_frames`); None keeps every frame."""
    retained_day: int | None = None
    lock: threading.RLock = field(default_factory=threading.RLock)
    """Held while the tick's thread or the weather job changes state both read (stowed, the last
    poll, the plant's reachability, the storage and clock faults); never across a device's reply."""
    weather_lock: threading.Lock = field(default_factory=threading.Lock)
    """One weather poll at a time (the tick's or the weather job's)."""

    @property
    def armed(self) -> bool:
        return self.options.armed

    @property
    def recheck(self) -> bool:
        return self.options.recheck

    def nominal_of(self, hid: str) -> HeliostatModel:
        """The nominal model of ``hid`` (one row, kept)."""
        model = self.nominal_one.get(hid)
        if model is None:
            model = self.nominal_one[hid] = self.nominal.subset([self.index[hid]])
        return model

    def nominal_rows(self, hids) -> HeliostatModel:
        """The nominal models of ``hids``, in that order."""
        return self.nominal.subset([self.index[h] for h in hids])


def build_state(cfg, campaign_id: int, heliostat_ids, options: CampaignOptions, board_ids) -> CampaignState:
    """A new campaign's state before anything is read from the store: nominal (or ``options.model``)
    models, an empty book, free boards. ``board_ids``: targets with a spot sensor (may be lent)."""
    ids = list(heliostat_ids) if heliostat_ids else [h.id for h in cfg.heliostats]
    planner = options.planner
    share = bool(cfg.calibration.share_targets) and planner in ("gaps", "round-robin-shared")
    guests = choices.shared_targets(cfg, ids, [t for t in board_ids if cfg.cameras_for(t)]) if share else {}
    settings = VisitSettings.from_config(cfg)
    base = options.model if options.model is not None else HeliostatModel.from_config(cfg, ids)
    book = books.Book(cfg, ids)
    book.table.set_guests(guests)
    spots = "auto" if options.spots_per_board in (None, "auto") else int(options.spots_per_board)
    # several visits per board with the gaps planner (the round robins are the paper's baselines)
    cap = (AUTO_SPOTS if spots == "auto" else spots) if planner == "gaps" else 1
    return CampaignState(
        cfg=cfg, campaign_id=campaign_id, ids=ids, index={hid: i for i, hid in enumerate(ids)},
        plant_index=np.array([cfg.heliostat_index(hid) for hid in ids], dtype=np.int64),
        home={t.id: [hid for hid in ids if cfg.heliostat(hid).target == t.id] for t in cfg.targets},
        guests=guests, options=options, planner_kind=planner, refine=bool(options.refine) and planner == "gaps",
        operation=options.operation if planner == "gaps" else None, settings=settings,
        check_settings=replace(settings, after_frames=max(settings.after_frames, op_rules.CHECK_AFTER_FRAMES),
                               band_deg=None),  # a check keeps its whole correction loop in the band too
        sun_table=SunTable(cfg.site), nominal=HeliostatModel.from_config(cfg, ids),
        models={hid: base.subset([i]) for i, hid in enumerate(ids)}, book=book,
        boards={t.id: Board(t.id, cap=cap) for t in cfg.targets}, corrections={hid: None for hid in ids},
        spots_per_board=spots, clean_rows=(np.full(len(ids), np.nan), np.full(len(ids), -math.inf)))


def storage_error(err: BaseException) -> bool:
    """Whether ``err`` says the database or its frames folder cannot be written (full disk,
    read-only file or folder): :class:`~helicalib.errors.StorageError`, SQLite's "full",
    "readonly" or I/O errors, or the system's "no space", "read-only file system", "permission"
    errors. A busy database ("locked") is not."""
    if isinstance(err, StorageError):
        return True
    if isinstance(err, sqlite3.OperationalError):
        text = str(err).lower()
        return any(k in text for k in ("full", "readonly", "read-only", "disk i/o", "unable to open"))
    if isinstance(err, OSError) and not isinstance(err, (ConnectionError, TimeoutError)):
        return err.errno in (errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT)
    return False
