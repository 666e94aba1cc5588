"""The crew console in a real headless Chromium, against a live simulated campaign over loopback.

One campaign for the module: the simulated plant served on loopback Modbus TCP + HTTP cameras
(plant time 150x real), the real clients, a real SQLite file, the runner on APScheduler
(:func:`helicalib.app.live.run_live`) in a thread, armed, with ``--console 127.0.0.1:0``
attached exactly as ``helicalib run`` attaches it. The operator's name carries markup and a script
(``<script>…</script>``; heliostat ids are restricted to a safe alphabet by the field config), so
escaping is checked on every panel that shows it. Chromium and
chromedriver are Debian's (``make test`` installs them); a missing browser fails these tests.
"""

from __future__ import annotations

import io
import json
import shutil
import tempfile
import threading
import time
import urllib.error
import urllib.request
from contextlib import ExitStack
from pathlib import Path

import pytest
import yaml

from conftest import DEMO_FIELD
from helicalib.app import live
from helicalib.app.terminal import LineLog
from helicalib.config import load_field_config
from helicalib.console.server import ConsoleOptions, attach_console
from helicalib.store.sqlite import Store

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
EVIL = "crew <script>window.pwned=1</script> lead"
"""An operator's name with markup and a script in it (shown as text, never run)."""
HEL = "H0001"
EVIL_ID = "H<script>window.pwned=2</script>02"
"""H0002 renamed in memory: an id with markup and a script, as a database written before ids were
restricted to a safe alphabet may hold (validate refuses it in a field config today)."""
IDS = [HEL, EVIL_ID, "H0003", "H0021", "H0022", "H0023"]
RATE = 150.0


def _until(what, timeout_s: float = 30.0, every_s: float = 0.2):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        value = what()
        if value:
            return value
        time.sleep(every_s)
    raise AssertionError(f"not within {timeout_s:.0f} s: {what.__doc__ or what}")


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium through chromedriver (no download: the Debian binaries, named explicitly)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    assert CHROMIUM.exists() and CHROMEDRIVER.exists(), (
        "Chromium and chromedriver are needed (Debian packages chromium and chromium-driver): run `make test`, "
        "which installs them")
    profile = tempfile.mkdtemp(prefix="helicalib-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--window-size=1400,1800", f"--user-data-dir={profile}"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
    driver.set_page_load_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)  # the browser profile is the test's own


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A live armed campaign of six heliostats with its console on 127.0.0.1 (a free port)."""
    from helicalib.campaign.loop import CampaignRunner
    from helicalib.app.simulated import _network_plant, default_start_s
    from helicalib.sim.scenario import Scenario

    tmp = tmp_path_factory.mktemp("console")
    data = yaml.safe_load(DEMO_FIELD.read_text())
    field = tmp / "field.yaml"
    field.write_text(yaml.safe_dump(data, sort_keys=False))
    cfg = load_field_config(field)
    cfg = cfg.model_copy(update={"heliostats": type(cfg.heliostats)(
        h.model_copy(update={"id": EVIL_ID}) if h.id == "H0002" else h for h in cfg.heliostats)})
    cfg.__dict__.pop("_index_cache", None)  # the copy must look its ids up afresh
    log = io.StringIO()
    stop = threading.Event()
    with ExitStack() as stack:
        plant, cameras, clock, _sim, _server = _network_plant(cfg, Scenario(seed=3), default_start_s(cfg) + 9 * 3600,
                                                              RATE, stack)
        store = Store.open(tmp / "c.db", tmp / "img", owner="test console")
        stack.callback(store.close)
        cid = store.start_campaign(name="console test", mode="live", started_s=clock.now_s(),
                                   heliostats=[(h, cfg.heliostat_index(h), cfg.heliostat(h).target) for h in IDS],
                                   config_path=str(field))
        output = LineLog(dt_utc(), log)
        runner = CampaignRunner(cfg, plant, cameras, clock, store, cid, heliostat_ids=IDS, listeners=[output.on_event])
        args = ConsoleOptions(console="127.0.0.1:0")
        output = attach_console(args, runner, output)
        thread = threading.Thread(target=live.run_live, args=(runner, clock.now_s() + 86400.0),
                                  kwargs={"stop_event": stop, "output": output}, daemon=True)
        thread.start()
        try:
            yield {"runner": runner, "store": store, "url": f"http://127.0.0.1:{output.server.port}/", "log": log,
                   "db": tmp / "c.db", "cid": cid, "data": data, "server": _server, "tmp": tmp}
        finally:
            stop.set()
            thread.join(timeout=60)
    assert not thread.is_alive(), "the live run did not stop"


def dt_utc():
    import datetime as dt

    return dt.timezone.utc


def _fresh(driver, act, tries: int = 30):
    """Do ``act`` (find an element and use it), again if the live page swapped the element in between."""
    from selenium.common.exceptions import StaleElementReferenceException

    for _ in range(tries):
        try:
            return act()
        except StaleElementReferenceException:
            time.sleep(0.1)
    raise AssertionError("the element was swapped out every time")


def _type(driver, element_id: str, text: str) -> None:
    """Type ``text`` into an input of the live page (its panels are swapped in while one types)."""
    def act():
        el = driver.find_element("id", element_id)
        el.clear()
        el.send_keys(text)

    for _ in range(10):
        _fresh(driver, act)
        if driver.execute_script("return document.getElementById(arguments[0]).value", element_id) == text:
            return
    raise AssertionError(f"{element_id} did not keep {text!r}")


def _board(driver, target: str) -> str:
    return driver.execute_script(f"return document.getElementById('board-{target}').dataset.heliostat")


def _texts(driver, css: str) -> list[str]:
    """The text of every element matching ``css``, read at once (the panels are swapped in live)."""
    return driver.execute_script("return Array.from(document.querySelectorAll(arguments[0]))"
                                 ".map(function (e) { return e.textContent; })", css)


def _text(driver, element_id: str) -> str:
    return driver.execute_script("var e = document.getElementById(arguments[0]); return e ? e.textContent : ''",
                                 element_id)


def test_the_page_follows_the_campaign_without_a_reload(campaign, browser):
    runner = campaign["runner"]
    browser.get(campaign["url"])
    loaded = browser.execute_script("return window.helicalibConsoleLoadedAt")
    assert loaded  # its script ran

    def shows_current():
        """the page shows the heliostat the runner has on board T1"""
        on_t1 = [h for h, v in list(runner.state.active.items()) if v.target_id == "T1"]
        shown = _board(browser, "T1")
        return shown in on_t1 and shown

    first = _until(shows_current, 40)

    def next_visit():
        """board T1 shows another heliostat (the next visit), pushed by the server"""
        now = _board(browser, "T1")
        return now and now != first and now

    _until(next_visit, 60)
    assert browser.execute_script("return window.helicalibConsoleLoadedAt") == loaded  # never reloaded
    assert int(browser.execute_script("return document.body.dataset.updates")) >= 2
    assert _text(browser, "connection") == "live"
    # the visit that ended is in the log (from the database), with its reason
    assert any(f"{first} off T1:" in r for r in _texts(browser, "#events tbody tr[data-kind='visit_end']"))


def test_a_queued_recheck_goes_next_and_is_logged_and_escaped(campaign, browser):
    runner, store, cid = campaign["runner"], campaign["store"], campaign["cid"]
    browser.get(campaign["url"])
    _until(lambda: browser.find_elements("id", "action-form"), 10)
    _type(browser, "action-who", EVIL)
    _type(browser, "action-heliostats", HEL)
    _fresh(browser, lambda: browser.find_element("css selector", "button[data-kind='recheck']").click())
    _until(lambda: "recorded" in _text(browser, "action-result"), 10)
    actions = store.actions(cid)
    assert [(a.kind, a.heliostat_ids) for a in actions] == [("recheck", (HEL,))]
    assert actions[0].who.startswith(EVIL + " (127.0.0.1")

    def started():
        """the re-check's visit started"""
        return store.actions(cid)[0].outcome.startswith("visit started")

    _until(started, 60)
    done = store.actions(cid)[0]
    # done next: the first visit to start on its board after the request is the re-check's
    board = runner.cfg.heliostat(HEL).target
    # (the console stamps the request with its own estimate of plant time, and a tick that read the
    # plant clock a moment before may apply it: its visit then starts at that tick's time, done_s)
    since = min(done.requested_s, done.done_s)
    after = [v for v in store.visits(campaign_id=cid) if v.target_id == board and v.started_s >= since]
    assert after and after[0].heliostat_id == HEL, [(v.heliostat_id, v.started_s) for v in after]

    def logged():
        """the log shows the re-check going onto the board"""
        rows = _texts(browser, "#events tbody tr[data-kind='operator']")
        return [r for r in rows if f"re-check of {HEL}" in r and f"onto {board} now" in r]

    assert _until(logged, 20)
    # the name is text everywhere: no script of it ran, no element was made of its markup
    assert browser.execute_script("return window.pwned") is None
    assert not browser.find_elements("xpath", "//script[contains(., 'pwned')]")
    assert EVIL in _text(browser, "panel-actions")
    assert any(EVIL in r for r in _texts(browser, "#events tbody tr[data-kind='operator']"))
    assert any(t.startswith(HEL + ":") for t in _texts(browser, "svg.field title"))
    # the hostile id is text on the map too, and its sheet opens with the id as text
    assert any(t.startswith(EVIL_ID + ":") for t in _texts(browser, "svg.field title"))
    assert not browser.find_elements("xpath", "//script[contains(., 'pwned')]")
    # its sheet opens from the map (the report's own sheet)
    _fresh(browser, lambda: browser.find_element("css selector", f"svg.field a[data-id='{HEL}'] circle").click())
    _until(lambda: "heliostat" in browser.title and HEL in browser.title, 30)
    assert browser.execute_script("return window.pwned") is None
    assert HEL in browser.find_element("tag name", "h1").text


def test_event_log_filters_by_kind(campaign, browser):
    browser.get(campaign["url"])
    _until(lambda: _texts(browser, "#events tbody tr[data-kind='visit_end']"), 30)
    from selenium.webdriver.support.ui import Select

    Select(browser.find_element("id", "event-kind")).select_by_value("visit_end")
    time.sleep(2.5)  # the log is swapped in again meanwhile: the filter must hold across updates
    shown = browser.execute_script("return Array.from(document.querySelectorAll('#events tbody tr'))"
                                   ".filter(function (r) { return r.offsetParent !== null; })"
                                   ".map(function (r) { return r.dataset.kind; })")
    hidden = browser.execute_script("return document.querySelectorAll('#events tbody tr.hidden').length")
    assert shown and set(shown) == {"visit_end"}
    assert hidden  # the campaign and tracking rows are filtered out, not gone


def _get(url: str, headers: dict | None = None) -> tuple[int, str]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as err:
        return err.code, err.read().decode()


def test_beyond_loopback_every_request_needs_the_token(campaign, browser):
    """``helicalib console DB --console-public`` on the running campaign's database (token mode forced
    on 127.0.0.1): refused without the token, served with it; read-only (no action, no write)."""
    import subprocess
    import sys

    db = campaign["db"]
    before = sorted(p.name for p in db.parent.iterdir())
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", "console", str(db), "--listen", "127.0.0.1:0",
                             "--console-public", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = json.loads(proc.stdout.readline())
        url, token = line["url"], line["token"]
        base = url.split("?")[0]
        assert token and url.endswith(f"?token={token}")
        for path in ("", "api/view", "stream", "progress.png", "static/console.js"):
            code, body = _get(base + path)
            assert code == 401 and "token required" in body, (path, code)
        assert _get(base + "?token=wrong")[0] == 401
        assert _get(base + "api/view", {"X-Helicalib-Token": token})[0] == 200
        req = urllib.request.Request(base + "api/action", data=b'{"kind": "pause", "who": "x"}', method="POST",
                                     headers={"Content-Type": "application/json", "X-Helicalib-Token": token})
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(req, timeout=10)
        assert refused.value.code == 403  # read-only: no action from a database console
        # the browser gets in once with ?token=, then by the cookie it set (the live stream too)
        browser.get(url)
        _until(lambda: _text(browser, "connection") == "live", 15)
        browser.get(base)
        assert "campaign" in browser.find_element("tag name", "h1").text
        assert "token required" not in browser.page_source
    finally:
        proc.terminate()
        proc.wait(timeout=15)
    assert not campaign["store"].actions(campaign["cid"], pending=True)
    assert sorted(p.name for p in db.parent.iterdir()) == before  # the reader left no file behind


def test_a_loopback_console_answers_only_to_this_machines_names(campaign):
    """DNS rebinding: a web page whose domain re-binds to 127.0.0.1 sends its own domain as the Host
    (and as the Origin, so they match): the loopback console refuses it, reads and actions alike."""
    port = campaign["url"].rsplit(":", 1)[1].rstrip("/")
    assert _get(campaign["url"] + "api/view")[0] == 200
    assert _get(f"http://localhost:{port}/api/view")[0] == 200
    for path in ("", "api/view", "stream", "static/console.js"):
        assert _get(campaign["url"] + path, {"Host": f"evil.example:{port}"})[0] == 400, path
    req = urllib.request.Request(campaign["url"] + "api/action", data=b'{"kind": "pause", "who": "page"}',
                                 method="POST", headers={"Content-Type": "application/json",
                                                         "Host": f"evil.example:{port}",
                                                         "Origin": f"http://evil.example:{port}"})
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(req, timeout=10)
    assert refused.value.code == 400
    assert not [a for a in campaign["store"].actions(campaign["cid"]) if a.who.startswith("page")]


def test_run_serves_the_console_of_its_dry_run(campaign):
    """``helicalib run FIELD --console 127.0.0.1:0 --json`` (no --arm: it only reads the plant, beside the
    armed campaign): the address comes as a JSON line, the page is served, read-only, until the run stops."""
    import signal
    import subprocess
    import sys

    data, server, tmp = dict(campaign["data"]), campaign["server"], campaign["tmp"]
    data["plant"] = dict(data["plant"], scs=dict(data["plant"]["scs"], port=server.modbus_port))
    data["cameras"] = [dict(c, url=server.camera_url(c["id"])) for c in data["cameras"]]
    data["storage"] = {"database": "sqlite:///dry/helicalib.db", "images_dir": "dry/images"}
    field = tmp / "dry.yaml"
    field.write_text(yaml.safe_dump(data, sort_keys=False))
    proc = subprocess.Popen([sys.executable, "-m", "helicalib", "run", str(field), "--heliostats", "H0002,H0021",
                             "--days", "1", "--console", "127.0.0.1:0", "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        lines = iter(proc.stdout.readline, "")
        line = next(x for x in map(json.loads, lines) if x.get("event") == "console")
        assert line["token"] is None and line["url"].startswith("http://127.0.0.1:")
        code, page = _get(line["url"])
        assert code == 200 and "Read-only: actions need the controller running with" in page
        view = json.loads(_get(line["url"] + "api/view")[1])
        assert view["campaign"]["mode"] == "dry-run" and view["armed_actions"] is False
        next(x for x in map(json.loads, lines) if x.get("event") == "status")  # the run's loop is going
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-2000:]
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["event"] == "summary" and summary["status"] == "stopped"
    with pytest.raises(urllib.error.URLError):
        urllib.request.urlopen(line["url"], timeout=5)  # the page stops with the run
