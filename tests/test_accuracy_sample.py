"""The shipped sample series for ``helicalib accuracy`` and the command line docs/vision.md gives for it.

The line is run as documented; its figures are checked against a computation written here with
numpy from the CSV and the field config alone: formula (1) η = |X − T| / |T − P| · 1000 with X the
spot on the board (centre + u·û + v·v̂), T the board centre and P the heliostat's position; the
RMS of η per heliostat; per wind bin (centre ± half width, inclusive) the count and the count
with η ≤ the threshold; precision as the RMS angle from P between each spot and their mean.
"""

from __future__ import annotations

import csv
import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import yaml

from helicalib.cli import main

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "accuracy_series.csv"
DOC_PREFIX = "helicalib accuracy examples/accuracy_series.csv"


def documented_line() -> list[str]:
    lines = [ln.strip() for ln in (ROOT / "docs" / "vision.md").read_text().splitlines()
             if ln.strip().startswith(DOC_PREFIX)]
    assert len(lines) == 1, f"docs/vision.md: expected one line starting {DOC_PREFIX!r}, found {len(lines)}"
    return shlex.split(lines[0])


def expected_by_heliostat(field_path: Path) -> dict:
    """Per heliostat, from the CSV and the raw YAML: eta (N,), wind (N,), precision (N,)."""
    raw = yaml.safe_load(field_path.read_text())
    from helicalib.config import load_field_config

    cfg = load_field_config(field_path)     # positions (the CSV of heliostats) and the boards' unit axes
    with SAMPLE.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = {}
    for hid in dict.fromkeys(r["heliostat"] for r in rows):
        mine = [r for r in rows if r["heliostat"] == hid]
        h = cfg.heliostat(hid)
        board = next(t for t in raw["targets"] if t["id"] == h.target)
        centre = np.array(board["center_enu_m"], dtype=float)
        eu, ev = cfg.target(h.target).frame_enu[0], cfg.target(h.target).frame_enu[1]
        uv = np.array([[float(r["u_m"]), float(r["v_m"])] for r in mine])
        x = centre + uv[:, :1] * eu + uv[:, 1:] * ev
        p = np.asarray(h.position_enu_m, dtype=float)
        eta = 1000 * np.linalg.norm(x - centre, axis=1) / np.linalg.norm(centre - p)
        prec = 1000 * np.linalg.norm(x - x.mean(axis=0), axis=1) / np.linalg.norm(x.mean(axis=0) - p)
        out[hid] = (eta, np.array([float(r["wind_ms"]) for r in mine]), prec)
    return out, raw["tracking_test"]


def test_sample_series_has_what_the_command_reads():
    with SAMPLE.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and set(rows[0]) == {"time", "heliostat", "wind_ms", "u_m", "v_m"}
    winds = np.array([float(r["wind_ms"]) for r in rows])
    assert len({r["heliostat"] for r in rows}) >= 3 and winds.max() - winds.min() > 4.0


def test_documented_accuracy_line_computes_the_series(tmp_path, capsys, monkeypatch):
    words = documented_line()
    monkeypatch.chdir(tmp_path)                              # the plot lands here, not in the checkout
    argv = [str(ROOT / w) if (ROOT / w).is_file() else w for w in words[1:]]
    assert main(argv) == 0
    text = capsys.readouterr().out
    plot = next(w for w in words if w.endswith(".png"))
    assert (tmp_path / plot).read_bytes().startswith(b"\x89PNG")
    assert main([*argv, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)

    expected, spec = expected_by_heliostat(ROOT / "field_config" / "demo_north.yaml")
    thr, half = spec["threshold_mrad"], spec["bin_half_width_ms"]
    assert set(summary["heliostats"]) == set(expected)
    verdicts = []
    for hid, (eta, wind, prec) in expected.items():
        got = summary["heliostats"][hid]
        assert got["n"] == len(eta)
        assert got["accuracy_rms_mrad"] == pytest.approx(np.sqrt(np.mean(eta**2)), abs=5.1e-5)   # JSON: 4 decimals
        assert got["precision_rms_mrad"] == pytest.approx(np.sqrt(np.mean(prec**2)), abs=5.1e-5)
        status = []
        for b, want in zip(got["bins"], spec["wind_bins"]):
            sel = (wind >= want["wind_ms"] - half) & (wind <= want["wind_ms"] + half)
            n, k = int(sel.sum()), int((sel & (eta <= thr)).sum())
            assert (b["n"], b["within"]) == (n, k)
            status.append(None if n == 0 else k / n > want["min_fraction"])
        verdict = "fail" if False in status else ("incomplete" if None in status else "pass")
        assert got["verdict"] == verdict
        verdicts.append(verdict)
        # the text output of the documented line shows the same figures
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(f"{hid}:"))
        m = re.search(r"accuracy ([\d.]+) mrad RMS, precision ([\d.]+) mrad RMS", line)
        assert m and float(m.group(1)) == pytest.approx(np.sqrt(np.mean(eta**2)), abs=0.0051)
        assert verdict in line
    overall = "fail" if "fail" in verdicts else ("incomplete" if "incomplete" in verdicts else "pass")
    assert summary["verdict"] == overall and overall.upper() in text.splitlines()[0]
