"""Shared fixtures: the demo field config and helpers to write variants of it."""

from __future__ import annotations

import copy
import socket
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, settings

# Property tests judge results, never speed: no per-example deadline and no health check that
# times data generation (both fail on a loaded 2-core machine while the property holds).
settings.register_profile("helicalib", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("helicalib")

ROOT = Path(__file__).resolve().parents[1]
DEMO_FIELD = ROOT / "field_config" / "demo_north.yaml"


def free_port() -> int:
    """A loopback port nobody listens on now (for a server a test starts in another process)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop(proc, timeout_s: float = 20.0) -> None:
    """End a server process a test started: SIGTERM, then SIGKILL if it has not ended after ``timeout_s``."""
    proc.terminate()
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def wait_port(port: int, timeout_s: float = 30.0) -> None:
    """Return once something listens on loopback ``port``; AssertionError after ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise AssertionError(f"nothing listens on {port} after {timeout_s:g} s")


@pytest.fixture(scope="session")
def demo_field_path() -> Path:
    return DEMO_FIELD


@pytest.fixture()
def demo_data() -> dict:
    """A fresh, mutable copy of the demo field config as parsed YAML."""
    return copy.deepcopy(_demo_data())


_CACHE: dict = {}


def _demo_data() -> dict:
    if "d" not in _CACHE:
        _CACHE["d"] = yaml.safe_load(DEMO_FIELD.read_text())
    return _CACHE["d"]


@pytest.fixture()
def write_field(tmp_path):
    """Write a field-config mapping to a YAML file in tmp_path and return its path."""

    def _write(data: dict, name: str = "field.yaml") -> Path:
        path = tmp_path / name
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path

    return _write
