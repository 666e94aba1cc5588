"""What a live session was asked to do, read once from the command line.

``helicalib run``, ``operate`` and ``check`` parse their arguments (:mod:`helicalib.commands`);
:meth:`LiveSettings.from_args` reads the namespace once, and everything below it (opening the
campaign, building the runner, the summary) takes these typed values, never the namespace.
"""

from __future__ import annotations

from dataclasses import dataclass

from helicalib.console.server import ConsoleOptions

MODES = ("live", "check")
"""``live``: ``run`` and ``operate`` (a campaign resumed or started); ``check``: one re-check."""


@dataclass(frozen=True)
class LiveSettings:
    """One live session's settings.

    ``days`` is ``--days`` as given (None: the command's default, see
    :func:`helicalib.app.session.session_days`); ``heliostat_ids`` the ``--heliostats`` list (None:
    every heliostat, or the resumed campaign's); ``operation`` the year-round rule of ``operate``
    (``"ranked"`` or ``"rota"``; None for ``run`` and ``check``); ``keep_frames`` the nightly frame
    retention of ``operate`` (None: keep every frame).
    """

    mode: str
    field: str
    armed: bool
    heliostat_ids: list[str] | None
    days: float | None
    until: str | None
    planner: str
    recheck: bool
    refine: bool
    operation: str | None
    rota_days: float
    keep_frames: int | None
    spots_per_board: int | str
    as_json: bool
    new_campaign: bool
    accept_clock_jump: bool
    console: ConsoleOptions
    register_map: str | None = None
    """``--register-map``: overrides the field config's ``plant.register_map``."""

    @property
    def command(self) -> str:
        """The command's name in its lines: ``operate``, ``run`` or ``check``."""
        return "operate" if self.operation else ("run" if self.mode == "live" else "check")

    @classmethod
    def from_args(cls, args, mode: str) -> LiveSettings:
        """The settings of a parsed ``run``/``operate``/``check`` namespace (``mode``: :data:`MODES`)."""
        ids = [s.strip() for s in args.heliostats.split(",") if s.strip()] if args.heliostats else None
        return cls(mode=mode, field=args.field, armed=bool(args.arm), heliostat_ids=ids, days=args.days,
                   until=args.until, planner=args.planner, recheck=args.recheck,
                   refine=getattr(args, "refine", False),
                   operation=getattr(args, "operation", None),  # helicalib operate: the long-running service
                   rota_days=getattr(args, "rota_days", 14.0), keep_frames=getattr(args, "keep_frames", None),
                   spots_per_board=getattr(args, "spots_per_board", 1), as_json=bool(getattr(args, "json", False)),
                   new_campaign=bool(getattr(args, "new_campaign", False)),
                   accept_clock_jump=bool(args.accept_clock_jump), console=ConsoleOptions.from_args(args),
                   register_map=getattr(args, "register_map", None))
