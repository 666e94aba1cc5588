"""``helicalib probe FIELD`` against the simulated plant served on loopback (its real Modbus TCP
server and HTTP cameras): a healthy plant passes every check; a count mismatch, a camera that
fails, a camera whose clock is off and implausible read-backs exit non-zero with a line naming
the heliostat, camera or quantity; nothing is ever written to the plant, also with ``--arm``;
a camera's exposure (the simulated plant's stream cameras keep one) is set back after probe tried
another one.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest
import yaml

from helicalib.app.probe import EXIT_CONFIG, EXIT_MISMATCH
from helicalib.cli import main

SECTIONS = ("plant", "clock", "weather", "heliostats", "cameras")


def _serve(demo_field_path, kind: str = "http"):
    """The demo field's simulated plant on loopback at 200× plant time, in daylight, its cameras of
    ``kind`` (``http`` snapshot or ``stream``); yields (server, the parsed demo config pointing at it)."""
    from helicalib.app.simulated import default_start_s
    from helicalib.config import load_field_config
    from helicalib.sim.clock import RateClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.sim.scenario import Scenario
    from helicalib.sim.server import PlantServer

    cfg = load_field_config(demo_field_path)
    cfg = cfg.model_copy(update={"cameras": tuple(c.model_copy(update={"kind": kind}) for c in cfg.cameras)})
    start = default_start_s(cfg) + 9 * 3600
    sim = SimulatedPlant(cfg, Scenario(seed=3), start_s=start, rate=200.0)
    server = PlantServer(sim, RateClock(start, 200.0, time.monotonic, time.sleep), modbus_port=0, camera_port=0)
    data = yaml.safe_load(demo_field_path.read_text())
    with server:
        data["plant"]["scs"]["port"] = server.modbus_port
        for cam in data["cameras"]:
            cam["url"] = server.camera_url(cam["id"])
            if kind == "stream":
                cam.update(kind="stream", exposure_url=server.streams.exposure_url(cam["id"]))
        yield server, data


@pytest.fixture(scope="module")
def served(demo_field_path):
    yield from _serve(demo_field_path)


@pytest.fixture(scope="module")
def streamed(demo_field_path):
    """The same plant with its cameras as streams (HTTP MJPEG and an exposure control URL)."""
    yield from _serve(demo_field_path, "stream")


@pytest.fixture()
def field(served, tmp_path):
    """Write a variant of the served config (``change(data)`` edits a copy) and return its path."""
    import copy

    def write(change=None):
        data = copy.deepcopy(served[1])
        if change is not None:
            change(data)
        path = tmp_path / "field.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return str(path)

    return write


@pytest.fixture()
def writes(served, monkeypatch):
    """Every register write the simulated plant receives (address, values)."""
    registers = served[0].registers
    seen, write = [], registers.write

    def counting(address, values, *args, **kw):
        seen.append((address, list(values)))
        return write(address, values, *args, **kw)

    monkeypatch.setattr(registers, "write", counting)
    return seen


def _json(argv, capsys):
    code = main(["probe", *argv, "--json"])
    return code, json.loads(capsys.readouterr().out)


def _failing(doc) -> dict[str, str]:
    return {c["name"]: c["found"] for c in doc["checks"] if c["status"] == "mismatch"}


def test_a_healthy_plant_passes_every_check_and_prints_every_section(field, capsys, writes):
    path = field()
    assert main(["probe", path]) == 0
    out = capsys.readouterr().out
    for section in SECTIONS:
        assert f"│ {section}" in out, section
    for name in ("heliostat count", "plant time", "wind speed", "DNI", "H0040", "C2 capture time", "C1 exposure"):
        assert name in out, name
    assert "MISMATCH" not in out
    assert out.strip().splitlines()[-1].endswith("every check passed (exit status 0)")
    assert writes == []


def test_json_lists_every_check_with_its_values(field, capsys):
    code, doc = _json([field()], capsys)
    assert code == 0 and doc["summary"]["passed"] is True and doc["summary"]["mismatch"] == 0
    names = [c["name"] for c in doc["checks"]]
    assert {c["section"] for c in doc["checks"]} == set(SECTIONS)
    assert [n for n in names if n.startswith("H")] == [f"H{k:04d}" for k in range(1, 41)]
    assert {"C1 frame", "C1 capture time", "C1 exposure", "C2 frame", "C2 capture time", "C2 exposure"} <= set(names)
    assert doc["summary"]["heliostats"] == {"read": 40, "ok": 40, "mismatch": 0, "warning": 0}
    assert doc["summary"]["checks"] == len(names) == doc["summary"]["ok"]
    count = next(c for c in doc["checks"] if c["name"] == "heliostat count")
    assert count["values"] == {"expected": 40, "found": 40}
    h = next(c for c in doc["checks"] if c["name"] == "H0001")["values"]
    assert h["state"] == "tracking" and 0.0 < h["cleanliness"] <= 1.0 and len(h["strokes_mm"]) == 2
    rate = next(c for c in doc["checks"] if c["name"] == "plant clock rate")["values"]["rate"]
    assert rate == pytest.approx(200.0)
    exposure = next(c for c in doc["checks"] if c["name"] == "C1 exposure")
    assert exposure["found"].startswith("exposure 1.1: yes") and exposure["values"]["applied_ms"] is not None
    assert exposure["found"].endswith(f"set back to {exposure['values']['exposure_ms']:g} ms")
    assert exposure["values"]["restored_ms"] == exposure["values"]["exposure_ms"]


def test_one_heliostat_more_than_the_plant_serves_is_a_count_mismatch(field, capsys):
    def one_more(data):
        last = data["heliostats"][-1]
        extra = dict(last, id="H0041", position_enu_m=[last["position_enu_m"][0] + 10.0, *last["position_enu_m"][1:]])
        data["heliostats"].append(extra)

    code, doc = _json([field(one_more)], capsys)
    assert code == EXIT_MISMATCH and doc["summary"]["passed"] is False
    failing = _failing(doc)
    assert "reports 40 heliostats" in failing["heliostat count"] and "41" in failing["heliostat count"]
    skipped = [c for c in doc["checks"] if c["section"] == "heliostats"]
    assert len(skipped) == 1 and skipped[0]["status"] == "skipped" and "count differs" in skipped[0]["found"]
    # what does not depend on the count is still read
    assert next(c for c in doc["checks"] if c["name"] == "DNI")["status"] == "ok"


def test_strokes_outside_the_drive_range_name_the_heliostat(field, capsys):
    def narrow(data):
        drive = json.loads(json.dumps(data["drives"]["tr20"]))
        drive["actuators"][0]["stroke_range_mm"] = [0, 500]  # the plant's strokes are near 900 mm
        data["drives"]["narrow"] = drive
        data["heliostats"][2]["drive"] = "narrow"

    assert main(["probe", field(narrow)]) == EXIT_MISMATCH
    out = capsys.readouterr().out.strip().splitlines()
    lines = [ln for ln in out if ln.startswith("MISMATCH:")]
    assert len(lines) == 1, lines
    assert lines[0].startswith("MISMATCH: heliostats: H0003: stroke 1 ") and "outside [0, 500] mm" in lines[0]
    assert "1 MISMATCH (exit status 1)" in out[-1]


def test_a_cleanliness_of_3_is_implausible(field, capsys, served, monkeypatch):
    soiling = served[0].plant.soiling
    real = soiling.cleanliness

    def dirty_reading(t_s, rows=None):
        out = np.array(real(t_s, rows), dtype=float)
        which = np.arange(out.size) if rows is None else np.asarray(rows).reshape(-1)
        out[which == 4] = 3.0  # H0005's register reads 3 (the plant reads the field or a few rows)
        return out

    monkeypatch.setattr(soiling, "cleanliness", dirty_reading)
    code, doc = _json([field()], capsys)
    assert code == EXIT_MISMATCH
    assert _failing(doc) == {"H0005": "cleanliness 3 outside 0..1"}
    assert doc["summary"]["heliostats"] == {"read": 40, "ok": 39, "mismatch": 1, "warning": 0}


def test_a_camera_nobody_listens_on_fails_with_its_address(field, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"http://127.0.0.1:{port}/T1.png"

    def dead_camera(data):
        data["cameras"][0]["url"] = url

    code, doc = _json([field(dead_camera)], capsys)
    assert code == EXIT_MISMATCH
    failing = _failing(doc)
    assert list(failing) == ["C1 frame"] and url in failing["C1 frame"] and "refused" in failing["C1 frame"].lower()
    assert next(c for c in doc["checks"] if c["name"] == "C2 frame")["status"] == "ok"


def _png() -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", np.full((1024, 1280), 40, dtype=np.uint8))
    assert ok
    return buf.tobytes()


@pytest.fixture()
def late_camera(served):
    """A camera (stdlib HTTP server) serving a real PNG stamped an hour after the plant's time."""
    body, clock = _png(), served[0].clock

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):  # noqa: N802
            self.send_response(200)
            self.send_header("Content-Type", "image/png")
            self.send_header("Content-Length", str(len(body)))
            self.send_header("X-Capture-Time", repr(clock.now_s() + 3600.0))
            self.end_headers()
            self.wfile.write(body)

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/T2.png"
    httpd.shutdown()
    httpd.server_close()
    thread.join(5)


def test_a_camera_whose_clock_is_an_hour_off_is_a_mismatch(field, capsys, late_camera):
    def late(data):
        data["cameras"][1]["url"] = late_camera

    assert main(["probe", field(late)]) == EXIT_MISMATCH
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if ln.startswith("MISMATCH:")]
    assert len(lines) == 1 and lines[0].startswith("MISMATCH: cameras: C2 capture time: camera clock off by +"), lines
    off = float(lines[0].rsplit("by ", 1)[1].split(" s")[0])
    assert 3500 < off <= 3600  # an hour ahead of the plant time after the grab
    assert "exposure 1.1: no" in out  # it sends no X-Exposure-Ms: it sets its own exposure


def test_probe_never_writes_not_even_with_arm(field, capsys, writes, served):
    from helicalib.config import load_field_config
    from helicalib.devices.modbus import ModbusPlant

    path = field()
    assert main(["probe", path, "--arm"]) == 0
    captured = capsys.readouterr()
    assert "--arm ignored: probe never writes to the plant" in captured.err
    assert main(["probe", path, "--arm", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["summary"]["passed"]
    assert writes == []
    # the count sees a write when there is one: an armed client's field command
    with ModbusPlant.from_config(load_field_config(path), armed=True) as armed:
        armed.field_command(2)
    assert len(writes) == 1


def test_bad_usage_exits_2_in_one_line(field, capsys, tmp_path):
    assert main(["probe", field(), "--heliostats", "H0001,H9999"]) == EXIT_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "H9999" in err[0] and err[0].startswith("helicalib probe: error: ")
    assert main(["probe", str(tmp_path / "nowhere.yaml")]) == EXIT_CONFIG
    assert "nowhere.yaml" in capsys.readouterr().err


def test_a_plant_nobody_answers_is_one_line_naming_the_endpoint(field, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    def dead_plant(data):
        data["plant"]["scs"]["port"] = port

    code, doc = _json([field(dead_plant)], capsys)
    assert code == EXIT_MISMATCH
    failing = _failing(doc)
    assert list(failing) == ["heliostat count"] and f"127.0.0.1:{port}" in failing["heliostat count"]
    skipped = {c["name"] for c in doc["checks"] if c["status"] == "skipped"}
    assert {"field state", "plant time", "weather", "40 heliostats"} <= skipped


def test_selected_heliostats_only(field, capsys):
    code, doc = _json([field(), "--heliostats", "H0002,H0039"], capsys)
    assert code == 0
    assert [c["name"] for c in doc["checks"] if c["section"] == "heliostats"] == ["H0002", "H0039"]


def test_a_second_camera_of_a_target_is_a_warning_not_a_failure(field, capsys):
    def second(data):
        data["cameras"].append(dict(data["cameras"][0], id="C3"))

    code, doc = _json([field(second)], capsys)
    row = next(c for c in doc["checks"] if c["name"] == "C3 frame")
    assert code == 0 and row["status"] == "warning" and "watched by C1" in row["found"]
    assert doc["summary"]["warning"] == 1


def test_probe_sets_a_stream_cameras_exposure_back_to_what_it_was(streamed, tmp_path, capsys):
    server, data = streamed
    cams = server.streams.cameras
    cams["C1"].set_exposure(1.5)  # not the nominal one: probe must restore this, not a default
    before = {cid: cam.exposure_ms for cid, cam in cams.items()}
    path = tmp_path / "field.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    code = main(["probe", str(path), "--json", "--heliostats", "H0001"])
    doc = json.loads(capsys.readouterr().out)
    assert {cid: cam.exposure_ms for cid, cam in cams.items()} == before
    assert code == 0, [c for c in doc["checks"] if c["status"] != "ok"]
    exposure = {c["name"]: c for c in doc["checks"] if c["name"].endswith(" exposure")}
    assert set(exposure) == {f"{cid} exposure" for cid in cams}
    c1 = exposure["C1 exposure"]
    assert c1["values"]["exposure_ms"] == 1.5 and c1["values"]["applied_ms"] == 3.0
    assert c1["found"].endswith("set back to 1.5 ms") and c1["status"] == "ok"
    assert c1["values"]["restored_ms"] == 1.5


def test_an_exposure_not_set_back_is_a_warning_naming_why():
    """A camera whose control fails after the asked exposure took (a dropped link, say): the row
    says it was not set back, and why (a stand-in camera: the failure needs a timed fault)."""
    from helicalib.app.probe import _exposure
    from helicalib.devices.camera_http import CameraError
    from helicalib.devices.protocols import Frame

    class Camera:
        def __init__(self):
            self.asked = []

        def grab(self, exposure_ms=None):
            self.asked.append(exposure_ms)
            if len(self.asked) > 1:
                raise CameraError("camera_unreachable", "camera http://cam/1: connection refused", True)
            return Frame(data=b"", capture_time_s=0.0, source="http://cam/1", exposure_ms=exposure_ms)

    cam = Camera()
    check = _exposure("C1", cam, 1.5)
    assert cam.asked == [3.0, 1.5] and check.status == "warning" and check.values["restored_ms"] is None
    assert check.found.endswith("not set back to 1.5 ms (camera http://cam/1: connection refused)")
