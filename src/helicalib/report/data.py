"""Everything a report shows, read once from a campaign database: the only I/O of the figures.

:func:`load_campaign` opens the store, picks the campaign (the newest by default) and returns a
:class:`CampaignData`: the campaign row, its heliostats, visits, observations (as one pandas
frame), fits, latest verdicts and events, the field config when it can be found, and the solar
days of the campaign (for the acceptance bands and windows). The pure functions of
:mod:`helicalib.report.figures` take this object and return plain dictionaries.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from helicalib.errors import ConfigError, HelicalibError
from helicalib.store import Campaign, CampaignHeliostat, Event, Fit, Store, Verdict, Visit


@dataclass
class CampaignData:
    """One campaign, as stored.

    Attributes
    ----------
    db_path, images_dir : Path
        The database and its frames directory.
    campaign : Campaign or None
        None when the database holds no campaign at all.
    heliostats : list of CampaignHeliostat
        Enrolled heliostats, in plant block order.
    visits : list of Visit
    observations : pandas.DataFrame
        The flat observation columns (``helicalib.store.OBSERVATION_COLUMNS``), one row per attempt.
    fits : dict heliostat id → Fit
        Each heliostat's newest fit.
    verdicts : dict heliostat id → Verdict
        Each heliostat's newest acceptance verdict.
    verdict_history : list of Verdict
        Every verdict of the campaign, oldest first (for acceptance over time).
    events : list of Event
    cfg : FieldConfig or None
        The field config the campaign ran with, when it could be read.
    config_note : str
        Why ``cfg`` is None (empty when it was loaded).
    days : tuple of SunDay
        Solar days covering the campaign (empty without ``cfg``).
    end_s : float
        The campaign's end, or the newest thing recorded while it runs [UTC s].
    """

    db_path: Path
    images_dir: Path
    campaign: Campaign | None
    heliostats: list[CampaignHeliostat] = field(default_factory=list)
    visits: list[Visit] = field(default_factory=list)
    observations: pd.DataFrame = field(default_factory=pd.DataFrame)
    fits: dict[str, Fit] = field(default_factory=dict)
    verdicts: dict[str, Verdict] = field(default_factory=dict)
    verdict_history: list[Verdict] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    cfg: Any = None
    config_note: str = ""
    days: tuple = ()
    end_s: float = 0.0

    @property
    def heliostat_ids(self) -> list[str]:
        return [h.heliostat_id for h in self.heliostats]


def _config_candidates(campaign: Campaign, db_path: Path) -> list[Path]:
    """Places the campaign's field config may be: its recorded path, as given and beside the database."""
    texts = [campaign.config_path]
    s = campaign.settings or {}
    for key in ("field", "config", "field_config"):
        value = s.get(key)
        if isinstance(value, str):
            texts.append(value)
        elif isinstance(value, dict) and isinstance(value.get("field"), str):
            texts.append(value["field"])
    out: list[Path] = []
    for t in texts:
        if not t:
            continue
        p = Path(t)
        out.append(p)
        if not p.is_absolute():
            out.append(db_path.parent / p)
    return out


def find_config(campaign: Campaign, db_path: Path, override: str | Path | None = None):
    """(FieldConfig or None, note): the field config of a campaign, or why it could not be read."""
    from helicalib.config import load_field_config

    candidates = [Path(override)] if override is not None else _config_candidates(campaign, db_path)
    if not candidates:
        return None, "the campaign records no field config path"
    errors = []
    for p in candidates:
        if p.is_file():
            try:
                return load_field_config(p), ""
            except ConfigError as err:
                errors.append(str(err))
    if errors:
        return None, f"the field config could not be read ({errors[0]})"
    return None, f"the field config {candidates[0]} was not found"


def load_campaign(db_path: str | Path, campaign_id: int | None = None, field_config: str | Path | None = None,
                  images_dir: str | Path | None = None) -> CampaignData:
    """Read one campaign (default: the newest) and everything the report shows.

    Raises
    ------
    ConfigError
        The database cannot be opened, or ``campaign_id`` is not in it.
    """
    db_path = Path(db_path)
    if not db_path.is_file():
        raise ConfigError(f"{db_path}: database not found")
    store = Store.open(db_path, images_dir, readonly=True)  # a reader: safe beside a running campaign
    try:
        campaigns = store.campaigns()
        if not campaigns:
            return CampaignData(db_path=db_path, images_dir=store.images_dir, campaign=None,
                                config_note="the database holds no campaign")
        campaign = store.campaign(campaign_id) if campaign_id is not None else campaigns[-1]
        cid = campaign.id
        heliostats = store.campaign_heliostats(cid)
        obs = store.observations_frame(campaign_id=cid)
        visits = store.visits(campaign_id=cid)
        fits: dict[str, Fit] = {}
        for f in store.fits(campaign_id=cid):
            fits[f.heliostat_id] = f  # oldest first: the newest wins
        data = CampaignData(
            db_path=db_path, images_dir=store.images_dir, campaign=campaign, heliostats=heliostats, visits=visits,
            observations=obs, fits=fits, verdicts=store.latest_verdicts(cid),
            verdict_history=store.verdicts(cid), events=store.events(campaign_id=cid),
        )
    finally:
        store.close()
    times = [campaign.started_s]
    times += [v.started_s for v in data.visits] + [v.ended_s for v in data.visits if v.ended_s is not None]
    times += [e.time_s for e in data.events]
    if len(data.observations):
        times.append(float(data.observations["capture_time_s"].max()))
    data.end_s = float(campaign.ended_s) if campaign.ended_s is not None else max(times)
    data.cfg, data.config_note = find_config(campaign, db_path, field_config)
    if data.cfg is not None:
        try:
            from helicalib.calibration.sun_days import sun_days

            acc = data.cfg.acceptance
            data.days = sun_days(data.cfg.site, campaign.started_s, max(data.end_s, campaign.started_s + 1.0),
                                 acc.low_band_deg, acc.high_elevation_deg, step_s=120.0)
        except HelicalibError as err:  # pragma: no cover - a config that loads has a valid site
            data.config_note = f"solar days could not be computed ({err})"
    return data
