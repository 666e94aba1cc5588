"""report: end to end from a REAL simulated campaign (``helicalib simulate ... --report``).

A short morning on three heliostats of the demo field, with a wind storm that stows the field,
camera 503s and one heliostat that never answers: a partly failed campaign. The report's figures
are checked against the database by SQL written here (not the report's code) and against the
runner's own summary.json; every link resolves and every PNG decodes.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml

from test_report_build import check_links

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"
IDS = ["H0001", "H0002", "H0021"]
SCENARIO = {
    "name": "report-test",
    "seed": 3,
    # local solar 06:00-06:40 on the default start day (local midnight = 2026-05-31T17:42:17Z)
    "weather": {"events": [{"start": "2026-05-31T23:42:00Z", "end": "2026-06-01T00:22:00Z", "wind_ms": 19.0}]},
    "faults": {"camera_503_probability": 0.15, "offline": ["H0002"]},
}


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    from helicalib.cli import main

    tmp = tmp_path_factory.mktemp("sim")
    scen = tmp / "scenario.yaml"
    scen.write_text(yaml.safe_dump(SCENARIO))
    out = tmp / "run"
    code = main(["simulate", str(FIELD), "--days", "0.32", "--seed", "3", "--scenario", str(scen),
                 "--heliostats", ",".join(IDS), "--out", str(out), "--report", "--json"])
    assert code == 0
    db = out / "helicalib.db"
    index = out / "report" / "index.html"
    return db, index, json.loads((out / "report" / "report.json").read_text()), json.loads((out / "summary.json").read_text())


def q(db, sql, *params):
    con = sqlite3.connect(db)
    try:
        return con.execute(sql, params).fetchall()
    finally:
        con.close()


def test_links_pngs_and_sheets(sim):
    db, index, rep, _summary = sim
    assert check_links(index) == 1 + len(IDS)
    assert sorted(h["id"] for h in rep["heliostats"]) == sorted(IDS)
    # a heliostat that measured something has its latest frames drawn and measured again
    for h in rep["heliostats"]:
        if h["latest_frames"] is not None:
            assert h["frames_png"] and (index.parent / h["frames_png"]).is_file()


def test_counts_match_the_database_and_the_runner(sim):
    db, _index, rep, summary = sim
    s = rep["summary"]
    assert s["visits"] == q(db, "SELECT COUNT(*) FROM visits")[0][0] == summary["visits"]
    assert s["observations"] == q(db, "SELECT COUNT(*) FROM observations")[0][0]
    assert s["valid_observations"] == q(db, "SELECT COUNT(*) FROM observations WHERE valid = 1")[0][0]
    valid_visits = q(db, "SELECT COUNT(DISTINCT visit_id) FROM observations WHERE valid = 1")[0][0]
    assert s["valid_visits"] == valid_visits == summary["valid_visits"]
    assert s["accepted"] == summary["accepted"]
    # the sky figure over accepted heliostats only: none here, so none (not the all-heliostat one)
    assert summary["accepted"] == 0 and summary["true_sky_rms_accepted_mrad"] is None
    assert summary["true_sky_rms_mrad"] > 0
    assert s["visits_by_outcome"] == dict(q(db, "SELECT outcome, COUNT(*) FROM visits GROUP BY outcome"))
    # hours from the events, against the runner's own accounting (ticks of at most a weather poll)
    assert s["stowed_hours"] == pytest.approx(summary["stowed_hours"], abs=0.05)
    assert s["gated_hours"] == pytest.approx(summary["gated_hours"], abs=0.1)
    assert s["stowed_hours"] > 0.3  # the 40-minute storm


def test_pass_rate_by_sql(sim):
    db, _index, rep, _summary = sim
    visits = q(db, """
        SELECT v.id,
          (SELECT o.wind_ms FROM observations o WHERE o.visit_id = v.id AND o.wind_ms IS NOT NULL ORDER BY o.id LIMIT 1),
          (SELECT o.dni_wm2 FROM observations o WHERE o.visit_id = v.id AND o.dni_wm2 IS NOT NULL ORDER BY o.id LIMIT 1),
          EXISTS (SELECT 1 FROM observations o WHERE o.visit_id = v.id AND o.valid = 1 AND o.error_mrad < 3.5),
          (SELECT COUNT(*) FROM observations o WHERE o.visit_id = v.id)
        FROM visits v""")
    attempted = [v for v in visits if v[4] > 0]
    assert rep["summary"]["passed_visits"] == sum(v[3] for v in visits)
    assert rep["summary"]["pass_rate"] == pytest.approx(sum(v[3] for v in attempted) / len(attempted), abs=1e-4)
    for key, col in (("wind", 1), ("dni", 2)):
        fig = rep["pass_rate"][key]
        edges = np.array(fig["edges"], dtype=float)
        known = [v for v in attempted if v[col] is not None]
        k = np.clip(np.searchsorted(edges, [v[col] for v in known], side="right") - 1, 0, len(edges) - 2)
        assert fig["all"]["n"] == np.bincount(k, minlength=len(edges) - 1).tolist()
        assert fig["all"]["passed"] == np.bincount(k, weights=[v[3] for v in known],
                                                   minlength=len(edges) - 1).astype(int).tolist()
        assert fig["n_unknown"] == len(attempted) - len(known)


def test_present_error_tracking_test_and_status(sim):
    db, _index, rep, _summary = sim
    rows = {r["id"]: r for r in rep["field_map"]["heliostats"]}
    for hid in IDS:
        last = q(db, "SELECT error_mrad FROM observations WHERE heliostat_id = ? AND valid = 1 ORDER BY id DESC LIMIT 1", hid)
        assert rows[hid]["present_error_mrad"] == (None if not last else pytest.approx(last[0][0], abs=1e-4))
        v = q(db, "SELECT accepted FROM verdicts WHERE heliostat_id = ? ORDER BY id DESC LIMIT 1", hid)
        assert rows[hid]["status"] == ("no verdict" if not v else ("accepted" if v[0][0] else "not accepted"))
    first = q(db, "SELECT error_mrad, wind_ms FROM observations WHERE valid = 1 AND iteration = 0 AND wind_ms IS NOT NULL")
    f3 = rep["tracking_test"]["figure_3"]
    assert sum(f3["n"]) == len(first) and sum(f3["within"]) == sum(e <= 3.5 for e, _w in first)
    st = rep["status"]
    assert st["partly_failed"] and not st["empty"]
    assert any("stowed" in m for m in st["messages"])
    # the offline heliostat: no valid observation, its failures are in its sheet
    h2 = next(h for h in rep["heliostats"] if h["id"] == "H0002")
    n_invalid = q(db, "SELECT COUNT(*) FROM observations WHERE heliostat_id = 'H0002' AND valid = 0")[0][0]
    assert h2["valid_observations"] == 0 and h2["observations"] == n_invalid


def test_each_fitted_heliostat_has_its_year_round_prediction_beside_the_verdict(sim):
    db, index, rep, summary = sim
    yp = rep["year_prediction"]
    assert yp["limit_mrad"] == 1.2 and yp["level"] == 0.9
    # exactly the heliostats with a valid, located point (by SQL) have a fit to predict from
    with_points = {h for (h,) in q(db, "SELECT DISTINCT heliostat_id FROM observations WHERE valid = 1 "
                                       "AND spot_e_m IS NOT NULL")}
    assert set(yp["heliostats"]) == with_points and "H0002" not in with_points
    for p in yp["heliostats"].values():
        lo, hi = p["interval_mrad"]
        assert 0 < lo <= hi and p["expected_rms_mrad"] > 0 and 0.0 <= p["p_exceed"] <= 1.0
    # the same prediction as the simulation's summary made from the runner's own fits
    expected = float(np.median([p["expected_rms_mrad"] for p in yp["heliostats"].values()]))
    assert expected == pytest.approx(summary["predicted_year_rms_median_mrad"], abs=0.01)
    # no drift injected: the sky over the undrifted heliostats is the sky over all
    assert summary["drifted"] == 0 and summary["true_sky_rms_undrifted_mrad"] == summary["true_sky_rms_mrad"]
    page = index.read_text()
    assert "predicted year RMS [mrad] (90 % interval)" in page and "on the year's path" in page
