"""The store's ``cleanliness_measured`` column: nullable, round trip, raw SQL and CSV export."""

from __future__ import annotations

import csv
import math
import sqlite3
from dataclasses import replace

import numpy as np
import pytest

from helicalib.store import OBSERVATION_COLUMNS, Observation, Store


def _obs(cid, i, measured):
    return Observation(
        campaign_id=cid, heliostat_id="H0001", target_id="T1", visit_id=None, iteration=i, capture_time_s=1.75e9 + i,
        strokes_cmd_mm=(812.5, 640.25), strokes_read_mm=(812.4, 640.3), sun_enu=(0.1, -0.6, float(np.sqrt(1 - 0.37))),
        sun_azimuth_deg=170.5, sun_elevation_deg=52.2, valid=True, cleanliness=0.93, cleanliness_measured=measured)


@pytest.fixture
def store(tmp_path):
    s = Store.open(tmp_path / "campaign.db", durable=False)
    yield s
    s.close()


def test_default_is_none():
    o = _obs(1, 0, None)
    assert replace(o, cleanliness_measured=None) == o
    fields = Observation.__dataclass_fields__
    assert fields["cleanliness_measured"].default is None


def test_measured_cleanliness_round_trip_sql_and_csv(store, tmp_path):
    cid = store.start_campaign(name="c", mode="simulate", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    store.record_observation(_obs(cid, 0, 0.8125))
    store.record_observation(_obs(cid, 1, None))
    store.record_observation(_obs(cid, 2, float("nan")))  # "no estimate" stored as NULL
    back = store.observations(campaign_id=cid)
    assert [o.cleanliness_measured for o in back] == [0.8125, None, None]
    assert [o.cleanliness for o in back] == [0.93, 0.93, 0.93]
    conn = sqlite3.connect(store.path)
    try:
        info = {r[1]: r for r in conn.execute("PRAGMA table_info(observations)")}
        assert info["cleanliness_measured"][2] == "REAL" and info["cleanliness_measured"][3] == 0  # nullable
        rows = conn.execute("SELECT cleanliness_measured FROM observations ORDER BY id").fetchall()
    finally:
        conn.close()
    assert [r[0] for r in rows] == [0.8125, None, None]
    frame = store.observations_frame(campaign_id=cid)
    assert frame["cleanliness_measured"].iloc[0] == 0.8125 and math.isnan(frame["cleanliness_measured"].iloc[1])
    out = tmp_path / "obs.csv"
    assert store.export_observations_csv(out) == 3
    with open(out) as fh:
        csv_rows = list(csv.DictReader(fh))
    assert tuple(csv_rows[0]) == OBSERVATION_COLUMNS
    assert OBSERVATION_COLUMNS.index("cleanliness_measured") == OBSERVATION_COLUMNS.index("cleanliness") + 1
    assert [r["cleanliness_measured"] for r in csv_rows] == ["0.8125", "", ""]
