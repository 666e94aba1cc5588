"""One campaign against three plants, each simulated and served on loopback: PLANT_INTERFACE.md's
Modbus map, an SCS-B plant through the shipped ``scs-b`` map (input registers, low word first,
scaled integers, status bits, an execute handshake) and an OPC UA plant through its node map.

With ``lockstep`` the served plant keeps the controller's virtual clock, so the same seed gives
the same campaign: every visit, observation and verdict the same, the numbers equal to within
what the plants' encodings carry (SCS-B's 0.01 mm and 0.01 m/s integers, f32 floats)."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from helicalib.app.simulated import SimulationOptions, simulate_campaign
from helicalib.config import load_field_config
from helicalib.sim.scenario import Scenario

from conftest import ROOT

PLANTS = {"plant-interface-1": dict(protocol="modbus", register_map=None),
          "scs-b": dict(protocol="modbus", register_map="scs-b"),
          "opcua": dict(protocol="opcua", register_map=None)}
IDS = ["H0001", "H0002"]
DAYS = 0.5


def _rows(db, sql):
    con = sqlite3.connect(db)
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    cfg = load_field_config(ROOT / "field_config" / "demo_north.yaml")
    out = {}
    for name, plant in PLANTS.items():
        o = SimulationOptions(DAYS, seed=4, scenario=Scenario(), heliostat_ids=IDS, over_network=True,
                              lockstep=True, **plant)
        res = simulate_campaign(cfg, tmp_path_factory.mktemp(name), o)
        db = res.database
        out[name] = {
            "summary": res.summary,
            "visits": _rows(db, "select heliostat_id, started_s, ended_s, outcome, reason, final_error_mrad from visits "
                                "order by id"),
            "obs": _rows(db, "select heliostat_id, iteration, valid, reason, capture_time_s, stroke_cmd_1_mm, "
                             "stroke_cmd_2_mm, wind_ms, dni_wm2 from observations order by id"),
            "verdicts": _rows(db, "select heliostat_id, time_s, accepted, n_points, reasons_json, rms_mrad from verdicts order by id"),
            "events": _rows(db, "select time_s, kind, heliostat_id from events where kind != 'campaign' order by id"),
        }
    return out


def test_the_runs_measure_something(runs):
    for name, r in runs.items():
        assert r["summary"]["valid_visits"] >= 5, name
        assert any(o[2] for o in r["obs"]), name


def _words(text: str) -> str:
    """A reason without its decimal numbers (``15.05 mrad`` → ``# mrad``)."""
    import re

    return re.sub(r"[-+]?\d+\.\d+", "#", text or "")


@pytest.mark.parametrize("other", ["scs-b", "opcua"])
def test_the_same_campaign_over_another_plant(runs, other):
    a, b = runs["plant-interface-1"], runs[other]
    # the same visits at the same plant times, the same observations and verdicts, the same events
    # a reason's numbers carry the plant's register resolution (SCS-B: 0.01 mm strokes): compared below
    assert [(v[0], v[3], _words(v[4])) for v in a["visits"]] == [(v[0], v[3], _words(v[4])) for v in b["visits"]]
    np.testing.assert_allclose([np.nan if v[5] is None else v[5] for v in a["visits"]],
                               [np.nan if v[5] is None else v[5] for v in b["visits"]], rtol=0, atol=0.02)
    np.testing.assert_allclose([v[1] for v in a["visits"]], [v[1] for v in b["visits"]], rtol=0, atol=1e-3)
    assert [o[:4] for o in a["obs"]] == [o[:4] for o in b["obs"]]
    np.testing.assert_allclose([o[4] for o in a["obs"]], [o[4] for o in b["obs"]], rtol=0, atol=1e-3)
    # commanded strokes: SCS-B carries 0.01 mm; weather 0.01 m/s and 1 W/m²
    np.testing.assert_allclose(np.array([o[5:7] for o in a["obs"]], float),
                               np.array([o[5:7] for o in b["obs"]], float), rtol=0, atol=0.011)
    np.testing.assert_allclose([o[7] for o in a["obs"]], [o[7] for o in b["obs"]], rtol=0, atol=0.006)
    np.testing.assert_allclose([o[8] for o in a["obs"]], [o[8] for o in b["obs"]], rtol=0, atol=0.51)
    same = lambda v: v[0:1] + v[2:4] + (_words(v[4]),)  # noqa: E731 - a reason's RMS at the registers' resolution
    assert [same(v) for v in a["verdicts"]] == [same(v) for v in b["verdicts"]]
    rms = lambda r: [np.nan if v[5] is None else v[5] for v in r["verdicts"]]  # noqa: E731
    np.testing.assert_allclose(rms(a), rms(b), rtol=0, atol=0.01)
    assert [e[1:] for e in a["events"]] == [e[1:] for e in b["events"]]  # (their texts carry the numbers)
    np.testing.assert_allclose([e[0] for e in a["events"]], [e[0] for e in b["events"]], rtol=0, atol=1e-3)
    for key in ("visits", "valid_visits", "accepted"):
        assert a["summary"][key] == b["summary"][key], key
