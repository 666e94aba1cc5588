"""``helicalib validate`` and ``python -m helicalib`` as subprocesses."""

from __future__ import annotations

import json
import subprocess
import sys

import yaml


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "helicalib", *args], capture_output=True, text=True, timeout=300)


def test_validate_demo_prints_summary(demo_field_path):
    r = _cli("validate", str(demo_field_path), "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["heliostats"] == 40
    assert s["targets"]["T1"]["heliostats"] + s["targets"]["T2"]["heliostats"] == 40
    assert s["drives"]["tr20"]["heliostats"] == 40
    # slant ranges from an independent computation over the YAML
    data = yaml.safe_load(demo_field_path.read_text())
    t1 = next(t for t in data["targets"] if t["id"] == "T1")["center_enu_m"]
    d = [sum((a - b) ** 2 for a, b in zip(h["position_enu_m"], t1)) ** 0.5 for h in data["heliostats"] if h["target"] == "T1"]
    assert abs(s["targets"]["T1"]["slant_range_m"]["max"] - max(d)) < 0.06


def test_validate_reports_errors_with_exit_1(demo_data, write_field):
    demo_data["heliostats"][1]["drive"] = "missing"
    path = write_field(demo_data)
    r = _cli("validate", str(path))
    assert r.returncode == 1
    assert f"{path}: heliostats[1].drive: unknown drive 'missing'" in r.stderr
    assert "not valid" in r.stderr


def test_help_lists_commands():
    r = _cli("--help")
    assert r.returncode == 0
    for name in ("validate", "sun", "demo"):
        assert name in r.stdout
