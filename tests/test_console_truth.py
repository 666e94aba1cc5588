"""What the console page says is true: the board's label and its frames, the gate's banner and its
figures, cleanliness, the progress plot early in a run, frames found where the campaign wrote
them, the campaign shown by default, and a plant that stopped answering.

A real runner on the in-process simulated plant (real PNG frames, a real SQLite file whose frames
folder is NOT "images beside the database"), its console attached as ``helicalib run --console``
attaches it, and ``helicalib console DB`` as a subprocess, over real HTTP on loopback.
"""

from __future__ import annotations

import dataclasses
import html
import io
import json
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest

from campaign_helpers import inprocess_campaign
from helicalib.app.terminal import LineLog
from helicalib.config import load_field_config
from helicalib.console.server import ConsoleOptions, attach_console
from helicalib.store.sqlite import Store

IDS = ["H0001", "H0021", "H0002", "H0003", "H0022"]


def _get(url: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.read(), r.headers.get("content-type", "")
    except urllib.error.HTTPError as err:
        return err.code, err.read(), err.headers.get("content-type", "")


def _view(base: str) -> dict:
    code, body, _t = _get(base + "api/view")
    assert code == 200, body[:300]
    return json.loads(body)


def _page(base: str) -> str:
    code, body, _t = _get(base)
    assert code == 200
    return html.unescape(body.decode())


@pytest.fixture(scope="module")
def live(demo_field_path, tmp_path_factory):
    """An armed runner stopped where board T1 holds a heliostat whose frames are not taken yet while
    the newest frames on T1 are an earlier visit's (what a crew sees at each new visit)."""
    import datetime as dt

    cfg = load_field_config(demo_field_path)
    tmp = tmp_path_factory.mktemp("truth")
    runner, sim, store, cid, _c = inprocess_campaign(cfg, tmp, 9, 3, IDS, armed=True)
    first_on_t1 = None
    for _ in range(4000):
        runner.run_until(sim.t_s + 2)
        on_t1 = [h for h, v in runner.state.active.items() if v.target_id == "T1"]
        framed = store.latest_by_target(cid, with_frames=True).get("T1")
        if on_t1 and framed is not None and framed.heliostat_id not in on_t1:
            first_on_t1 = on_t1[0]
            break
    assert first_on_t1, "no new visit on T1 after an earlier one's frames"
    output = attach_console(ConsoleOptions(console="127.0.0.1:0"), runner,
                            LineLog(dt.timezone.utc, io.StringIO()))
    snap = runner.snapshot(sim.t_s)
    output.on_snapshot(snap)
    try:
        yield {"runner": runner, "sim": sim, "store": store, "cid": cid, "output": output, "snap": snap,
               "base": f"http://127.0.0.1:{output.server.port}/", "tmp": tmp, "cfg": cfg, "field": demo_field_path}
    finally:
        output.stop()
        store.close()


def _show(live, snap):
    """Hand the console a snapshot and wait out its one-second view cache."""
    live["output"].on_snapshot(snap)
    live["output"].feed.bump()


def test_a_board_labels_its_frames_with_the_visit_they_belong_to(live):
    store, cid = live["store"], live["cid"]
    framed = store.latest_by_target(cid, with_frames=True)["T1"]
    v = _view(live["base"])
    (t1,) = [b for b in v["boards"] if b["target"] == "T1"]
    assert t1["heliostat"] != framed.heliostat_id  # the board holds the new visit's heliostat
    f = t1["frames"]
    assert (f["id"], f["heliostat"], f["time_s"]) == (framed.id, framed.heliostat_id, framed.capture_time_s)
    assert f["this_visit"] is False and f["age_s"] >= 0
    page = _page(live["base"])
    board = page[page.index('id="board-T1"'):page.index('id="board-T2"')]
    assert "Newest frames on T1: an earlier visit" in board
    assert f"<strong>{framed.heliostat_id}</strong>" in board
    assert f"before and after frames of {framed.heliostat_id}" in board
    code, png, ctype = _get(live["base"] + f"frames/{f['id']}.png")
    assert code == 200 and ctype == "image/png" and png.startswith(b"\x89PNG")


def test_each_board_shows_the_cleanliness_of_its_reading(live):
    store, cid = live["store"], live["cid"]
    v = _view(live["base"])
    page = _page(live["base"])
    for b in v["boards"]:
        obs = store.latest_by_target(cid, with_frames=True).get(b["target"])
        if obs is None:
            continue
        assert obs.cleanliness is not None
        assert b["frames"]["cleanliness"] == round(obs.cleanliness, 2)
        assert f"cleanliness {b['frames']['cleanliness']:g}" in page or f"cleanliness {b['frames']['cleanliness']}" in page


def test_the_gate_banner_and_its_figures_are_one_reading(live):
    """While every board is busy the controller does not re-judge the gate: its reason still says
    the DNI of an older reading (399) while the newest reading is 295, under the 300 minimum. The
    banner and the table must both be the newest reading, with its time and age."""
    snap = live["snap"]
    stale = dataclasses.replace(
        snap, dni_wm2=295.0, wind_ms=3.0, gate_open=True, night=False, stowed=False,
        gate_reason="calibration allowed: wind 3.0 m/s (good), DNI 399 W/m² (good)",
        weather_time_s=snap.time_s - 120.0, sun_elevation_deg=max(snap.sun_elevation_deg, 30.0))
    _show(live, stale)
    v = _view(live["base"])
    g = v["gate"]
    assert g["dni_wm2"] == 295 and g["as_of_s"] == stale.weather_time_s and g["age_s"] == pytest.approx(120.0)
    assert "DNI 295 W/m² ≤ 300 W/m²: no calibration" in g["text"] and g["open"] is False
    page = _page(live["base"])
    panel = page[page.index("<h2>Gate</h2>"):page.index('id="panel-boards"')]
    assert "399" not in panel and "DNI 295" in panel and "2.0 min old" in panel


def test_a_plant_that_stopped_answering_is_said_with_the_age_of_the_readings(live):
    snap = live["snap"]
    lost = dataclasses.replace(snap, plant_unreachable_since_s=snap.time_s - 900.0, gate_open=True,
                               gate_reason="calibration allowed: wind 3.0 m/s (good), DNI 900 W/m² (good)",
                               wind_ms=3.0, dni_wm2=900.0, weather_time_s=snap.time_s - 960.0)
    _show(live, lost)
    v = _view(live["base"])
    assert v["gate"]["unreachable_since_s"] == lost.plant_unreachable_since_s and v["gate"]["open"] is False
    page = _page(live["base"])
    panel = page[page.index("<h2>Gate</h2>"):page.index('id="panel-boards"')]
    assert "<strong>PLANT UNREACHABLE</strong> since" in panel and "(15.0 min)" in panel
    assert "calibration allowed" not in panel and "16.0 min old" in panel
    _show(live, snap)


def test_the_progress_plot_spans_the_run_not_years(live):
    """Early in a run the report's progress holds one instant (matplotlib then spans years): the
    console carries it on to the plant time shown, and says so before 10 plant minutes."""
    import matplotlib.dates as mdates

    from helicalib.console.app import progress_until
    from helicalib.report import plots

    console = live["output"].console
    _show(live, live["snap"])
    v = _view(live["base"])
    now = v["clock"]["time_s"]
    _data, rep = console.report_data()
    pr = progress_until(rep["progress"], now)
    assert pr["times_s"][-1] == now and len(pr["accepted"]) == len(pr["times_s"])
    fig = plots.figure_progress(pr)
    lo, hi = (mdates.num2date(x).timestamp() for x in fig.axes[2].get_xlim())
    assert lo >= v["progress"]["started_s"] - 3600 and hi <= now + 3600, (lo, hi)
    code, png, _t = _get(live["base"] + "progress.png")
    assert code == 200 and png.startswith(b"\x89PNG")
    young = dataclasses.replace(live["snap"], time_s=v["progress"]["started_s"] + 120.0)
    _show(live, young)
    page = _page(live["base"])
    assert 'id="progress-empty"' in page and 'id="progress-plot"' not in page
    _show(live, live["snap"])


def _console_db(db, *extra):
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", "console", str(db), "--listen", "127.0.0.1:0",
                             "--json", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = json.loads(proc.stdout.readline() or "{}")
    if not line:
        proc.kill()
        raise AssertionError(proc.stderr.read())
    return proc, line


def test_console_db_finds_the_frames_where_the_campaign_wrote_them(live):
    """The campaign's frames are in tmp/img, not in images beside tmp/c.db."""
    db = live["tmp"] / "c.db"
    assert not (db.parent / "images").exists()
    proc, line = _console_db(db, "--campaign", str(live["cid"]))
    try:
        base = line["url"]
        boards = [b for b in _view(base)["boards"] if b["frames"]]
        assert boards
        for b in boards:
            code, png, ctype = _get(base + f"frames/{b['frames']['id']}.png")
            assert code == 200 and ctype == "image/png" and png.startswith(b"\x89PNG"), (code, png[:200])
    finally:
        proc.terminate()
        proc.wait(timeout=15)


def test_console_db_shows_plant_unreachable_from_the_events(live, tmp_path):
    import sqlite3

    db = tmp_path / "c.db"
    src, dst = sqlite3.connect(live["tmp"] / "c.db"), sqlite3.connect(db)
    src.backup(dst)  # the live writer's committed rows, its write-ahead log included
    src.close()
    dst.close()
    cid, t = live["cid"], live["snap"].time_s
    with Store.open(db, live["tmp"] / "img") as s:
        s.record_event(campaign_id=cid, time_s=t + 60.0, kind="plant_lost",
                       reason="plant not answering (timed out); no visit starts until it answers")
    proc, line = _console_db(db, "--campaign", str(cid))
    try:
        g = _view(line["url"])["gate"]
        assert g["unreachable_since_s"] == t + 60.0 and g["open"] is False
        assert "<strong>PLANT UNREACHABLE</strong> since" in _page(line["url"])
    finally:
        proc.terminate()
        proc.wait(timeout=15)
    with Store.open(db, live["tmp"] / "img") as s:
        s.record_event(campaign_id=cid, time_s=t + 300.0, kind="plant_back",
                       reason="plant answers again after 4.0 min unreachable")
    proc, line = _console_db(db, "--campaign", str(cid))
    try:
        assert _view(line["url"])["gate"]["unreachable_since_s"] is None
    finally:
        proc.terminate()
        proc.wait(timeout=15)


def test_console_db_opens_the_campaign_the_controller_runs(tmp_path):
    """A run campaign (1) resumed after a check campaign (2) ended: the console opens 1 while its
    controller holds the database, and names it; without a controller, the newest running one."""
    db = tmp_path / "c.db"
    with Store.open(db) as s:
        run_id = s.start_campaign(name="run of the field", mode="live", started_s=1000.0, heliostats=[("H1", 0, "T1")])
        s.record_event(campaign_id=run_id, time_s=1000.0, kind="campaign", reason="new", data={"command": "run"})
        check_id = s.start_campaign(name="check H1", mode="check", started_s=2000.0, heliostats=[("H1", 0, "T1")])
        s.record_event(campaign_id=check_id, time_s=2000.0, kind="campaign", reason="new", data={"command": "check"})
        s.finish_campaign(check_id, 2100.0)
    owner = Store.open(db, owner="run field.yaml")  # the controller: resumes campaign 1
    try:
        owner.record_event(campaign_id=run_id, time_s=3000.0, kind="campaign", reason="resumed",
                           data={"command": "run"})
        proc, line = _console_db(db)
        try:
            assert line["campaign"] == run_id and line["campaign_name"] == "run of the field"
            assert "the process holding the database runs" in line["campaign_chosen"]
            page = _page(line["url"])
            assert f"campaign {run_id}: run of the field" in page and "the database is held by pid" in page
        finally:
            proc.terminate()
            proc.wait(timeout=15)
    finally:
        owner.close()
    proc, line = _console_db(db)
    try:
        assert line["campaign"] == run_id and line["campaign_chosen"] == "the newest campaign marked running"
        assert "recorded as running, but no process runs it now" in _page(line["url"])
    finally:
        proc.terminate()
        proc.wait(timeout=15)
