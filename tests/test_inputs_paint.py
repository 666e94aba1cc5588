"""``import-paint`` writes only finite, physical rows: a record with a value no plant can have (NaN or
boolean motor positions, an infinite spot, a sun at 1e308°, integers of 400 digits) is skipped and
named with its file and key, a heliostat whose kinematics no drive has (``increment: 0``, an
infinite axis setting) too, and all are counted in the summary (``--json`` too). A property test
over generated records: never a traceback, every written row finite and physical.

The records are the real PAINT test data of ``tests/data/paint`` (see its ATTRIBUTION.md)."""

from __future__ import annotations

import copy
import csv
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helicalib.cli import main
from helicalib.config import load_field_config

PAINT = Path(__file__).resolve().parent / "data" / "paint"
AA39 = "AA39"
RECORDS = sorted(p.relative_to(PAINT) for p in PAINT.rglob("*calibration-properties*.json"))
HUGE = "1" + "0" * 400


@pytest.fixture()
def tree(tmp_path) -> Path:
    out = tmp_path / "paint"
    shutil.copytree(PAINT, out, ignore=shutil.ignore_patterns("*.png"))
    return out


def _edit(path: Path, edit) -> None:
    d = json.loads(path.read_text())
    edit(d)
    path.write_text(json.dumps(d))


def _import(capsys, tree: Path, out: Path) -> tuple[int, dict | None, str]:
    rc = main(["import-paint", str(tree), "--out", str(out), "--json"])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err
    return rc, (json.loads(cap.out) if rc == 0 else None), cap.err


def test_records_with_impossible_values_are_skipped_and_counted(tree, tmp_path, capsys):
    a = tree / AA39
    _edit(a / "AA39-270398-calibration-properties.json",
          lambda d: d["motor_position"].update(axis_1_motor_position=math.nan))
    _edit(a / "AA39-271633-calibration-properties.json", lambda d: d["focal_spot"]["UTIS"].__setitem__(2, math.inf))
    _edit(a / "AA39-275564-calibration-properties.json", lambda d: d.update(sun_elevation=1e308))
    _edit(a / "AA39-calibration-properties_1.json", lambda d: d["motor_position"].update(axis_2_motor_position=True))
    p = a / "AA39-calibration-properties_2.json"
    p.write_text(p.read_text().replace('"axis_1_motor_position": ', f'"axis_1_motor_position": {HUGE}, "was": '))
    rc, summary, err = _import(capsys, tree, tmp_path / "out")
    assert rc == 0, err
    assert summary["records"] == 11 and summary["heliostats"][AA39]["records"] == 1
    assert summary["skipped"] == {"records": 5, "heliostats": 0, "targets": 0}
    assert sorted(summary["bad"]) == sorted([
        f"{a / 'AA39-270398-calibration-properties.json'}: motor_position.axis_1_motor_position: expected a finite "
        "number, got nan; record skipped",
        f"{a / 'AA39-271633-calibration-properties.json'}: focal_spot.UTIS[2]: expected a finite number, got inf; "
        "record skipped",
        f"{a / 'AA39-275564-calibration-properties.json'}: sun_elevation: 1e+308 is outside -1..90; record skipped",
        f"{a / 'AA39-calibration-properties_1.json'}: motor_position.axis_2_motor_position: expected a number, got "
        "True; record skipped",
        f"{p}: motor_position.axis_1_motor_position: expected a finite number, got inf; record skipped",
    ])
    with open(tmp_path / "out" / "observations.csv", newline="") as f:
        assert sum(1 for row in csv.reader(f) if row and not row[0].startswith("#")) == 1 + 11  # header + rows


def test_the_text_summary_counts_the_skipped(tree, tmp_path, capsys):
    _edit(tree / AA39 / "AA39-270398-calibration-properties.json", lambda d: d.update(sun_azimuth="south"))
    assert main(["import-paint", str(tree), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "skipped for impossible values: 1 record, 0 heliostats, 0 targets" in out
    assert "sun_azimuth: expected a number, got 'south'; record skipped" in out


def test_a_heliostat_whose_kinematics_no_drive_has_is_skipped(tree, tmp_path, capsys):
    _edit(tree / AA39 / "AA39-heliostat-properties.json",
          lambda d: d["kinematics_properties"]["actuators"][0].update(increment=0))
    rc, summary, err = _import(capsys, tree, tmp_path / "out")
    assert rc == 0, err
    assert list(summary["heliostats"]) == ["AA23"] and summary["records"] == 10
    assert summary["skipped"]["heliostats"] == 1
    assert summary["bad"] == [f"{tree / AA39 / 'AA39-heliostat-properties.json'}: kinematics_properties.actuators[0]."
                              "increment: 0 is outside 1e-06..1e+09; heliostat AA39 skipped"]


def test_an_infinite_axis_setting_names_its_line_and_column(tree, tmp_path, capsys):
    p = tree / "AA23" / "test_axis_data.csv"
    text = p.read_text(encoding="utf-8-sig")
    p.write_text(text.replace(",0.005842952618520847,", ",inf,"))
    rc, summary, err = _import(capsys, tree, tmp_path / "out")
    assert rc == 0, err
    assert list(summary["heliostats"]) == [AA39]
    assert summary["bad"] == [f"{p}: line 2: AngleK: expected a finite number, got inf; heliostat '10123' skipped"]


def test_no_usable_heliostat_is_one_line_each(tree, tmp_path, capsys):
    _edit(tree / AA39 / "AA39-heliostat-properties.json",
          lambda d: d["kinematics_properties"]["actuators"][1].update(initial_stroke_length=1e300))
    p = tree / "AA23" / "test_axis_data.csv"
    p.write_text(p.read_text(encoding="utf-8-sig").replace(",154166.66666666666,", ",0,", 1))
    rc, _, err = _import(capsys, tree, tmp_path / "out")
    assert rc == 1 and not (tmp_path / "out" / "field.yaml").exists()
    lines = err.strip().split("\n")
    assert all(ln.startswith("helicalib import-paint: error: ") for ln in lines)
    assert "kinematics_properties.actuators[1].initial_stroke_length: 1e+300 is outside" in lines[0]
    assert "line 2: PulseRatio: 0 is outside" in lines[1]
    assert lines[-1].endswith("no usable heliostat properties found (heliostat-properties.json or HeliOS tables)")


# ----------------------------------------------------------------------------------- property test
ODD = st.one_of(
    st.none(), st.booleans(), st.sampled_from([0, -1, 10**40, -(10**40), 0.0, -0.0, 1e308, -1e308, 1e-320, 5e5]),
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**7), st.text(max_size=6),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4), st.builds(dict),
)
RECORD_KEYS = [("motor_position", "axis_1_motor_position"), ("motor_position", "axis_2_motor_position"),
               ("motor_position",), ("sun_elevation",), ("sun_azimuth",), ("target_name",), ("focal_spot", "UTIS"),
               ("focal_spot", "UTIS", 0), ("focal_spot", "UTIS", 1), ("focal_spot", "UTIS", 2), ("focal_spot",)]
PROPERTY_KEYS = [("heliostat_position", 0), ("heliostat_position", 2), ("width",), ("height",),
                 ("initial_orientation", 1)] + [
    ("kinematics_properties", "actuators", k, key) for k in (0, 1)
    for key in ("increment", "initial_stroke_length", "offset", "pivot_radius", "initial_angle",
                "clockwise_axis_movement", "min_increment", "max_increment")] + [
    ("kinematics_properties", "concentrator_translation_n",)]


def _set(d, path, value) -> None:
    for key in path[:-1]:
        d = d[key]
    d[path[-1]] = value


@st.composite
def damaged_tree(draw):
    """Edits of the real PAINT data: one to four calibration records and perhaps the AA39 properties,
    each with one to three values replaced by odd ones; huge integers as JSON digits."""
    edits = []
    for rel in draw(st.lists(st.sampled_from(RECORDS), min_size=1, max_size=4, unique=True)):
        edits.append((rel, [(draw(st.sampled_from(RECORD_KEYS)), draw(ODD)) for _ in range(draw(st.integers(1, 3)))]))
    if draw(st.booleans()):
        edits.append((Path(AA39) / "AA39-heliostat-properties.json",
                      [(draw(st.sampled_from(PROPERTY_KEYS)), draw(ODD)) for _ in range(draw(st.integers(1, 2)))]))
    return edits


def _write(tree: Path, edits) -> None:
    for rel, changes in edits:
        d = json.loads((PAINT / rel).read_text())
        for path, value in changes:
            try:
                _set(d, path, value)
            except (KeyError, IndexError, TypeError):
                pass  # an earlier edit replaced the container
        text = json.dumps(d)
        (tree / rel).write_text(text.replace("10000000000000000000000000000000000000000", HUGE))  # 10**40 -> 10**400


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(edits=damaged_tree())
def test_generated_records_never_give_a_traceback_and_rows_are_physical(tmp_path_factory, capsys, edits):
    work = tmp_path_factory.mktemp("gen")
    tree = work / "paint"
    shutil.copytree(PAINT, tree, ignore=shutil.ignore_patterns("*.png"))
    _write(tree, edits)
    rc, summary, err = _import(capsys, tree, work / "out")  # any other exception fails the test
    if rc != 0:
        assert rc == 1 and err and all(ln.startswith("helicalib import-paint: error: ") for ln in err.strip().split("\n"))
        return
    assert summary["records"] + summary["skipped"]["records"] <= len(RECORDS)
    assert summary["skipped"]["records"] + summary["skipped"]["heliostats"] == len(summary["bad"])
    cfg = load_field_config(work / "out" / "field.yaml")
    with open(work / "out" / "observations.csv", newline="") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    assert len(rows) == summary["records"]
    for row in rows:
        nums = {k: float(v) for k, v in row.items() if k not in ("heliostat_id", "utc_time", "target_id", "spot_method",
                                                                  "source", "record_id")}
        assert all(math.isfinite(v) for v in nums.values()), row
        sun = np.array([nums["sun_e"], nums["sun_n"], nums["sun_u"]])
        assert abs(np.linalg.norm(sun) - 1) < 1e-9 and sun[2] >= math.sin(math.radians(-1.0)) - 1e-12
        drive = cfg.drive_of(row["heliostat_id"])
        for k, a in enumerate(drive.actuators, start=1):
            lo, hi = a.stroke_range_mm
            assert lo - 1e-6 <= nums[f"stroke{k}_mm"] <= hi + 1e-6, (row, a.stroke_range_mm)
        w, h = cfg.target(row["target_id"]).size_m
        assert abs(nums["target_u_m"]) <= w / 2 + 1e-9 and abs(nums["target_v_m"]) <= h / 2 + 1e-9
