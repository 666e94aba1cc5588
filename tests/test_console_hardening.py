"""The console's guard: action bodies (size, nesting, field types, who sent them) and the rules
that must keep holding (forged Host 400, cross-origin actions 403, token 401, traversals 404).

A real armed runner on the in-process simulated plant (real frames, a real SQLite file) with its
console attached exactly as ``helicalib run --arm --console 127.0.0.1:0`` attaches it, over real
HTTP on loopback.
"""

from __future__ import annotations

import http.client
import io
import json
import urllib.error
import urllib.request

import pytest

from campaign_helpers import inprocess_campaign
from helicalib.app.terminal import LineLog
from helicalib.config import load_field_config
from helicalib.console.server import ConsoleOptions, attach_console

IDS = ["H0001", "H0021", "H0002"]


@pytest.fixture(scope="module")
def armed(demo_field_path, tmp_path_factory):
    """An armed runner after 20 plant minutes, its console on a free loopback port."""
    import datetime as dt

    cfg = load_field_config(demo_field_path)
    tmp = tmp_path_factory.mktemp("hardening")
    runner, sim, store, cid, _c = inprocess_campaign(cfg, tmp, 9, 3, IDS, armed=True)
    runner.run_until(sim.t_s + 1200)
    output = LineLog(dt.timezone.utc, io.StringIO())
    output = attach_console(ConsoleOptions(console="127.0.0.1:0"), runner,
                            output)
    output.on_snapshot(runner.snapshot(sim.t_s))
    try:
        yield {"runner": runner, "store": store, "cid": cid, "port": output.server.port,
               "base": f"http://127.0.0.1:{output.server.port}/"}
    finally:
        output.stop()
        store.close()


def _post(port: int, body, headers: dict | None = None, chunked: bool = False) -> tuple[int, dict | str]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    h = {"Content-Type": "application/json", **(headers or {})}
    try:
        if chunked:
            conn.request("POST", "/api/action", body=iter(body), headers=h, encode_chunked=True)
        else:
            conn.request("POST", "/api/action", body=body, headers=h)
        r = conn.getresponse()
        text = r.read().decode()
    except (ConnectionResetError, BrokenPipeError):
        return -1, ""
    finally:
        conn.close()
    try:
        return r.status, json.loads(text)
    except ValueError:
        return r.status, text


def _get(url: str, headers: dict | None = None) -> tuple[int, str]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=20) as r:
            return r.status, r.read().decode(errors="replace")
    except urllib.error.HTTPError as err:
        return err.code, err.read().decode(errors="replace")


def _recorded(armed) -> list:
    return armed["store"].actions(armed["cid"])


def test_a_body_over_the_limit_is_refused_unread_in_one_line(armed):
    before = len(_recorded(armed))
    big = json.dumps({"kind": "pause", "who": "x" * 40, "heliostats": ["H0001"] * 200_000}).encode()  # ~1.8 MB
    code, body = _post(armed["port"], big)
    assert code == 413, (code, body)
    assert body["error"].startswith(f"action: body of {len(big)} bytes refused (at most 16384 bytes)")
    # no Content-Length (chunked): refused as soon as the bytes received pass the limit
    code, body = _post(armed["port"], [b'{"kind": "pause", "who": "', *[b"y" * 4096] * 10, b'"}'], chunked=True)
    assert code == 413 and body["error"] == "action: body over 16384 bytes refused", (code, body)
    assert len(_recorded(armed)) == before


@pytest.mark.parametrize("body, message", [
    (b"[" * 5000 + b"]" * 5000, "action: the JSON is nested too deeply"),
    (b'{"kind": "pause", "who": {"a": {"b": [1, 2]}}}', "action: 'who' must be text, your name (got dict)"),
    (b'{"kind": "pause", "who": null}', "action: 'who' must be text, your name (got null)"),
    (b'{"kind": "pause", "who": NaN}', "action: not JSON (NaN is not a number JSON allows)"),
    (b'{"kind": "pause", "who": 1e999}', "action: 'who' must be text, your name (got float)"),
    (b'{"kind": ["pause"], "who": "a"}', "action: 'kind' '[\"pause\"]' is not one of pause, resume"),
    (b'{"kind": "launch", "who": "a"}', "action: 'kind' 'launch' is not one of pause, resume"),
    (b'{"kind": "pause", "who": "a", "as": "root"}', "action: unknown field 'as' (the fields are kind, heliostats"),
    (b'{"kind": "recheck", "who": "a", "heliostats": [7]}', "action: 'heliostats' must be a list of ids"),
    (b'{"kind": "recheck", "who": "a", "heliostats": ["H9999"]}', "action recheck: heliostat 'H9999' is not in "
                                                                  "this campaign"),
    (b'{"kind": "pause", "who": "a\\nforged line"}', "action: 'who' holds control characters"),
    (b'{"kind": "pause", "who": "' + b"w" * 121 + b'"}', "action: 'who' is longer than 120 characters"),
    (b'{"kind": "pause", "who": "  "}', "action: 'who' is empty"),
    (b'"pause"', "action: the body must be one JSON object"),
    (b"\xff\xfe", "action: the body is not UTF-8 text"),
])
def test_bad_bodies_are_refused_with_one_line_naming_the_field(armed, body, message):
    before = len(_recorded(armed))
    code, answer = _post(armed["port"], body)
    assert code == 400, (code, answer)
    assert answer["error"].startswith(message) and "\n" not in answer["error"], answer
    assert len(_recorded(armed)) == before


def test_the_recorded_address_is_the_socket_peer_never_a_header(armed):
    code, answer = _post(armed["port"], b'{"kind": "recheck", "who": "crew lead", "heliostats": "H0021"}',
                         {"X-Forwarded-For": "10.9.9.9", "X-Real-IP": "10.8.8.8", "Forwarded": "for=10.7.7.7"})
    assert code == 200, answer
    (action,) = [a for a in _recorded(armed) if a.id == answer["id"]]
    assert action.who == "crew lead (127.0.0.1)" and action.heliostat_ids == ("H0021",)


def test_what_held_still_holds(armed):
    """Forged Host 400, another site's action 403, traversals 404: on the armed console."""
    base, port = armed["base"], armed["port"]
    for path in ("", "api/view", "static/console.js", "progress.png"):
        assert _get(base + path, {"Host": f"evil.example:{port}"})[0] == 400, path
    before = len(_recorded(armed))
    code, answer = _post(port, b'{"kind": "pause", "who": "page"}', {"Origin": "http://evil.example"})
    assert code == 403 and "another site" in answer["error"]
    assert len(_recorded(armed)) == before
    for path in ("static/../app.py", "static/%2e%2e/app.py", "static/..%2f..%2fpyproject.toml",
                 "sheets/../../../../etc/passwd", "sheets/%2e%2e/%2e%2e/etc/passwd", "frames/..%2f1.png",
                 "frames/1.png/../../etc/passwd", "static//etc/passwd"):
        code, text = _get(base + path)
        assert code == 404 and "root:" not in text and "import" not in text, (path, code)


def test_beyond_loopback_every_route_needs_the_token(armed, tmp_path):
    from helicalib.console.app import Console, create_app
    from helicalib.console.server import ConsoleServer
    from helicalib.console.view import Sources
    from helicalib.geometry.sitetime import site_time
    from helicalib.store.sqlite import Store

    runner = armed["runner"]
    reader = Store.open(runner.devices.store.path, runner.devices.store.images_dir, readonly=True)
    console = Console(Sources(store=reader, cfg=runner.cfg, campaign_id=armed["cid"], site=site_time(runner.cfg)),
                      token="s3cret-token")
    server = ConsoleServer(create_app(console), "127.0.0.1", 0)
    server.start()
    try:
        base = f"http://127.0.0.1:{server.port}/"
        for path in ("", "api/view", "stream", "progress.png", "static/console.js", "frames/1.png",
                     "heliostat/H0001"):
            code, text = _get(base + path)
            assert code == 401 and "token required" in text, (path, code)
        code, text = _get(base + "api/view", {"X-Helicalib-Token": "s3cret-token"})
        assert code == 200, text
    finally:
        server.stop()
        reader.close()
        console.remove_cache()
