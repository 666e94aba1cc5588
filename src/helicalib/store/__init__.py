"""helicalib.store: the campaign database (SQLite, WAL) and its PNG frames.

>>> from helicalib.store import Store, Observation
>>> store = Store.open("campaign.db")            # creates or reopens; frames in ./images
>>> cid = store.start_campaign(name="demo", mode="simulate", started_s=t0,
...                            heliostats=[("H0001", 0, "T1")])
>>> vid = store.begin_visit(cid, "H0001", "T1", t0)
>>> oid = store.record_observation(obs, before_frame=png0, after_frames=[png1])

See ``docs/campaign.md`` (storage) for the schema.
"""

from helicalib.store.observation_rows import OBSERVATION_COLUMNS
from helicalib.store.records import (Campaign, CampaignHeliostat, Event, Fit, Observation, OperatorAction,
                                     Verdict, Visit)
from helicalib.store.schema import SCHEMA_VERSION
from helicalib.store.sqlite import Store

__all__ = [
    "Store", "Campaign", "CampaignHeliostat", "Visit", "Observation", "Fit", "Verdict", "Event", "OperatorAction",
    "OBSERVATION_COLUMNS", "SCHEMA_VERSION",
]
