"""report: mirrors that need washing (campaign page, report.json) and the measured cleanliness over
time on each heliostat's sheet, checked against the database read back with SQL (not the report's code)."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helicalib.config import load_field_config
from helicalib.geometry.sun import sun_at_site
from helicalib.store import Observation, Store

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"
CFG = load_field_config(FIELD)
T0 = float(pd.Timestamp("2026-06-01T00:00:00Z").timestamp()) - CFG.site.longitude_deg / 15.0 * 3600.0
IDS = ["H0001", "H0002", "H0003", "H0021", "H0022"]

# (heliostat, hour, valid, plant's cleanliness, measured cleanliness)
OBS = [
    ("H0001", 8.0, True, 0.92, 0.90),
    ("H0001", 11.0, True, 0.92, 0.62),      # newest measured: 0.62 → wash
    ("H0001", 12.0, False, 0.92, None),     # an invalid observation measures nothing
    ("H0002", 9.0, True, 0.60, None),
    ("H0002", 13.0, True, 0.58, None),      # never measured: the plant's newest, 0.58 → wash (dirtiest)
    ("H0003", 9.5, True, 0.50, 0.95),       # measured clean although the plant says 0.5 ...
    ("H0003", 14.0, True, 0.50, None),      # ... and a later visit without an estimate keeps it
    ("H0021", 10.0, True, None, 0.70),      # exactly the threshold: not below it
    ("H0022", 10.5, False, None, None),     # nothing known
]


def _obs(cid, hid, vid, t, valid, plant, measured):
    pos = sun_at_site(CFG.site, np.array([t, t + 60.0]))
    return Observation(campaign_id=cid, heliostat_id=hid, target_id=CFG.heliostat(hid).target, visit_id=vid,
                       iteration=0, capture_time_s=t, strokes_cmd_mm=(900.0, 800.0), strokes_read_mm=(900.1, 800.2),
                       sun_enu=tuple(float(x) for x in pos.vector_enu[0]), sun_azimuth_deg=float(pos.azimuth_deg[0]),
                       sun_elevation_deg=float(pos.elevation_deg[0]), sun_rising=bool(pos.elevation_deg[1] > pos.elevation_deg[0]),
                       valid=valid, reason="ok" if valid else "no_spot", wind_ms=3.0, dni_wm2=850.0, cleanliness=plant,
                       cleanliness_measured=measured, error_mrad=1.5 if valid else None,
                       offset_u_m=0.1 if valid else None, offset_v_m=0.1 if valid else None,
                       spot_enu_m=tuple(CFG.target(CFG.heliostat(hid).target).center_enu_m) if valid else None)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    from helicalib.report.build import build_report

    tmp = tmp_path_factory.mktemp("wash")
    db = tmp / "campaign.db"
    store = Store.open(db, durable=False)
    cid = store.start_campaign(name="wash", mode="simulate", started_s=T0,
                               heliostats=[(h, CFG.heliostat_index(h), CFG.heliostat(h).target) for h in IDS],
                               config_path=str(FIELD))
    # recorded out of time order on purpose: "newest" means the capture time, not the row id
    for hid, hour, valid, plant, measured in sorted(OBS, key=lambda o: -o[1]):
        t = T0 + hour * 3600.0
        vid = store.begin_visit(cid, hid, CFG.heliostat(hid).target, t)
        store.record_observation(_obs(cid, hid, vid, t, valid, plant, measured))
        store.end_visit(vid, ended_s=t + 60.0, outcome="converged" if valid else "invalid", iterations=1)
    store.finish_campaign(cid, T0 + 20 * 3600.0)
    store.close()
    index = build_report(db, tmp / "out", frames=False, jobs=1)
    return db, index, json.loads((index.parent / "report.json").read_text())


def _sql_present(db: Path) -> dict[str, tuple[float, str, float]]:
    """Each heliostat's newest measured cleanliness, else its newest plant value (SQL only)."""
    conn = sqlite3.connect(db)
    newest = """SELECT heliostat_id, {c}, capture_time_s FROM observations o WHERE {c} IS NOT NULL AND NOT EXISTS
                (SELECT 1 FROM observations p WHERE p.heliostat_id = o.heliostat_id AND p.{c} IS NOT NULL
                 AND (p.capture_time_s > o.capture_time_s OR (p.capture_time_s = o.capture_time_s AND p.id > o.id)))"""
    try:
        measured = {h: (v, "measured", t) for h, v, t in conn.execute(newest.format(c="cleanliness_measured"))}
        plant = {h: (v, "plant", t) for h, v, t in conn.execute(newest.format(c="cleanliness"))}
    finally:
        conn.close()
    return {**plant, **measured}


def test_washing_list_matches_sql(built):
    db, _index, rep = built
    w = rep["washing"]
    assert w["threshold"] == CFG.gating.cleanliness_preferred == 0.7
    assert w["threshold_source"] == "gating.cleanliness_preferred"
    present = _sql_present(db)
    want = sorted(((v, h, src, t) for h, (v, src, t) in present.items() if v < 0.7), key=lambda x: (x[0], x[1]))
    got = [(r["cleanliness"], r["heliostat"], r["source"], r["time_s"]) for r in w["rows"]]
    assert got == [(pytest.approx(v), h, s, pytest.approx(t)) for v, h, s, t in want]
    # the hand-made expectation the SQL must agree with
    assert [r["heliostat"] for r in w["rows"]] == ["H0002", "H0001"]
    assert [r["source"] for r in w["rows"]] == ["plant", "measured"]
    assert w["rows"][1]["time_utc"].startswith("2026-06-01") and w["rows"][1]["n_measured"] == 2
    assert w["heliostats_with_value"] == len(present) == 4
    assert w["heliostats_measured"] == sum(1 for v in present.values() if v[1] == "measured") == 3


def test_main_page_lists_the_mirrors_to_wash(built):
    _db, index, rep = built
    page = index.read_text()
    assert "<h2>Mirrors to wash (2)</h2>" in page
    section = page.split("<h2>Mirrors to wash (2)</h2>")[1].split("<h2>")[0]
    assert section.index("H0002") < section.index("H0001") and "H0003" not in section and "H0021" not in section
    assert 'href="heliostats/H0002.html"' in section and "0.58" in section and "0.62" in section


def test_sheet_shows_measured_cleanliness_over_time(built):
    db, index, rep = built
    conn = sqlite3.connect(db)
    try:
        sql = conn.execute("SELECT id, capture_time_s, cleanliness_measured FROM observations WHERE heliostat_id = ?"
                           " AND cleanliness_measured IS NOT NULL ORDER BY capture_time_s, id", ("H0001",)).fetchall()
    finally:
        conn.close()
    sheet = json.loads((index.parent / "heliostats" / "H0001.json").read_text())
    c = sheet["cleanliness"]
    assert [(r["id"], r["cleanliness_measured"]) for r in c["measured"]] == [(i, pytest.approx(v)) for i, _t, v in sql]
    assert [r["time_s"] for r in c["measured"]] == [pytest.approx(t, abs=0.1) for _i, t, _v in sql]
    assert c["present"] == pytest.approx(0.62) and c["source"] == "measured" and c["needs_washing"] is True
    html = (index.parent / "heliostats" / "H0001.html").read_text()
    assert "<h2>Mirror cleanliness</h2>" in html and "<svg" in html and "needs washing" in html
    h3 = json.loads((index.parent / "heliostats" / "H0003.json").read_text())["cleanliness"]
    assert h3["present"] == pytest.approx(0.95) and h3["needs_washing"] is False
    h2 = json.loads((index.parent / "heliostats" / "H0002.json").read_text())["cleanliness"]
    assert h2["measured"] == [] and h2["source"] == "plant" and h2["present"] == pytest.approx(0.58)
    h22 = json.loads((index.parent / "heliostats" / "H0022.json").read_text())["cleanliness"]
    assert h22["present"] is None and h22["needs_washing"] is None
    # the observation table carries the measured value of each observation
    rows = {r["id"]: r for r in sheet["observation_rows"]}
    assert all(rows[i]["cleanliness_measured"] == pytest.approx(v) for i, _t, v in sql)
