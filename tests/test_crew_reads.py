"""What a crew reads at field scale: ``status``'s summary, the console's heliostats table (real
HTTP on 127.0.0.1) and its canvas map (headless Chromium), on one synthetic campaign database of
a few thousand heliostats built once for the module (:mod:`helicalib.store.synthetic`).

Every figure is checked against numbers computed here from the store's rows by other means (SQL
of our own, the verdicts read one by one), not against the code under test.
"""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import yaml

from helicalib.config import load_field_config
from helicalib.store.sqlite import Store
from helicalib.store.synthetic import build_synthetic_campaign, open_for_synthesis
from test_console_browser import browser  # noqa: F401 - the module's headless Chromium (a fixture)

DEMO = "field_config/demo_north.yaml"
N = 2000
"""Heliostats of the synthetic field: past the summary's threshold and the map's SVG limit."""
OUT = {"H00003", "H01999"}
"""Taken out of service by the crew (the first accepted, the second not)."""


def big_field(n: int, path: Path):
    """The demo field with ``n`` heliostats on a grid north of the tower (ids H00001...), boards
    alternating, written to ``path``: a field config of any size without sim-field's year of checks."""
    data = yaml.safe_load(Path(DEMO).read_text())
    side = int(np.ceil(np.sqrt(n)))
    targets = [t["id"] for t in data["targets"]]
    drive = data["heliostats"][0]["drive"]
    del data["heliostats"]
    data["heliostats_csv"] = path.with_suffix(".csv").name
    lines = ["id,e_m,n_m,u_m,drive,target"] + [
        f"H{i + 1:05d},{-120.0 + 8.0 * (i % side)},{40.0 + 8.0 * (i // side)},4.3,{drive},{targets[i % len(targets)]}"
        for i in range(n)]
    path.with_suffix(".csv").write_text("\n".join(lines) + "\n")
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_field_config(path)


@pytest.fixture(scope="module")
def crew_db(tmp_path_factory):
    """A 5-day campaign of N heliostats (450 commissioned a day: the last ones not accepted yet),
    with two taken out of service by the crew, one of them accepted."""
    folder = tmp_path_factory.mktemp("crew")
    cfg = big_field(N, folder / "field.yaml")
    path = folder / "crew.db"
    with open_for_synthesis(path) as store:
        s = build_synthetic_campaign(store, cfg, days=5, per_day=450, seed=4)
    with Store.open(path) as store:
        for hid in sorted(OUT):
            a = store.request_action(campaign_id=s.campaign_id, kind="out_of_service", heliostat_ids=[hid], who="test",
                                     requested_wall_s=0.0, requested_s=None)
            store.finish_action(a, done_s=1.0, outcome="out of service")
    return cfg, path, s.campaign_id, expected(path, s.campaign_id)


def expected(path: Path, cid: int) -> dict:
    """Per heliostat, from our own SQL: board, newest verdict (accepted, reasons), last valid error."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    rows = {}
    for hid, target in con.execute("SELECT heliostat_id, target_id FROM heliostats WHERE campaign_id = ? "
                                   "ORDER BY block_index", (cid,)):
        v = con.execute("SELECT accepted, reasons_json FROM verdicts WHERE campaign_id = ? AND heliostat_id = ? "
                        "ORDER BY id DESC LIMIT 1", (cid, hid)).fetchone()
        e = con.execute("SELECT error_mrad FROM observations WHERE campaign_id = ? AND heliostat_id = ? AND valid = 1 "
                        "ORDER BY id DESC LIMIT 1", (cid, hid)).fetchone()
        rows[hid] = {"target": target, "accepted": None if v is None else bool(v[0]),
                     "reasons": [] if v is None else json.loads(v[1]), "error": None if e is None else e[0]}
    con.close()
    return rows


def status(capsys, monkeypatch, *argv) -> str:
    """``helicalib status ...`` in this process (a wide terminal); its standard output."""
    from helicalib.cli import main

    monkeypatch.setenv("COLUMNS", "160")
    capsys.readouterr()
    assert main(["status", *argv]) == 0
    return capsys.readouterr().out


def test_status_summary_per_board_and_attention(crew_db, capsys, monkeypatch):
    cfg, path, cid, exp = crew_db
    pending = [h for h, r in exp.items() if not r["accepted"] and h not in OUT]
    assert 0 < len(pending) < N  # the module's database has both kinds
    got = json.loads(status(capsys, monkeypatch, str(path), "--json"))
    boards = {b["target_id"]: b for b in got["summary"]["boards"]}
    for tid in {r["target"] for r in exp.values()}:
        mine = {h: r for h, r in exp.items() if r["target"] == tid}
        errors = [r["error"] for r in mine.values() if r["error"] is not None]
        b = boards[tid]
        assert b["heliostats"] == len(mine)
        assert b["out_of_service"] == len(OUT & set(mine))
        assert b["accepted"] == sum(1 for h, r in mine.items() if r["accepted"] and h not in OUT)
        assert b["pending"] == sum(1 for h, r in mine.items() if not r["accepted"] and h not in OUT)
        assert b["error_p50_mrad"] == pytest.approx(float(np.median(errors)))
        assert b["error_p90_mrad"] == pytest.approx(float(np.quantile(errors, 0.9)))
        assert b["error_max_mrad"] == pytest.approx(max(errors))
    assert got["summary"]["needing_attention"] == len(pending)
    assert got["out_of_service"] == sorted(OUT)
    assert len(got["heliostats"]) == N  # --json keeps every heliostat's row
    worst = sorted((r["error"] for r in exp.values() if r["error"] is not None), reverse=True)[:10]
    assert [w["last_error_mrad"] for w in got["summary"]["worst"]] == pytest.approx(worst)


def test_status_terminal_summary_lists_attention_in_block_order(crew_db, capsys, monkeypatch):
    cfg, path, cid, exp = crew_db
    pending = [h for h, r in exp.items() if not r["accepted"] and h not in OUT]
    text = status(capsys, monkeypatch, str(path))
    assert f"{len(pending)} heliostat(s) need attention" in text
    assert f"the first 20 of {len(pending)} in block order" in text
    shown = [line.split()[1] for line in text.splitlines() if line.startswith("│ H")]
    assert shown[:20] == pending[:20]
    assert len(text.splitlines()) < 120  # a summary, not N rows
    full = status(capsys, monkeypatch, str(path), "--all")
    assert sum(1 for line in full.splitlines() if line.startswith("│ H")) == N


# ---------------------------------------------------------------------------------------------- console
@pytest.fixture(scope="module")
def console_url(crew_db):
    """``helicalib console DB`` on 127.0.0.1 (a free port) for the module."""
    cfg, path, cid, _exp = crew_db
    field = path.parent / "field.yaml"
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", "console", str(path), "--listen", "127.0.0.1:0",
                             "--json", "--field", str(field)], stdout=subprocess.PIPE, text=True)
    try:
        yield json.loads(proc.stdout.readline())["url"].rstrip("/")
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def table(url: str, query: str = "") -> dict:
    with urllib.request.urlopen(f"{url}/api/heliostats?{query}", timeout=60) as resp:
        return json.loads(resp.read())


def test_table_pages_in_block_order(crew_db, console_url):
    cfg, path, cid, exp = crew_db
    ids = list(exp)
    first, second = table(console_url, "limit=100"), table(console_url, "offset=100&limit=100")
    assert first["total"] == first["matched"] == N
    assert [r["heliostat_id"] for r in first["rows"] + second["rows"]] == ids[:200]
    last = table(console_url, f"offset={N - 7}")
    assert [r["heliostat_id"] for r in last["rows"]] == ids[-7:]


def test_table_filters_by_board_verdict_and_error_and_sorts(crew_db, console_url):
    cfg, path, cid, exp = crew_db
    page = table(console_url, "board=T2&verdict=not-accepted&limit=500")
    want = [h for h, r in exp.items() if r["target"] == "T2" and r["accepted"] is False and h not in OUT]
    assert page["matched"] == len(want) and [r["heliostat_id"] for r in page["rows"]] == want[:500]
    page = table(console_url, "verdict=out-of-service")
    assert {r["heliostat_id"] for r in page["rows"]} == OUT
    page = table(console_url, "min_error=1.5&max_error=2.5&sort=last_error_mrad&order=desc&limit=500")
    want = sorted((r["error"] for r in exp.values() if r["error"] is not None and 1.5 <= round(r["error"], 3) <= 2.5),
                  reverse=True)
    assert page["matched"] == len(want)
    assert [r["last_error_mrad"] for r in page["rows"]] == pytest.approx(want[:500], abs=1e-3)
    up = table(console_url, "sort=heliostat_id&order=desc&limit=3")
    assert [r["heliostat_id"] for r in up["rows"]] == sorted(exp, reverse=True)[:3]


def test_table_refuses_a_bad_parameter_in_one_line(console_url):
    for query, word in (("sort=nope", "sort='nope'"), ("limit=0", "limit=0"), ("min_error=x", "min_error='x'"),
                        ("verdict=maybe", "verdict='maybe'"), ("colour=red", "'colour'"),
                        ("offset=%C2%B2", "offset='²'"),  # a digit to str.isdigit, not to int()
                        ("offset=" + "9" * 5000, "offset='999")):  # more digits than int() takes
        with pytest.raises(urllib.error.HTTPError) as err:
            table(console_url, query)
        assert err.value.code == 400
        line = json.loads(err.value.read())["error"]
        assert word in line and "\n" not in line


def test_the_map_draws_every_heliostat_and_the_table_fills(console_url, browser):
    """The canvas map of a field past the SVG limit draws every heliostat; the table's first page
    fills and sorts from a column click (Chromium: test_console_browser's module browser)."""
    from selenium.webdriver.support.ui import WebDriverWait

    driver = browser
    driver.get(console_url + "/")
    WebDriverWait(driver, 60).until(lambda d: d.execute_script(
        "var c = document.getElementById('field-canvas'); return c && c.dataset.drawn && "
        "document.getElementById('hel-info').dataset.total"))
    drawn = driver.execute_script("return Number(document.getElementById('field-canvas').dataset.drawn)")
    assert drawn == N
    assert driver.execute_script("return document.querySelectorAll('svg.field circle').length") == 0
    # the canvas's pixels: dots were painted (not just counted)
    painted = driver.execute_script(
        "var c = document.getElementById('field-canvas'), d = c.getContext('2d').getImageData(0, 0, c.width, "
        "c.height).data, k = 0; for (var i = 3; i < d.length; i += 4) { if (d[i] > 0) { k++; } } return k;")
    assert painted > N
    assert driver.execute_script("return document.querySelectorAll('#hel-rows tr').length") == 50
    driver.execute_script("document.querySelector(\"th[data-sort='last_error_mrad']\").click()")
    driver.execute_script("document.querySelector(\"th[data-sort='last_error_mrad']\").click()")
    WebDriverWait(driver, 30).until(lambda d: d.execute_script(
        "return document.querySelector(\"th[data-sort='last_error_mrad']\").classList.contains('sorted-desc')"))
    shown = driver.execute_script("return Array.from(document.querySelectorAll('#hel-rows tr td:nth-child(7)'))"
                                  ".map(function (td) { return Number(td.textContent); })")
    assert shown == sorted(shown, reverse=True) and len(shown) == 50


OLD_KEYS = {"campaign", "shown_because", "name", "mode", "status", "owner", "plant_unreachable_since",
            "plant_unreachable_since_s", "gate", "weather", "newest_record", "newest_record_s", "accepted",
            "heliostats", "stows", "off_tracking"}
ROW_KEYS = {"heliostat_id", "target_id", "visits", "observations", "valid", "last_error_mrad", "accepted", "rms_mrad",
            "reasons"}
"""``status --json``'s keys and per-heliostat keys before the summary was added (kept as they are)."""


def test_a_small_field_keeps_its_table_and_json(tmp_path, capsys, monkeypatch):
    cfg = big_field(40, tmp_path / "field.yaml")
    path = tmp_path / "small.db"
    with open_for_synthesis(path) as store:
        s = build_synthetic_campaign(store, cfg, days=3, per_day=20, seed=2)
    exp = expected(path, s.campaign_id)
    got = json.loads(status(capsys, monkeypatch, str(path), "--json"))
    assert OLD_KEYS <= set(got) and set(got) - OLD_KEYS == {"summary", "out_of_service"}
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    for row in got["heliostats"]:
        assert set(row) == ROW_KEYS
        hid, r = row["heliostat_id"], exp[row["heliostat_id"]]
        assert (row["target_id"], row["accepted"], list(row["reasons"])) == (r["target"], r["accepted"], r["reasons"])
        assert row["last_error_mrad"] == (None if r["error"] is None else pytest.approx(r["error"]))
        assert row["visits"] == con.execute("SELECT COUNT(*) FROM visits WHERE heliostat_id = ?", (hid,)).fetchone()[0]
        assert (row["observations"], row["valid"]) == con.execute(
            "SELECT COUNT(*), COALESCE(SUM(valid), 0) FROM observations WHERE heliostat_id = ?", (hid,)).fetchone()
    con.close()
    assert [row["heliostat_id"] for row in got["heliostats"]] == list(exp)
    text = status(capsys, monkeypatch, str(path))
    assert sum(1 for line in text.splitlines() if line.startswith("│ H")) == 40  # every heliostat, as before
    assert "need attention" not in text and "err p50" not in text
