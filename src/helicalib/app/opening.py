"""Opening a live session's campaign, resumed or new, on a plant clock consistent with it.

* ``run`` resumes the field's campaign by default (finished or not: the database keeps one
  calibration of the field, its points never expire) and starts another only with
  ``--new-campaign``; a run without ``--arm`` is a *dry run*, kept as a campaign of its own
  (mode ``dry-run``) that an armed run never resumes, because nothing was calibrated in it;
* ``check`` is one campaign per re-check (mode ``check``);
* a campaign is resumed only on a plant clock consistent with it (:func:`check_plant_clock`):
  a plant time before the campaign's last record, or far beyond what the time since then allows,
  is refused unless ``--accept-clock-jump``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

from helicalib.app.settings import LiveSettings
from helicalib.errors import ConfigError, PlantError

CLOCK_BACK_TOLERANCE_S = 60.0
"""A resumed campaign's last record may lie this many plant seconds after the plant's time now
(records stamped by the controller's own clock run slightly ahead)."""
CLOCK_FORWARD_SLACK_S = 86400.0
"""Plant seconds a plant's time may lie beyond the campaign's last record on top of what the real
time since the database was last written allows at the plant's rate (×1.5)."""


@dataclass(frozen=True)
class Opened:
    """The campaign a session runs, and the sentence that introduces it."""

    campaign_id: int
    heliostat_ids: list[str]
    line: str


def campaign_kind(campaign) -> str | None:
    """``"armed"`` (a run that calibrates), ``"dry"`` (a run without --arm) or None (check, simulate)."""
    if campaign.mode == "dry-run" or (campaign.mode == "live" and campaign.settings.get("armed") is False):
        return "dry"
    return "armed" if campaign.mode == "live" else None


def last_record_s(store, campaign_id: int) -> float | None:
    """Plant time of a campaign's newest record (event, visit start or end), None if it has none."""
    times = [e.time_s for e in store.events(campaign_id=campaign_id)]
    for v in store.visits(campaign_id=campaign_id):
        times.append(v.started_s)
        if v.ended_s is not None:
            times.append(v.ended_s)
    times = [t for t in times if t is not None and math.isfinite(t)]
    return max(times) if times else None


def check_plant_clock(store, campaign_id: int, now_s: float, rate: float, written_wall_s: float | None,
                      accept: bool) -> str | None:
    """Refuse (:class:`PlantError`, one line naming both times) to resume campaign ``campaign_id``
    on a plant whose time ``now_s`` lies before its last record (beyond
    :data:`CLOCK_BACK_TOLERANCE_S`: a plant restarted at an earlier date) or far beyond it (more than
    the real seconds since the database was last written, ``written_wall_s``, allow at
    ``rate`` ×1.5, plus :data:`CLOCK_FORWARD_SLACK_S`). With ``accept`` the jump is returned as a
    sentence to record instead; None when the clock is consistent."""
    from helicalib.campaign.events import iso_utc

    last = last_record_s(store, campaign_id)
    if last is None:
        return None
    jump = None
    if now_s < last - CLOCK_BACK_TOLERANCE_S:
        jump = (f"the plant's time {iso_utc(now_s)} lies before campaign {campaign_id}'s last record "
                f"{iso_utc(last)} ({(last - now_s) / 3600.0:.1f} h back: a plant restarted at an earlier date?)")
    elif written_wall_s is not None:
        real = max(0.0, time.time() - written_wall_s)
        if now_s - last > 1.5 * max(float(rate), 1.0) * real + CLOCK_FORWARD_SLACK_S:
            jump = (f"the plant's time {iso_utc(now_s)} lies {(now_s - last) / 86400.0:.1f} days after campaign "
                    f"{campaign_id}'s last record {iso_utc(last)}, but the database was written "
                    f"{real / 3600.0:.1f} h ago (the plant's clock jumped forwards?)")
    if jump is None:
        return None
    if not accept:
        raise PlantError(f"refusing to resume: {jump}; check the plant's clock, or resume from the plant's time "
                         "with --accept-clock-jump")
    return jump


def last_written_wall_s(db: Path) -> float | None:
    """Real time the database (or its write-ahead log) was last written; None if it does not exist."""
    times = []
    for f in (db, db.with_name(db.name + "-wal")):
        try:
            times.append(f.stat().st_mtime)
        except OSError:
            pass
    return max(times) if times else None


def open_campaign(store, cfg, settings: LiveSettings, now_s: float, rate: float = 1.0,
                  written_wall_s: float | None = None) -> Opened:
    """Resume or start the session's campaign; the returned line says which and what it holds. A
    resume on a plant clock that jumped is refused (:func:`check_plant_clock`) unless
    ``settings.accept_clock_jump``."""
    mode, ids = settings.mode, settings.heliostat_ids
    armed = settings.armed
    kind = "armed" if armed else "dry"
    run_mode = "live" if armed else "dry-run"
    resumed = None
    skipped = ""
    if mode == "live" and not settings.new_campaign:
        same = [c for c in store.campaigns() if campaign_kind(c) == kind]
        resumed = same[-1] if same else None
        other = [c for c in store.campaigns() if campaign_kind(c) == ("dry" if armed else "armed")]
        if resumed is None and armed and other:
            skipped = (f"; campaign {other[-1].id} was a dry run (nothing was calibrated in it), so this armed run "
                       "starts its own")
    if resumed is not None:
        held = [h.heliostat_id for h in store.campaign_heliostats(resumed.id)]
        if ids and sorted(ids) != sorted(held):
            raise ConfigError(f"--heliostats: campaign {resumed.id} calibrates {plural(len(held), 'heliostat')}, not the "
                              f"{len(ids)} named; resume it without --heliostats, or add --new-campaign")
        jump = check_plant_clock(store, resumed.id, now_s, rate, written_wall_s, settings.accept_clock_jump)
        was = resumed.status
        store.reopen_campaign(resumed.id)
        accepted = f"; resumed from the plant's time although {jump} (--accept-clock-jump)" if jump else ""
        return Opened(resumed.id, held, f"campaign {resumed.id} ({_label(kind)}, resumed; it was {was}): "
                                        + holdings(store, resumed.id, held) + f"; database {store.path}{accepted}")
    ids = ids or [h.id for h in cfg.heliostats]
    name = {"live": f"{'live' if armed else 'dry run'} {cfg.site.name}", "check": f"check {cfg.site.name}"}[mode]
    cid = store.start_campaign(
        name=name, mode=run_mode if mode == "live" else "check", started_s=now_s,
        heliostats=[(hid, cfg.heliostat_index(hid), cfg.heliostat(hid).target) for hid in ids],
        config_path=str(cfg.source), settings={"armed": armed, "planner": settings.planner,
                                               "refine": settings.refine})
    what = "re-check" if mode == "check" else _label(kind)
    return Opened(cid, ids, f"campaign {cid} ({what}, new): {plural(len(ids), 'heliostat')}{skipped}; database {store.path}")


def _label(kind: str) -> str:
    return "armed" if kind == "armed" else "dry run: nothing is written to the plant"


def holdings(store, campaign_id: int, ids: list[str]) -> str:
    """What a campaign holds, in one clause: heliostats, accepted, observations, visits."""
    verdicts = store.latest_verdicts(campaign_id)
    accepted = sum(1 for h in ids if verdicts.get(h) is not None and verdicts[h].accepted)
    n_obs = store.count_observations(campaign_id)
    n_valid = store.count_observations(campaign_id, valid=True)
    visits = len(store.visits(campaign_id=campaign_id))
    return (f"{plural(len(ids), 'heliostat')}, {accepted} accepted, {plural(n_obs, 'observation')} ({n_valid} valid) "
            f"in {plural(visits, 'visit')}")


def plural(n: int, noun: str) -> str:
    """``1 heliostat``, ``2 heliostats``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"
