"""Damaged database contents on the console: one line naming the table and row, never HTTP 500.

A real campaign database written by a runner on the in-process simulated plant (real frames),
copied and damaged with sqlite3 the way a disk or a hand edit damages it; the console of the copy
served over real HTTP exactly as ``helicalib console DB`` serves it (and the command itself for
a damaged campaign row).
"""

from __future__ import annotations

import html
import json
import shutil
import sqlite3
import subprocess
import sys
import urllib.error
import urllib.request

import pytest

from campaign_helpers import inprocess_campaign
from helicalib.config import load_field_config

IDS = ["H0001", "H0021", "H0002"]


@pytest.fixture(scope="module")
def written(demo_field_path, tmp_path_factory):
    """A campaign database after 20 plant minutes (observations with frames, events, visits)."""
    cfg = load_field_config(demo_field_path)
    tmp = tmp_path_factory.mktemp("damage")
    runner, sim, store, cid, _c = inprocess_campaign(cfg, tmp, 9, 3, IDS, armed=True)
    runner.run_until(sim.t_s + 1200)
    store.close()
    return {"db": tmp / "c.db", "images": tmp / "img", "cid": cid, "field": demo_field_path}


def _damaged(written, tmp_path, sql: str):
    db = tmp_path / "c.db"
    shutil.copy(written["db"], db)
    conn = sqlite3.connect(db)
    with conn:
        conn.execute(sql)
    row = conn.execute("SELECT changes()").fetchone()
    conn.close()
    assert row is not None
    return db


def _get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.read().decode(errors="replace")
    except urllib.error.HTTPError as err:
        return err.code, err.read().decode(errors="replace")


def _serve(db, written):
    """The console of ``db`` as ``helicalib console DB`` builds it (in this process, a free port)."""
    from helicalib.console.app import Console, create_app
    from helicalib.console.server import ConsoleServer
    from helicalib.console.view import Sources
    from helicalib.geometry.sitetime import site_time
    from helicalib.store.sqlite import Store

    cfg = load_field_config(written["field"])

    def reopen():
        return Store.open(db, written["images"], readonly=True)

    console = Console(Sources(store=reopen(), cfg=cfg, campaign_id=written["cid"], site=site_time(cfg)),
                      reopen=reopen)
    server = ConsoleServer(create_app(console), "127.0.0.1", 0)
    server.start()
    return console, server, f"http://127.0.0.1:{server.port}/"


@pytest.mark.parametrize("sql, where", [
    ("UPDATE events SET data_json = '{\"command\": ' WHERE id = (SELECT MIN(id) FROM events)",
     "table events, row {id}: data_json is not JSON"),
    ("UPDATE observations SET after_frame_paths_json = '[\"c1/x.png\"' WHERE id = (SELECT MAX(id) FROM observations)",
     "table observations, row {id}: after_frame_paths_json is not JSON"),
    ("UPDATE observations SET capture_time_s = 'yesterday' WHERE id = (SELECT MAX(id) FROM observations)",
     "table observations, row {id}: capture_time_s is not a number (str 'yesterday')"),
    ("UPDATE visits SET started_s = 'noon' WHERE id = (SELECT MAX(id) FROM visits)",
     "table visits, row {id}: started_s is not a number (str 'noon')"),
])
def test_a_damaged_row_gives_one_line_naming_table_and_row(written, tmp_path, sql, where):
    db = _damaged(written, tmp_path, sql)
    table = where.split()[1].rstrip(",")
    agg = "MIN" if "MIN(id)" in sql else "MAX"
    conn = sqlite3.connect(db)
    row_id = conn.execute(f"SELECT {agg}(id) FROM {table}").fetchone()[0]
    conn.close()
    expected = where.format(id=row_id)
    console, server, url = _serve(db, written)
    try:
        code, body = _get(url + "api/view")
        assert code == 503, (code, body[:300])
        error = json.loads(body)["error"]
        assert expected in error and "\n" not in error and "Traceback" not in error, error
        code, page = _get(url)
        assert code == 503 and expected in html.unescape(page) and "Traceback" not in page
        code, text = _get(url + "progress.png")
        assert code in (503, 200) and "Traceback" not in text
    finally:
        server.stop()
        console.src.store.close()
        console.remove_cache()


def test_the_command_says_which_campaign_row_is_damaged(written, tmp_path):
    db = _damaged(written, tmp_path, "UPDATE campaigns SET settings_json = '{\"images_dir\": ' WHERE id = 1")
    r = subprocess.run([sys.executable, "-m", "helicalib", "console", str(db), "--listen", "127.0.0.1:0", "--json"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "table campaigns, row 1: settings_json is not JSON" in lines[0], lines
