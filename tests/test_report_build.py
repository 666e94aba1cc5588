"""report: a report built from a real SQLite campaign database filled through the Store, with real PNG frames.

The campaign is constructed (not simulated): four heliostats of the demo field, visits through the
day with rendered before/after frames, invalid observations, a failure record, a stow, a gated
span and a fault. Every figure in report.json is checked against the database read back
independently (SQL on the file, not the report's code); every linked file exists and every PNG
decodes; an empty and a partly failed campaign say so.
"""

from __future__ import annotations

import json
import re
import sqlite3
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from helicalib.config import load_field_config
from helicalib.geometry.error_model import NAMES
from helicalib.geometry.sun import sun_at_site
from helicalib.store import Observation, Store
from helicalib.vision.frames import encode_png
from helicalib.sim.render import Spot, pose_from_camera, render_frame

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"
CFG = load_field_config(FIELD)
T0 = float(pd.Timestamp("2026-06-01T00:00:00Z").timestamp()) - CFG.site.longitude_deg / 15.0 * 3600.0
IDS = ["H0001", "H0002", "H0003", "H0021"]

_FRAMES: dict = {}


def frames(target_id: str):
    """(before PNG, after PNG, spot offset u, v [m]) rendered once per target."""
    if target_id not in _FRAMES:
        t = CFG.target(target_id)
        pose = pose_from_camera(CFG.cameras_for(target_id)[0], t)
        spot = (0.9, -0.6)
        before = encode_png(render_frame(t, pose, rng=1))
        after = encode_png(render_frame(t, pose, [Spot(spot, (0.8, 0.8), peak=70)], rng=2))
        _FRAMES[target_id] = (before, after, spot)
    return _FRAMES[target_id]


def _obs(cid, hid, tid, vid, it, t, valid=True, reason="ok", err=None, wind=3.0, dni=850.0, clean=0.9, spot=None):
    pos = sun_at_site(CFG.site, np.array([t, t + 60.0]))
    el = pos.elevation_deg
    return Observation(campaign_id=cid, heliostat_id=hid, target_id=tid, visit_id=vid, iteration=it,
                       capture_time_s=t, strokes_cmd_mm=(900.0, 800.0), strokes_read_mm=(900.1, 800.2),
                       sun_enu=tuple(float(x) for x in pos.vector_enu[0]), sun_azimuth_deg=float(pos.azimuth_deg[0]),
                       sun_elevation_deg=float(el[0]), sun_rising=bool(el[1] > el[0]), valid=valid, reason=reason,
                       message=f"{reason} at placement {it}", wind_ms=wind, dni_wm2=dni, cleanliness=clean,
                       error_mrad=err if valid else None, spot_x_px=None if spot is None else spot[0],
                       spot_y_px=None if spot is None else spot[1], offset_u_m=0.9 if valid else None,
                       offset_v_m=-0.6 if valid else None)


# (heliostat, hour after local midnight, errors by placement (None = invalid), outcome, wind, dni, cleanliness)
VISITS = [
    ("H0001", 6.0, [12.0, 4.1, 1.2], "converged", 2.0, 820.0, 0.92),
    ("H0001", 9.5, [2.1], "converged", 4.0, 900.0, 0.92),
    ("H0001", 13.0, [0.9], "converged", 7.5, 880.0, 0.92),
    ("H0001", 18.5, [1.0], "converged", 11.0, 700.0, 0.92),
    ("H0002", 7.0, [18.0, 6.0, 5.0, 4.5], "not_converged", 8.2, 650.0, 0.6),
    ("H0002", 11.0, [None, 3.0], "converged", 3.5, 1000.0, 0.6),
    ("H0002", 15.0, [None], "invalid", 6.0, 350.0, 0.75),
    ("H0003", 8.0, [], "fault", None, None, None),  # a failure record only
    ("H0003", 10.0, [3.8, 2.0], "converged", 9.0, 950.0, 0.8),
]


def make_campaign(tmp: Path, *, visits=VISITS, events=True, finish=True, field=FIELD) -> Path:
    db = tmp / "campaign.db"
    store = Store.open(db, durable=False)
    heliostats = [(h, CFG.heliostat_index(h), CFG.heliostat(h).target) for h in IDS]
    cid = store.start_campaign(name="report test", mode="simulate", started_s=T0, heliostats=heliostats,
                               config_path=str(field), settings={"seed": 1})
    for hid, hour, errs, outcome, wind, dni, clean in visits:
        tid = CFG.heliostat(hid).target
        t = T0 + hour * 3600.0
        vid = store.begin_visit(cid, hid, tid, t)
        before, after, _ = frames(tid)
        if not errs:
            o = _obs(cid, hid, tid, vid, -1, t + 5, valid=False, reason="plant_fault", wind=None, dni=None, clean=None)
            store.record_observation(o)
        for it, err in enumerate(errs):
            o = _obs(cid, hid, tid, vid, it, t + 60 * (it + 1), valid=err is not None,
                     reason="ok" if err is not None else "no_spot", err=err, wind=wind, dni=dni, clean=clean,
                     spot=(686.0, 525.0) if err is not None else None)
            store.record_observation(o, before_frame=before, after_frames=[after])
        valid_errs = [e for e in errs if e is not None]
        store.end_visit(vid, ended_s=t + 60 * (len(errs) + 1), outcome=outcome, reason="ok" if outcome == "converged"
                        else outcome, iterations=len(errs), first_error_mrad=valid_errs[0] if valid_errs else None,
                        final_error_mrad=valid_errs[-1] if valid_errs else None)
        if valid_errs:
            store.record_verdict(campaign_id=cid, heliostat_id=hid, time_s=t + 600, accepted=False,
                                 n_points=len(valid_errs), rms_mrad=float(np.sqrt(np.mean(np.square(valid_errs)))),
                                 reasons=["2 valid points, 5 needed"])
    store.record_verdict(campaign_id=cid, heliostat_id="H0001", time_s=T0 + 19 * 3600, accepted=True, n_points=4,
                         rms_mrad=1.3, reasons=[])
    store.record_fit(campaign_id=cid, heliostat_id="H0001", time_s=T0 + 19 * 3600, model="error-model-13",
                     params={n: 0.1 * k for k, n in enumerate(NAMES)}, sigma={n: 0.01 * (k + 1) for k, n in enumerate(NAMES)},
                     rms_mrad=0.8, n_points=6)
    if events:
        store.record_event(campaign_id=cid, time_s=T0 + 14 * 3600, kind="stow", reason="wind 16.0 m/s above stow_wind_ms 15")
        store.record_event(campaign_id=cid, time_s=T0 + 16.5 * 3600, kind="resume", reason="wind 9 m/s")
        store.record_event(campaign_id=cid, time_s=T0 + 12 * 3600, kind="gated", reason="DNI 250 W/m² below 300")
        store.record_event(campaign_id=cid, time_s=T0 + 12.75 * 3600, kind="ungated", reason="DNI back")
        store.record_event(campaign_id=cid, time_s=T0 + 8 * 3600, kind="fault", heliostat_id="H0003",
                           reason="plant fault code 3 on a move command")
    if finish:
        store.finish_campaign(cid, T0 + 20 * 3600)
    store.close()
    return db


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    from helicalib.report.build import build_report

    tmp = tmp_path_factory.mktemp("report")
    db = make_campaign(tmp)
    index = build_report(db, tmp / "out")
    return db, index, json.loads((index.parent / "report.json").read_text())


class Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k in ("href", "src") and v:
                self.links.append(v)
            if k == "id" and v:
                self.ids.add(v)


def page_ids(page: Path) -> set[str]:
    parser = Links()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser.ids


def check_links(index: Path) -> int:
    """Every href/src of every page reachable from index.html exists; every PNG decodes. Returns pages seen."""
    seen, todo = set(), [index.resolve()]
    while todo:
        page = todo.pop()
        if page in seen:
            continue
        seen.add(page)
        parser = Links()
        parser.feed(page.read_text(encoding="utf-8"))
        for link in parser.links:
            assert not re.match(r"^[a-z]+://", link), f"{page.name}: external resource {link}"
            link, _, anchor = link.partition("#")
            target = (page.parent / link).resolve() if link else page
            if anchor:
                assert anchor in page_ids(target), f"{page.name}: no id {anchor!r} in {target.name}"
            assert target.is_file(), f"{page.name}: broken link {link}"
            if target.suffix == ".png":
                img = cv2.imread(str(target))
                assert img is not None and img.size > 0, f"{link} does not decode"
            elif target.suffix == ".html":
                todo.append(target)
            elif target.suffix == ".json":
                json.loads(target.read_text())
    return len(seen)


def test_every_link_exists_and_every_png_decodes(built):
    _db, index, rep = built
    pages = check_links(index)
    assert pages == 1 + len(IDS)
    assert all((index.parent / h["frames_png"]).is_file() for h in rep["heliostats"] if h["id"] != "H0021")


def test_summary_matches_the_database(built):
    db, _index, rep = built
    s = rep["summary"]
    con = sqlite3.connect(db)
    q = lambda sql: con.execute(sql).fetchall()  # noqa: E731
    assert s["heliostats"] == q("SELECT COUNT(*) FROM heliostats")[0][0] == len(IDS)
    assert s["visits"] == q("SELECT COUNT(*) FROM visits")[0][0]
    assert s["observations"] == q("SELECT COUNT(*) FROM observations")[0][0]
    assert s["valid_observations"] == q("SELECT COUNT(*) FROM observations WHERE valid = 1")[0][0]
    assert s["visits_by_outcome"] == dict(q("SELECT outcome, COUNT(*) FROM visits GROUP BY outcome"))
    assert s["invalid_by_reason"] == dict(q("SELECT reason, COUNT(*) FROM observations WHERE valid = 0 GROUP BY reason"))
    accepted = q("SELECT COUNT(*) FROM verdicts v WHERE accepted = 1 AND id = (SELECT MAX(id) FROM verdicts w"
                 " WHERE w.heliostat_id = v.heliostat_id)")[0][0]
    assert s["accepted"] == accepted == 1
    passed = q("SELECT COUNT(DISTINCT visit_id) FROM observations WHERE valid = 1 AND error_mrad < 3.5")[0][0]
    assert s["passed_visits"] == passed
    attempted = q("SELECT COUNT(DISTINCT visit_id) FROM observations")[0][0]
    assert s["pass_rate"] == pytest.approx(passed / attempted, abs=1e-4)
    assert s["stowed_hours"] == pytest.approx(2.5) and s["gated_hours"] == pytest.approx(0.75)
    assert s["events_by_kind"] == dict(q("SELECT kind, COUNT(*) FROM events GROUP BY kind"))


def test_field_map_present_error_and_status(built):
    db, _index, rep = built
    con = sqlite3.connect(db)
    rows = {r["id"]: r for r in rep["field_map"]["heliostats"]}
    for hid in IDS:
        last = con.execute("SELECT error_mrad FROM observations WHERE heliostat_id = ? AND valid = 1 ORDER BY id DESC"
                           " LIMIT 1", (hid,)).fetchone()
        assert rows[hid]["present_error_mrad"] == (None if last is None else pytest.approx(last[0], abs=1e-4))
        assert (rows[hid]["east_m"], rows[hid]["north_m"]) == pytest.approx(CFG.heliostat(hid).position_enu_m[:2], abs=1e-3)
    assert [rows[h]["status"] for h in IDS] == ["accepted", "not accepted", "not accepted", "no verdict"]


def test_pass_rate_figures_match_the_visits(built):
    _db, _index, rep = built
    wind = rep["pass_rate"]["wind"]
    # independent count from the construction table: visits with conditions, passed = any error < 3.5
    counted = [(w, any(e is not None and e < 3.5 for e in errs)) for _h, _t, errs, _o, w, _d, _c in VISITS if errs]
    edges = np.array(wind["edges"])
    n = np.zeros(len(edges) - 1, int)
    p = np.zeros(len(edges) - 1, int)
    for w, ok in counted:
        k = min(int(np.searchsorted(edges, w, side="right") - 1), len(n) - 1)
        n[k] += 1
        p[k] += ok
    assert wind["all"]["n"] == n.tolist() and wind["all"]["passed"] == p.tolist()
    assert wind["n_unknown"] == 1  # the visit with only a failure record
    # good_other for wind: dni >= 800 and cleanliness > 0.7
    good = [(w, any(e is not None and e < 3.5 for e in errs)) for _h, _t, errs, _o, w, d, c in VISITS
            if errs and d >= 800 and c > 0.7]
    assert sum(wind["good_other"]["n"]) == len(good)
    assert sum(wind["good_other"]["passed"]) == sum(ok for _w, ok in good)
    for key in ("dni", "cleanliness"):
        assert sum(rep["pass_rate"][key]["all"]["n"]) == len(counted)


def test_tracking_test_uses_first_placements(built):
    db, _index, rep = built
    con = sqlite3.connect(db)
    first = con.execute("SELECT error_mrad, wind_ms FROM observations WHERE valid = 1 AND iteration = 0").fetchall()
    f3 = rep["tracking_test"]["figure_3"]
    assert sum(f3["n"]) == len(first)
    assert sum(f3["within"]) == sum(1 for e, _w in first if e <= 3.5)
    bins = {b["wind_ms"]: b for b in rep["tracking_test"]["field"]["bins"]}
    at4 = [e for e, w in first if 3.0 <= w <= 5.0]
    assert bins[4.0]["n"] == len(at4) and bins[4.0]["within"] == sum(e <= 3.5 for e in at4)
    assert bins[4.0]["pass"] == (sum(e <= 3.5 for e in at4) / len(at4) > 0.99)
    assert rep["tracking_test"]["field"]["verdict"] in ("fail", "incomplete")


def test_progress_counts_over_time(built):
    db, _index, rep = built
    pr = rep["progress"]
    con = sqlite3.connect(db)
    t_end = pr["times_s"][-1]
    assert pr["visits"][-1] == con.execute("SELECT COUNT(*) FROM visits WHERE started_s <= ?", (t_end,)).fetchone()[0]
    assert pr["accepted"][-1] == 1 and pr["accepted"][0] == 0
    assert pr["stowed_hours"][-1] == pytest.approx(2.5) and pr["gated_hours"][-1] == pytest.approx(0.75)
    assert all(np.diff(pr["visits"]) >= 0) and all(np.diff(pr["valid_visits"]) >= 0)


def test_sheet_has_fit_verdict_corrections_and_frames(built):
    db, index, rep = built
    h1 = next(h for h in rep["heliostats"] if h["id"] == "H0001")
    assert h1["status"] == "accepted" and h1["verdict"]["reasons"] == []
    assert [p["name"] for p in h1["fit"]["parameters"]] == list(NAMES)
    assert h1["fit"]["parameters"][3]["value"] == pytest.approx(0.3) and h1["fit"]["parameters"][3]["sigma"] == pytest.approx(0.04)
    assert h1["corrections"][0]["errors_mrad"] == [12.0, 4.1, 1.2]
    lf = h1["latest_frames"]
    assert lf["remeasured"]["valid"], lf["note"]
    assert lf["remeasured"]["offset_m"] == pytest.approx([0.9, -0.6], abs=0.05)  # the rendered spot, measured again
    sheet = json.loads((index.parent / h1["json"]).read_text())
    con = sqlite3.connect(db)
    ids = [r[0] for r in con.execute("SELECT id FROM observations WHERE heliostat_id = 'H0001' ORDER BY id")]
    assert [r["id"] for r in sheet["observation_rows"]] == ids
    h2 = next(h for h in rep["heliostats"] if h["id"] == "H0002")
    assert h2["verdict"]["reasons"] == ["2 valid points, 5 needed"]
    page = (index.parent / h2["href"]).read_text()
    assert "2 valid points, 5 needed" in page and "not accepted" in page


def test_banner_lists_what_to_act_on(built):
    _db, index, rep = built
    st = rep["status"]
    assert st["partly_failed"] and not st["empty"] and st["level"] == "action"
    actions, info = " ".join(st["actions"]), " ".join(st["information"])
    assert "fault" in actions and "H0003" in actions  # the fault event names its heliostat
    assert "not accepted" in actions and "H0002" in actions and "no verdict" in actions and "H0021" in actions
    assert "stowed" in info and "no_spot" in info  # information, not an action
    assert st["messages"] == st["actions"] + st["information"]
    page = index.read_text()
    assert 'class="banner action"' in page and "To act on" in page


def test_empty_campaign_says_so(tmp_path):
    from helicalib.report.build import build_report

    db = make_campaign(tmp_path, visits=[], events=False, finish=False)
    index = build_report(db, tmp_path / "out")
    rep = json.loads((index.parent / "report.json").read_text())
    assert rep["status"]["empty"] and rep["status"]["level"] == "empty"
    assert rep["summary"]["visits"] == 0 and rep["summary"]["pass_rate"] is None
    assert "Empty campaign" in index.read_text() and "unfinished" in " ".join(rep["status"]["messages"])
    check_links(index)


def test_database_without_campaign_and_missing_config(tmp_path):
    from helicalib.report.build import build_report

    Store.open(tmp_path / "none.db").close()
    index = build_report(tmp_path / "none.db", tmp_path / "out0")
    rep = json.loads((index.parent / "report.json").read_text())
    assert rep["status"]["empty"] and rep["campaign"] is None and rep["heliostats"] == []
    check_links(index)
    db = make_campaign(tmp_path, field=tmp_path / "moved.yaml")  # the config is gone: figures still come
    index = build_report(db, tmp_path / "out1")
    rep = json.loads((index.parent / "report.json").read_text())
    assert not rep["field_map"]["available"] and "not found" in rep["field_map"]["note"]
    assert rep["summary"]["visits"] == len(VISITS)
    check_links(index)


def test_cli_report(tmp_path, capsys):
    from helicalib.cli import main

    db = make_campaign(tmp_path)
    assert main(["report", str(db), "--out", str(tmp_path / "cli"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["summary"]["visits"] == len(VISITS) and Path(out["index"]).is_file()
    assert main(["report", str(tmp_path / "missing.db"), "--out", str(tmp_path / "x")]) == 1


def test_parallel_sheets_equal_serial(built, tmp_path, monkeypatch):
    from helicalib.report import build

    db, index, rep = built
    monkeypatch.setattr(build, "PARALLEL_MIN_HELIOSTATS", 2)
    index2 = build.build_report(db, tmp_path / "par", jobs=2)
    rep2 = json.loads((index2.parent / "report.json").read_text())
    assert [h["id"] for h in rep2["heliostats"]] == IDS
    for a, b in zip(rep["heliostats"], rep2["heliostats"]):
        assert a == b
    check_links(index2)
