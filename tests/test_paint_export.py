"""PAINT export: a simulated campaign written in PAINT's layout and read back by import-paint gives the
same observations (1e-9), the exported linkage is the drive's, and the STAC catalogue holds together."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helicalib.calibration.observations import read_observations
from helicalib.cli import main
from helicalib.config import load_field_config
from helicalib.geometry.heliostat import HeliostatModel
from helicalib.realdata import geodesy, paint, paint_export
from helicalib.realdata.paint_kinematics import sun_vector_paint

from campaign_helpers import inprocess_campaign

DATA = Path(__file__).parent / "data" / "paint"
ECEF_ULP_M = math.ulp(6.4e6)
"""One unit in the last place of an Earth-centred coordinate (9.3e-10 m): the importer's WGS84 → ENU subtracts
two such numbers, so a WGS84 round trip of a plant point is good to a few of these, not better."""
IDS = ["H0003", "H0021"]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory, demo_field_path):
    """A real in-process campaign (rendered frames, vision, store) of two heliostats over two hours,
    exported with the CLI and imported back with the CLI."""
    tmp = tmp_path_factory.mktemp("paint_export")
    cfg = load_field_config(demo_field_path)
    runner, sim, store, cid, _ = inprocess_campaign(cfg, tmp, 8.5, 7, IDS)
    runner.run_until(sim.t_s + 2.0 * 3600)
    store.close()
    out = tmp / "paint"
    assert main(["export-paint", str(tmp / "c.db"), "--out", str(out), "--field", str(demo_field_path),
                 "--images", str(tmp / "img"), "--increment", "154166.6667", "--json"]) == 0
    back = tmp / "back"
    assert main(["import-paint", str(out), "--out", str(back)]) == 0
    assert main(["export-paint", str(tmp / "c.db"), "--out", str(tmp / "plain"), "--field", str(demo_field_path),
                 "--no-frames"]) == 0
    return {"cfg": cfg, "db": tmp / "c.db", "out": out, "back": back, "plain": tmp / "plain"}


def _source_rows(db: Path, tmp: Path):
    from helicalib.store.sqlite import Store

    with Store.open(db, readonly=True) as store:
        store.export_fit_csv(tmp / "src.csv")
    return {r.record_id: r for r in read_observations(tmp / "src.csv")}


def test_round_trip_gives_back_the_observations(campaign, tmp_path):
    src = _source_rows(campaign["db"], tmp_path)
    back = {r.record_id: r for r in read_observations(campaign["back"] / "observations.csv")}
    assert len(src) >= 6 and {r.heliostat_id for r in src.values()} == set(IDS)
    assert set(back) == set(src)
    for rid, a in src.items():
        b = back[rid]
        assert (b.heliostat_id, b.target_id) == (a.heliostat_id, a.target_id)
        assert pd.Timestamp(b.utc_time) == pd.Timestamp(a.utc_time)  # exact, to the nanosecond
        np.testing.assert_allclose(b.sun_enu, a.sun_enu, rtol=0, atol=1e-12)
        np.testing.assert_allclose(b.strokes_mm, a.strokes_mm, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.spot_enu_m, a.spot_enu_m, rtol=0, atol=4 * ECEF_ULP_M)
        np.testing.assert_allclose([b.target_u_m, b.target_v_m], [a.target_u_m, a.target_v_m], rtol=0,
                                   atol=8 * ECEF_ULP_M)


def test_records_are_in_paint_convention(campaign, tmp_path):
    """Sun azimuth 0 = south, +90 = east; motor positions = stroke · increment / 1000; the spot in WGS84."""
    src = _source_rows(campaign["db"], tmp_path)
    cfg = campaign["cfg"]
    ref = (cfg.site.latitude_deg, cfg.site.longitude_deg, cfg.site.altitude_m)
    for rid, a in src.items():
        rec = json.loads((campaign["out"] / a.heliostat_id / "Calibration" / f"{rid}-calibration-properties.json")
                         .read_text())
        az, el = rec["sun_azimuth"], rec["sun_elevation"]
        # written out independently: north-clockwise azimuth A of the sun vector, PAINT's = 180° - A
        e, n, u = a.sun_enu
        a_north = math.degrees(math.atan2(e, n)) % 360.0
        assert (180.0 - a_north - az + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-9)
        assert el == pytest.approx(math.degrees(math.asin(u)), abs=1e-9)
        np.testing.assert_allclose(sun_vector_paint(az, el), a.sun_enu, atol=1e-12)
        m = rec["motor_position"]
        assert m["axis_1_motor_position"] == pytest.approx(a.stroke1_mm * 154.1666667, rel=1e-12)
        assert m["axis_2_motor_position"] == pytest.approx(a.stroke2_mm * 154.1666667, rel=1e-12)
        assert rec["target_name"] == a.target_id
        np.testing.assert_allclose(geodesy.wgs84_to_enu(rec["focal_spot"]["UTIS"], ref), a.spot_enu_m, atol=1e-8)
        assert (campaign["out"] / a.heliostat_id / "Calibration" / f"{rid}-raw.png").read_bytes()[:8] == \
            b"\x89PNG\r\n\x1a\n"
    assert not list((campaign["plain"]).rglob("*.png"))


def test_exported_linkage_is_the_drive(campaign):
    """The field config import-paint makes from the export moves the mirror as the demo drive does: same
    normal and mirror centre for strokes over the whole range, and the same stroke range."""
    cfg, back = campaign["cfg"], load_field_config(campaign["back"] / "field.yaml")
    rng = np.random.default_rng(3)
    for hid in IDS:
        lo, hi = np.array([a.stroke_range_mm for a in cfg.drives[cfg.heliostat(hid).drive].actuators]).T
        strokes = lo + rng.random((50, 2)) * (hi - lo)
        ours = HeliostatModel.from_config(cfg, [hid]).repeat(50)
        theirs = HeliostatModel.from_config(back, [hid]).repeat(50)
        np.testing.assert_allclose(theirs.normal(strokes), ours.normal(strokes), atol=1e-12)
        np.testing.assert_allclose(theirs.pivots_eff_enu, ours.pivots_eff_enu, atol=1e-9)
        assert theirs.mirror_offset_m == pytest.approx(ours.mirror_offset_m, abs=1e-12)
        np.testing.assert_allclose([a.stroke_range_mm for a in back.drives[back.heliostat(hid).drive].actuators],
                                   [a.stroke_range_mm for a in cfg.drives[cfg.heliostat(hid).drive].actuators],
                                   atol=1e-9)
    for t in cfg.targets:
        b = back.target(t.id)
        np.testing.assert_allclose(b.center_enu_m, t.center_enu_m, atol=1e-9)
        np.testing.assert_allclose(b.normal_enu, t.normal_enu, atol=1e-12)
        np.testing.assert_allclose(b.size_m, t.size_m, atol=1e-9)


def test_stac_catalogue_links_resolve(campaign):
    """Every link and asset href is relative and points to a file; every record has an item and every item
    is reached from the catalogue through its collection."""
    out = campaign["out"]
    seen, todo = set(), [out / "catalog.json"]
    while todo:
        doc_path = todo.pop()
        if doc_path in seen:
            continue
        seen.add(doc_path)
        doc = json.loads(doc_path.read_text())
        assert doc["stac_version"] == "1.0.0" and doc["type"] in ("Catalog", "Collection", "Feature")
        hrefs = [link["href"] for link in doc["links"]] + [a["href"] for a in doc.get("assets", {}).values()]
        for href in hrefs:
            assert href.startswith(("./", "../")), href
            assert (doc_path.parent / href).resolve().is_file(), f"{doc_path}: {href}"
        todo += [(doc_path.parent / link["href"]).resolve() for link in doc["links"]
                 if link["rel"] in ("child", "item")]
    items = {p.name for p in seen if p.name.endswith("-calibration-item-stac.json")}
    records = {p.name.replace("-calibration-properties", "-calibration-item-stac")
               for p in out.rglob("*-calibration-properties.json")}
    assert items == records and len(items) >= 6
    item = json.loads(next(out.rglob("*-calibration-item-stac.json")).read_text())
    assert 0.0 <= item["properties"]["view:sun_azimuth"] < 360.0  # STAC's azimuth is from north


def test_enu_to_wgs84_inverts_the_importer():
    ref = (50.913421122592574, 6.387824755874856, 87.0)
    pts = np.random.default_rng(1).uniform([-3000, -3000, -50], [3000, 3000, 300], size=(200, 3))
    llh = paint_export.enu_to_wgs84(pts, ref)
    np.testing.assert_allclose(geodesy.wgs84_to_enu(llh, ref), pts, rtol=0, atol=4 * ECEF_ULP_M)
    # a known point: the AA39 properties' WGS84 position (the README's ENU)
    aa39 = json.loads((DATA / "AA39" / "AA39-heliostat-properties.json").read_text())["heliostat_position"]
    back = paint_export.enu_to_wgs84(geodesy.wgs84_to_enu(aa39, ref), ref)
    np.testing.assert_allclose(back[:2], aa39[:2], rtol=0, atol=1e-13)  # degrees: 1e-13° ≈ 1e-8 m
    assert back[2] == pytest.approx(aa39[2], abs=4 * ECEF_ULP_M)


def test_real_paint_properties_survive_import_and_export():
    """AA39's real linkage, imported and exported again, gives PAINT's own kinematics (up to the equivalent
    parameterisation) and its motor positions to the step."""
    from helicalib.config import parse_field_config

    imp = paint.scan([DATA / "AA39", DATA / "tower-measurements.json"])
    cfg = parse_field_config(paint.field_config_dict(imp))
    props = paint_export.heliostat_properties(cfg, "AA39", increment_steps_per_m=154166.6667)
    orig = imp.heliostats["AA39"].kinematics
    acts = props["kinematics_properties"]["actuators"]
    for a, o in zip(acts, orig.actuators):
        assert (a["offset"], a["pivot_radius"], a["clockwise_axis_movement"]) == (o.offset, o.pivot_radius,
                                                                                   o.clockwise_axis_movement)
        assert a["initial_angle"] == pytest.approx(o.initial_angle, abs=1e-12)
        assert a["max_increment"] == pytest.approx(o.max_increment, rel=1e-12)
    assert props["kinematics_properties"]["concentrator_translation_n"] == pytest.approx(0.175)
    rec = imp.records[0]
    strokes = paint.steps_to_stroke_mm(rec.motor_steps, orig.actuators[0])
    assert paint_export.stroke_to_steps(strokes[0], 154166.6667) == pytest.approx(rec.motor_steps[0], abs=1e-9)


def test_azimuth_elevation_drive_is_refused_with_its_key(demo_data, write_field):
    demo_data["drives"]["tr20"]["kind"] = "azimuth-elevation"
    cfg = load_field_config(write_field(demo_data))
    with pytest.raises(Exception, match=r"drives\.tr20: axis 1 .* not east"):
        paint_export.heliostat_properties(cfg, "H0001")


def test_export_without_a_database_is_one_line(tmp_path, capsys):
    assert main(["export-paint", str(tmp_path / "none.db"), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.db: no such database file" in err[0]


def test_export_holds_every_key_artists_paint_parsers_read(campaign):
    """The keys and file names ARTIST's PAINT parsers (``artist/io/paint_scenario_parser.py``,
    ``paint_calibration_parser.py``, commit f11ff5a) read, looked up the way they look them up."""
    out = campaign["out"]
    tower = json.loads((out / "tower-measurements.json").read_text())
    assert list(tower)[0] == "power_plant_properties" and len(tower["power_plant_properties"]["coordinates"]) == 3
    for name in list(tower)[1:]:  # ARTIST: every key after the first is a target area with a type
        area = tower[name]
        assert area["type"] == "planar" and len(area["normal_vector"]) == 3
        for corner in ("upper_left", "lower_left", "upper_right", "lower_right", "center"):
            assert len(area["coordinates"][corner]) == 3
    actuator_keys = {"increment", "initial_stroke_length", "offset", "pivot_radius", "initial_angle", "type_axis",
                     "clockwise_axis_movement", "min_increment", "max_increment"}
    for hid in IDS:
        h = json.loads((out / hid / "Properties" / f"{hid}-heliostat-properties.json").read_text())
        assert len(h["heliostat_position"]) == 3 and len(h["initial_orientation"]) == 3
        facets = h["facet_properties"]
        assert facets["number_of_facets"] == len(facets["facets"])
        for f in facets["facets"]:
            assert all(len(f[k]) == 3 for k in ("translation_vector", "canting_e", "canting_n"))
        kin = h["kinematics_properties"]
        for j in (1, 2):
            assert all(isinstance(kin[f"joint_translation_{c}_{j}"], float) for c in "enu")
        assert all(isinstance(kin[f"concentrator_translation_{c}"], float) for c in "enu")
        assert len(kin["actuators"]) == 2 and all(actuator_keys <= set(a) for a in kin["actuators"])
        props = sorted((out / hid / "Calibration").glob("*calibration-properties.json"))
        assert props
        for p in props:
            rec = json.loads(p.read_text())
            assert (p.parent / f"{p.stem.split('-')[0]}-raw.png").is_file()  # ARTIST's image lookup
            assert rec["target_name"] in tower and len(rec["focal_spot"]["UTIS"]) == 3
            assert all(isinstance(rec[k], float) for k in ("sun_azimuth", "sun_elevation"))
            assert set(rec["motor_position"]) == {"axis_1_motor_position", "axis_2_motor_position"}


@pytest.mark.parametrize("hid", ["../escaped", "AB12-N", ".hidden", "a b", "x/y", ""])
def test_a_heliostat_id_that_cannot_name_a_paint_folder_is_refused(hid):
    from helicalib.errors import ConfigError

    with pytest.raises(ConfigError, match="PAINT needs an id"):
        paint_export.heliostat_name(hid)


def test_an_export_never_writes_outside_its_folder(campaign, tmp_path, demo_data, write_field):
    import dataclasses

    from helicalib.errors import ConfigError

    # validate refuses such an id; a database written before that rule (or a config built in memory)
    # may still hold one, and the export must guard its folder on its own
    cfg = load_field_config(write_field(demo_data))
    escaped = cfg.heliostats[0].model_copy(update={"id": "../escaped"})
    cfg = cfg.model_copy(update={"heliostats": type(cfg.heliostats)([escaped, *cfg.heliostats[1:]])})
    row = next(iter(_source_rows(campaign["db"], tmp_path).values()))
    row = dataclasses.replace(row, heliostat_id="../escaped", target_id=cfg.heliostats[0].target)
    out = tmp_path / "deep" / "export"
    with pytest.raises(ConfigError, match="PAINT needs an id"):
        paint_export.write_export(cfg, [row], out)
    assert not (tmp_path / "deep" / "escaped").exists() and not list(out.rglob("*"))
    assert paint_export.heliostat_name("H0003") == "H0003" and paint_export.heliostat_name("AA39") == "AA39"


# ------------------------------------------------------------------------------------ streaming
def test_streamed_export_equals_the_in_memory_export_byte_for_byte(campaign, tmp_path):
    """The CLI streams the database heliostat by heliostat (store/stream.py, PaintWriter); the in-memory
    path (export_fit_csv → CSV → write_export) writes the same files, byte for byte."""
    from helicalib.commands.export_paint import campaign_rows
    from helicalib.outdir import MARKER
    from helicalib.store.sqlite import Store

    with Store.open(campaign["db"], readonly=True) as store:
        c = store.campaigns()[-1]
        rows, _frames = campaign_rows(store, c.id, campaign["cfg"].calibration.spot_method)
    ref = tmp_path / "ref"
    paint_export.write_export(campaign["cfg"], rows, ref,
                              description=f"helicalib campaign {c.id} ({c.name}) of {campaign['db']}")
    streamed = {p.relative_to(campaign["plain"]): p.read_bytes() for p in campaign["plain"].rglob("*")
                if p.is_file() and p.name != MARKER}
    memory = {p.relative_to(ref): p.read_bytes() for p in ref.rglob("*") if p.is_file()}
    assert len(memory) > 6 + 2 * len(IDS)
    assert set(streamed) == set(memory)
    assert [k for k in memory if streamed[k] != memory[k]] == []


def test_stream_reads_every_row_once_in_any_chunk(campaign):
    from helicalib.store.sqlite import Store
    from helicalib.store.stream import iter_heliostat_observations, iter_observation_chunks, iter_observations

    with Store.open(campaign["db"], readonly=True) as store:
        cid = store.campaigns()[-1].id
        every = store.observations(campaign_id=cid)
        by_key = [o.id for o in sorted(every, key=lambda o: (o.heliostat_id, o.id))]
        for chunk in (1, 3, 5000):
            assert [o.id for o in iter_observations(store, cid, chunk=chunk)] == by_key
            assert [o.id for o in iter_observations(store, cid, chunk=chunk, order="id")] == [o.id for o in every]
            assert max(len(c) for c in iter_observation_chunks(store, cid, chunk=chunk)) <= chunk
        for flag in (True, False):
            assert list(iter_observations(store, cid, chunk=2, valid=flag)) == \
                sorted((o for o in every if o.valid == flag), key=lambda o: (o.heliostat_id, o.id))
        groups = list(iter_heliostat_observations(store, cid, chunk=2))
        assert [h for h, _ in groups] == sorted({o.heliostat_id for o in every})
        assert all({o.heliostat_id for o in rows} == {h} for h, rows in groups)
        with pytest.raises(ValueError, match="order 'time'"):
            next(iter_observations(store, cid, order="time"))
