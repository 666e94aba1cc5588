"""Every reader of user files either succeeds or raises HelicalibError naming the file — never
another exception — on mutated inputs: flipped, cut or non-UTF-8 bytes, random YAML values at
random key paths, random CSV cells.

Readers: field config (YAML and its heliostat CSV), scenario, FLUX.yaml (and its response-curve
CSV), trough COLLECTOR.yaml / CAMERA.yaml, observations CSV (``helicalib fit``), accuracy series
CSV (``helicalib accuracy``) and the PAINT importer (``helicalib import-paint``).
"""

from __future__ import annotations

import copy
import csv
import io
import json
import shutil
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from helicalib.calibration.observations import read_observations
from helicalib.cli import main
from helicalib.commands.accuracy import read_series
from helicalib.config import load_field_config
from helicalib.errors import HelicalibError
from helicalib.flux.config import load_correction_data, load_flux_calibration
from helicalib.sim.scenario import load_scenario
from helicalib.trough.config import load_camera, load_collector

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"
PAINT = ROOT / "tests" / "data" / "paint"
SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
                derandomize=True)

# ---------------------------------------------------------------------------------------- strategies
ODD_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6), st.integers(min_value=10**300, max_value=10**301),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0, -1, 0.0, -0.0, 1e308, -1e308, 1e-320]),
    st.text(max_size=12), st.sampled_from(["", " ", "nan", "inf", "2026-13-45", "yesterday", "T1", "H0001"]),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5),
    st.lists(st.integers(-5, 5), min_size=2, max_size=3), st.builds(list), st.builds(dict),  # fresh objects
    st.dictionaries(st.text(max_size=6), st.integers(-3, 3), max_size=3),
    st.lists(st.lists(st.integers(-3, 3), min_size=2, max_size=2), min_size=4, max_size=4),
)
ODD_CELLS = st.one_of(
    st.sampled_from(["", " ", "nan", "inf", "-inf", "1e999", "-1", "0", "1e308", "x", '"', "a,b", "é", "\x00",
                     "yesterday", "2026-06-01T10:00:00Z", "2026-06-01 10:00", "H0001", "T1", "ZZZ"]),
    st.text(max_size=10), st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


@st.composite
def mutated_mapping(draw, base):
    """``base`` with one to three random edits: a value replaced, a key removed, an unknown key added."""
    data = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(data))
        path = draw(st.sampled_from(paths))
        kind = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if not path:
            if kind == "replace":
                data = draw(ODD_VALUES)
            continue
        parent = data
        try:
            for key in path[:-1]:
                parent = parent[key]
        except (KeyError, IndexError, TypeError):
            continue
        if not isinstance(parent, (dict, list)):
            continue
        if kind == "replace":
            parent[path[-1]] = draw(ODD_VALUES)
        elif kind == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(["extra", "id", "x_m", "1"]))] = draw(ODD_VALUES)
        else:
            parent.append(draw(ODD_VALUES))
    return data


@st.composite
def mutated_bytes(draw, base: bytes):
    """``base`` with one to three byte-level edits: flips, cuts, non-UTF-8 bytes, deleted spans."""
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.integers(0, len(data)))
        kind = draw(st.sampled_from(["flip", "truncate", "non-utf8", "delete", "nul"]))
        if kind == "flip" and at < len(data):
            data[at] = draw(st.integers(0, 255))
        elif kind == "truncate":
            del data[at:]
        elif kind == "non-utf8":
            data[at:at] = draw(st.sampled_from([b"\xff", b"\xe9", b"\xc3", b"\x80\x80", b"\xed\xa0\x80"]))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 40))]
        else:
            data[at:at] = b"\x00"
    return bytes(data)


@st.composite
def mutated_csv(draw, rows: list[list[str]]):
    """``rows`` with one to three cells replaced, a row cut short or lengthened."""
    rows = [list(r) for r in rows]
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(rows) - 1))
        kind = draw(st.sampled_from(["cell", "cell", "cell", "short", "long"]))
        if kind == "cell" and rows[i]:
            rows[i][draw(st.integers(0, len(rows[i]) - 1))] = draw(ODD_CELLS)
        elif kind == "short" and rows[i]:
            rows[i] = rows[i][: draw(st.integers(0, len(rows[i]) - 1))]
        else:
            rows[i] = rows[i] + [draw(ODD_CELLS)]
    return rows


def _csv_text(rows) -> str:
    out = io.StringIO()
    csv.writer(out).writerows(rows)
    return out.getvalue()


def _yaml(data) -> str:
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True)


def _refused_or_read(read, *names: str):
    """Call ``read()``; a HelicalibError is fine when every line of it names one of the files."""
    try:
        read()
    except HelicalibError as err:
        lines = str(err).split("\n")
        assert str(err), "an empty error message"
        for line in lines:
            assert any(n in line for n in names), f"error line names no file: {line!r}"


# ---------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def field_data():
    return yaml.safe_load(FIELD.read_text())


@pytest.fixture(scope="module")
def field_cfg():
    return load_field_config(FIELD)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("bad_input")


# ---------------------------------------------------------------------------------------- field config
FIELD_DATA = yaml.safe_load(FIELD.read_text())
FIELD_PATHS = [p for p in _paths(FIELD_DATA) if p]


def _edited(base, edits):
    data = copy.deepcopy(base)
    for path, value in edits:
        parent = data
        try:
            for key in path[:-1]:
                parent = parent[key]
            parent[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            pass  # an earlier edit removed the way there
    return data


@settings(max_examples=80, **SETTINGS)
@given(edits=st.lists(st.tuples(st.sampled_from(FIELD_PATHS), ODD_VALUES), min_size=1, max_size=3))
@example(edits=[(("heliostats",), [])])  # validate's summary divided by nothing before
@example(edits=[(("heliostats", 2, "position_enu_m"), [10**400, 0, 0])])  # OverflowError in the loader before
def test_field_config_mutated_yaml(edits, work, capsys):
    """The loader and ``helicalib validate``'s summary: a result or one error line per problem."""
    path = work / "field.yaml"
    path.write_text(_yaml(_edited(FIELD_DATA, edits)))
    _refused_or_read(lambda: load_field_config(path), "field.yaml")
    rc = main(["validate", str(path), "--no-sweep"])
    err = capsys.readouterr().err
    assert rc in (0, 1) and (rc == 0) == (err == "")


@settings(max_examples=60, **SETTINGS)
@given(data=st.data())
def test_field_config_mutated_bytes(data, work):
    path = work / "field_b.yaml"
    path.write_bytes(data.draw(mutated_bytes(FIELD.read_bytes())))
    _refused_or_read(lambda: load_field_config(path), "field_b.yaml")


@settings(max_examples=60, **SETTINGS)
@given(data=st.data())
def test_field_config_heliostat_csv(data, field_data, work):
    d = dict(field_data)
    rows = [["id", "e_m", "n_m", "u_m", "drive", "target"]] + [
        [h["id"], *map(str, h["position_enu_m"]), h["drive"], h["target"]] for h in d.pop("heliostats")]
    d["heliostats_csv"] = "field_h.csv"
    path = work / "field_c.yaml"
    path.write_text(_yaml(d))
    text = _csv_text(data.draw(mutated_csv(rows))).encode()
    if data.draw(st.booleans()):
        text = data.draw(mutated_bytes(text))
    (work / "field_h.csv").write_bytes(text)
    _refused_or_read(lambda: load_field_config(path), "field_c.yaml", "field_h.csv")


# ---------------------------------------------------------------------------------------- other YAML files
SCENARIO = {"name": "t", "start": "2026-06-01T00:00:00+08:00", "duration_days": 2, "seed": 3,
            "weather": {"wind": {"mean_ms": 3.0}, "events": [{"start": "2026-06-01T10:00:00Z",
                                                             "end": "2026-06-01T12:00:00Z", "wind_ms": 12}]},
            "soiling": {"rate_per_day": 0.01}, "errors": {"tilt_1_mrad": 1.0},
            "faults": {"offline": ["H0001"], "camera_503_probability": 0.1}}
FLUX = {"camera": "C1", "grid_cell_m": 0.02,
        "fe": {"two_radiometer": {"ea_wm2": 900, "eb_wm2": 1000, "eb_prime_wm2": 950, "gav_grey": 120}},
        "corrections": {"dark": {"grey": 3.0}, "nonlinearity": {"curve_csv": "curve.csv"}, "distortion": False,
                        "non_lambertian": {"incidence_deg": [0, 30, 60], "relative": [1, 0.98, 0.9]}},
        "errors": {"dark": 0.01, "calibration": 0.02}, "cleanliness": {"reflectivity_clean": 0.93}}
CURVE = [["input", "grey"]] + [[str(x), str(0.9 * x + 2)] for x in range(0, 260, 20)]


@pytest.mark.parametrize("kind", ["scenario", "flux", "collector", "camera"])
@settings(max_examples=50, **SETTINGS)
@given(data=st.data())
def test_yaml_readers_mutated(kind, data, work):
    base = {"scenario": SCENARIO, "flux": FLUX,
            "collector": yaml.safe_load((ROOT / "field_config" / "trough_collector.yaml").read_text()),
            "camera": yaml.safe_load((ROOT / "field_config" / "trough_camera.yaml").read_text())}[kind]
    path = work / f"{kind}.yaml"
    text = _yaml(data.draw(mutated_mapping(base))).encode()
    if data.draw(st.booleans()):
        text = data.draw(mutated_bytes(text))
    path.write_bytes(text)
    names = [path.name]
    if kind == "flux":
        curve = work / "curve.csv"
        curve.write_bytes(_csv_text(data.draw(mutated_csv(CURVE)) if data.draw(st.booleans()) else CURVE).encode())
        names.append(curve.name)

    def read():
        if kind == "scenario":
            load_scenario(path)
        elif kind == "flux":
            load_correction_data(load_flux_calibration(path))
        elif kind == "collector":
            load_collector(path).facets()
        else:
            load_camera(path).pinhole()

    _refused_or_read(read, *names)


# ---------------------------------------------------------------------------------------- CSV readers
OBS_HEADER = ["heliostat_id", "utc_time", "sun_e", "sun_n", "sun_u", "stroke1_mm", "stroke2_mm", "target_id",
              "spot_e_m", "spot_n_m", "spot_u_m", "target_u_m", "target_v_m", "spot_method", "source", "record_id"]
OBS = [OBS_HEADER] + [["H0001", f"2026-06-01T0{k}:00:00Z", "0.6", "0.0", "0.8", str(300 + k), str(500 - k), "T1",
                       "9.1", "8.0", "95.0", "0.1", "-0.2", "grlm-centroid", "campaign", str(k)] for k in range(5)]
SERIES = [["time", "heliostat", "wind_ms", "u_m", "v_m"]] + [
    [f"2026-06-01T1{k}:00:00+08:00", "H0008", str(2.0 * k), str(0.1 * k), "-0.05"] for k in range(6)]


@settings(max_examples=80, **SETTINGS)
@given(data=st.data())
def test_observations_csv_mutated(data, work):
    path = work / "obs.csv"
    text = ("# provenance, with a comma and a \"quote\n" + _csv_text(data.draw(mutated_csv(OBS)))).encode()
    if data.draw(st.booleans()):
        text = data.draw(mutated_bytes(text))
    path.write_bytes(text)
    _refused_or_read(lambda: read_observations(path), "obs.csv")


@settings(max_examples=80, **SETTINGS)
@given(data=st.data())
def test_accuracy_series_mutated(data, field_cfg, work):
    path = work / "series.csv"
    text = _csv_text(data.draw(mutated_csv(SERIES))).encode()
    if data.draw(st.booleans()):
        text = data.draw(mutated_bytes(text))
    path.write_bytes(text)
    _refused_or_read(lambda: read_series(path, field_cfg, "grlm-centroid"), "series.csv")


# ---------------------------------------------------------------------------------------- PAINT importer
PAINT_FILES = sorted(str(p.relative_to(PAINT)) for p in PAINT.rglob("*") if p.suffix in (".json", ".csv"))


@settings(max_examples=30, **SETTINGS)
@given(data=st.data())
def test_paint_import_mutated(data, work, capsys):
    tree = work / "paint"
    if tree.exists():
        shutil.rmtree(tree)
    shutil.copytree(PAINT, tree, ignore=shutil.ignore_patterns("*.png"))
    victim = tree / data.draw(st.sampled_from(PAINT_FILES))
    if victim.suffix == ".json" and data.draw(st.booleans()):
        victim.write_text(json.dumps(data.draw(mutated_mapping(json.loads(victim.read_text())))))
    else:
        victim.write_bytes(data.draw(mutated_bytes(victim.read_bytes())))
    rc = main(["import-paint", str(tree), "--out", str(work / "paint_out")])
    err = capsys.readouterr().err
    assert rc in (0, 1)
    assert rc == 0 or (err.count("\n") >= 1 and all(ln.startswith("helicalib import-paint: error: ")
                                                  for ln in err.rstrip("\n").split("\n")))
