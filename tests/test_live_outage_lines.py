"""What the crew reads when the plant is down or its clock is wrong: one line of ours, nothing else.

A real CLI process against a closed loopback port (nothing listens): its stderr is our one line,
without pymodbus's own "Connection ... refused" / "Repeating...." lines.
"""

from __future__ import annotations

import socket
import subprocess
import sys

import yaml


def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens on it now: connections are refused
    return port


def _field_at(demo_data, tmp_path, port: int):
    demo_data["plant"]["scs"]["port"] = port
    demo_data["storage"] = {"database": "sqlite:///c.db", "images_dir": "img"}
    path = tmp_path / "field.yaml"
    path.write_text(yaml.safe_dump(demo_data, sort_keys=False))
    return path


def test_a_plant_that_is_down_gives_one_line_and_no_pymodbus_lines(demo_data, tmp_path):
    field = _field_at(demo_data, tmp_path, _closed_port())
    proc = subprocess.run([sys.executable, "-m", "helicalib", "run", str(field)], capture_output=True, text=True,
                          timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("helicalib run: error:") and "refusing to start" in lines[0]
    assert "Repeating" not in proc.stderr and "Connection to" not in proc.stderr
