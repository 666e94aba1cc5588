"""The report of a field past the small-field limits (helicalib.report.overview): its overview's table
and map hold every heliostat, every sheet linked from them exists, the band counts and statuses are
the store's, and the search, filters and paging work in a real headless Chromium. One synthetic
campaign database built once for the module (:mod:`helicalib.store.synthetic`); the expected figures
come from SQL of our own, not from the code under test."""

from __future__ import annotations

import json
import sqlite3

import pytest

from helicalib.report.build import FULL_PLOTS_MAX, build_report
from helicalib.store.synthetic import build_synthetic_campaign, open_for_synthesis
from test_console_browser import browser  # noqa: F401 - the module's headless Chromium (a fixture)
from test_crew_reads import big_field

N = FULL_PLOTS_MAX + 100
"""Heliostats: past the limit up to which every sheet gets its drawn plot and the page a static table."""


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scale")
    cfg = big_field(N, folder / "field.yaml")
    db = folder / "big.db"
    with open_for_synthesis(db) as store:
        s = build_synthetic_campaign(store, cfg, days=3, per_day=250, seed=5)
    seen = []
    index = build_report(db, folder / "report", jobs=2, frames=False,
                         progress=lambda done, total, what: seen.append((done, total)))
    rep = json.loads((index.parent / "report.json").read_text())
    return cfg, db, s.campaign_id, index, rep, seen


def _rows(rep) -> list[dict]:
    ov = rep["overview"]
    return [dict(zip(ov["columns"], r)) for r in ov["rows"]]


def test_overview_holds_every_heliostat_with_the_store_s_status(built):
    cfg, db, cid, _index, rep, seen = built
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    boards = dict(con.execute("SELECT heliostat_id, target_id FROM heliostats WHERE campaign_id = ?", (cid,)))
    newest = dict(con.execute("SELECT heliostat_id, accepted FROM verdicts WHERE id IN (SELECT MAX(id) FROM verdicts "
                              "WHERE campaign_id = ? GROUP BY heliostat_id)", (cid,)))
    rows = _rows(rep)
    assert len(rows) == len(boards) == N and [r["id"] for r in rows] == [h.id for h in cfg.heliostats]
    status = {None: "no verdict", 0: "not accepted", 1: "accepted"}
    assert {r["id"]: r["status"] for r in rows} == {h: status[newest.get(h)] for h in boards}
    assert {r["id"]: r["board"] for r in rows} == boards
    assert 0 < sum(r["status"] == "accepted" for r in rows) < N  # both kinds on the page
    by_board = {b["board"]: b for b in rep["overview"]["boards"]}
    assert sum(b["heliostats"] for b in by_board.values()) == N
    for board, b in by_board.items():
        mine = [r for r in rows if r["board"] == board]
        assert b["heliostats"] == len(mine) and b["accepted"] == sum(r["status"] == "accepted" for r in mine)
    assert seen[-1] == (N, N) and len(seen) >= 2  # progress while the sheets are written


def test_band_counts_are_the_store_s(built):
    _cfg, db, cid, _index, rep, _seen = built
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    q = ("SELECT heliostat_id, SUM(sun_rising = 1 AND sun_elevation_deg BETWEEN 5 AND 15), "
         "SUM(sun_rising = 0 AND sun_elevation_deg BETWEEN 5 AND 15), SUM(sun_elevation_deg > 15) FROM observations "
         "WHERE campaign_id = ? AND valid = 1 AND error_mrad IS NOT NULL GROUP BY heliostat_id")
    counts = {h: (r, s, u) for h, r, s, u in con.execute(q, (cid,))}
    rows = _rows(rep)
    assert {r["id"]: (r["rising_points"], r["setting_points"], r["high_points"]) for r in rows} == \
        {r["id"]: counts.get(r["id"], (0, 0, 0)) for r in rows}
    bands = rep["overview"]["bands"]
    both = sum(1 for r, s, _u in counts.values() if r and s)
    assert bands["both_bands"] == both and bands["heliostats"] == N
    assert bands["rising_covered"] == sum(1 for r, _s, _u in counts.values() if r)


def test_every_sheet_linked_from_the_table_and_map_exists(built):
    cfg, _db, _cid, index, rep, _seen = built
    rows = _rows(rep)
    where = {h.id: h.position_enu_m for h in cfg.heliostats}
    for r in rows:
        page = index.parent / r["href"]
        assert page.is_file(), r["href"]
        assert (r["east_m"], r["north_m"]) == pytest.approx(tuple(where[r["id"]][:2]), abs=1e-3)
    text = {r["status"]: (index.parent / r["href"]).read_text() for r in rows}
    assert 'id="error-chart"' in text["accepted"] and ".png" not in text["accepted"].split("Observations and")[1][:400]
    drawn = [r for r in rows if r["status"] != "accepted"]
    assert all((index.parent / r["href"]).with_suffix(".png").is_file() for r in drawn)
    assert not any((index.parent / r["href"]).with_suffix(".png").exists() for r in rows if r["status"] == "accepted")
    page = index.read_text()
    assert 'id="overview-data"' in page and page.count("<tr><td><a href=") == 0  # no static table of N rows
    assert rep["year_prediction"] is None and "--predictions" in rep["year_prediction_note"]


def test_search_filters_and_paging_in_a_browser(built, browser):  # noqa: F811 - the fixture imported above
    from selenium.webdriver.support.ui import WebDriverWait

    _cfg, _db, _cid, index, rep, _seen = built
    rows = _rows(rep)
    driver = browser
    driver.get(index.resolve().as_uri())
    WebDriverWait(driver, 60).until(lambda d: d.execute_script(
        "var c = document.getElementById('ov-map'); return c && c.dataset.drawn"))
    assert int(driver.execute_script("return document.getElementById('ov-map').dataset.drawn")) == N
    shown = lambda: driver.execute_script(  # noqa: E731
        "return Array.from(document.querySelectorAll('#ov-table tbody tr td:first-child a'))"
        ".map(function(a){return a.getAttribute('href');})")
    assert len(shown()) == 100 and driver.execute_script("return document.getElementById('ov-count').textContent") \
        == f"{N} of {N} heliostats"
    driver.execute_script("var q = document.getElementById('ov-q'); q.value = 'H00042';"
                          "q.dispatchEvent(new Event('input'));")
    assert shown() == [r["href"] for r in rows if "h00042" in r["id"].lower()]
    board = rows[1]["board"]
    driver.execute_script(f"var q = document.getElementById('ov-q'); q.value = '';"
                          f"var b = document.getElementById('ov-board'); b.value = {json.dumps(board)};"
                          f"b.dispatchEvent(new Event('input'));")
    mine = [r for r in rows if r["board"] == board]
    assert driver.execute_script("return document.getElementById('ov-count').textContent") == \
        f"{len(mine)} of {N} heliostats"
    driver.execute_script("document.getElementById('ov-next').click()")
    assert shown() == [r["href"] for r in sorted(mine, key=lambda r: r["id"])][100:200]
