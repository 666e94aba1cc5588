"""Field config loader: the demo loads; every bad-input class gives one line naming file and key path."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from helicalib.config import load_field_config
from helicalib.errors import ConfigError

from conftest import ROOT


def _problems(path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_field_config(path)
    return info.value.problems


def test_demo_config_loads(demo_field_path):
    cfg = load_field_config(demo_field_path)
    assert len(cfg.heliostats) == 40
    assert {t.id for t in cfg.targets} == {"T1", "T2"}
    assert all(cfg.drives[h.drive].kind == "tilt-roll" for h in cfg.heliostats)
    assert {c.target for c in cfg.cameras} == {"T1", "T2"}
    assert cfg.heliostat_index("H0003") == 2
    # relative storage paths resolve next to the config file (FIELD_CONFIG.md); the shipped one keeps
    # its data out of field_config/, in runs/demo_north/ at the repository root
    assert cfg.database_path.resolve() == (demo_field_path.parent / "../runs/demo_north/helicalib.db").resolve()
    assert cfg.database_path.parent.resolve() != demo_field_path.parent.resolve()


def test_config_objects_are_frozen(demo_field_path):
    cfg = load_field_config(demo_field_path)
    with pytest.raises(Exception):
        cfg.site.latitude_deg = 0.0  # type: ignore[misc]
    with pytest.raises(Exception):
        cfg.heliostats[0].drive = "x"  # type: ignore[misc]


def test_target_frame_follows_the_convention(demo_field_path):
    # FIELD_CONFIG.md: u = unit(z_up × normal), v = normal × u. The demo boards face north, tilted
    # 35° down toward the field: n = (0, cos 35°, -sin 35°), so u = west and v = (0, sin 35°, cos 35°)
    t = load_field_config(demo_field_path).target("T1")
    u, v, w = t.frame_enu
    c, s = np.cos(np.radians(35.0)), np.sin(np.radians(35.0))
    np.testing.assert_allclose(u, [-1, 0, 0], atol=1e-4)
    np.testing.assert_allclose(v, [0, s, c], atol=1e-4)
    np.testing.assert_allclose(w, [0, c, -s], atol=1e-4)
    pts = np.array([[1.0, 2.0, 0.5], [-3.0, 0.0, 0.0]])
    np.testing.assert_allclose(t.enu_to_uvw(t.uvw_to_enu(pts)), pts, atol=1e-12)


@pytest.mark.parametrize(
    ("mutate", "expected_path", "expected_words"),
    [
        (lambda d: d["site"].update(colour="blue"), "site.colour", "unknown key"),
        (lambda d: d["site"].pop("latitude_deg"), "site.latitude_deg", "missing"),
        (lambda d: d["heliostats"][12].update(position_enu_m=[1.0, 2.0]), "heliostats[12].position_enu_m", "expected 3 numbers"),
        (lambda d: d["heliostats"][3].update(position_enu_m="north"), "heliostats[3].position_enu_m", "expected 3 numbers"),
        (lambda d: d["site"].update(altitude_m="high"), "site.altitude_m", "number"),
        (lambda d: d["targets"][1].update(normal_enu=[0.0, 2.0, 0.0]), "targets[1].normal_enu", "unit vector"),
        (lambda d: d["drives"]["tr20"]["actuators"][1].update(stroke_range_mm=[1400, 0]),
         "drives.tr20.actuators[1].stroke_range_mm", "reversed"),
        (lambda d: d["heliostats"][5].update(drive="nosuch"), "heliostats[5].drive", "unknown drive 'nosuch'"),
        (lambda d: d["heliostats"][7].update(target="T9"), "heliostats[7].target", "unknown target 'T9'"),
        (lambda d: d["heliostats"][9].update(id=d["heliostats"][2]["id"]), "heliostats[9].id", "duplicate heliostat id"),
        (lambda d: d["targets"][1].update(id="T1"), "targets[1].id", "duplicate target id"),
        (lambda d: d["cameras"][0].update(target="T7"), "cameras[0].target", "unknown target 'T7'"),
        (lambda d: d["targets"][0].update(standby_offset_m=[1.0, 1.0]), "targets[0].standby_offset_m", "on the board"),
        (lambda d: d["drives"]["tr20"]["actuators"][0].update(gamma0_deg="wide"), "drives.tr20.actuators[0].gamma0_deg", "number"),
        (lambda d: d["drives"]["tr20"]["actuators"][0].update(sign=2), "drives.tr20.actuators[0].sign", "1"),
        (lambda d: d["storage"].update(database="postgres://x"), "storage.database", "sqlite:///"),
    ],
)
def test_bad_input_names_file_and_key_path(demo_data, write_field, mutate, expected_path, expected_words):
    mutate(demo_data)
    path = write_field(demo_data)
    problems = _problems(path)
    hits = [p for p in problems if f": {expected_path}:" in p]
    assert hits, f"no problem names {expected_path}: {problems}"
    assert all(str(path) in p for p in problems)
    assert expected_words.lower() in hits[0].lower()
    assert all("\n" not in p for p in problems)


def test_custom_drive_needs_its_axes(demo_data, write_field):
    demo_data["drives"]["tr20"]["kind"] = "custom"
    problems = _problems(write_field(demo_data))
    assert any("drives.tr20" in p and "axis1_enu" in p for p in problems)


def test_custom_axes_are_normalised(demo_data, write_field):
    demo_data["drives"]["tr20"].update(kind="custom", axis1_enu=[2, 0, 0], axis2_enu=[0, 0, 5], normal0_enu=[0, -3, 0])
    cfg = load_field_config(write_field(demo_data))
    a1, a2, n0 = cfg.drives["tr20"].axes
    np.testing.assert_allclose([a1, a2, n0], [[1, 0, 0], [0, 0, 1], [0, -1, 0]])


def test_heliostats_csv_resolves_next_to_the_config(demo_data, tmp_path):
    rows = demo_data.pop("heliostats")
    sub = tmp_path / "plant"
    sub.mkdir()
    lines = ["id,e_m,n_m,u_m,drive,target"] + [
        f"{h['id']},{h['position_enu_m'][0]},{h['position_enu_m'][1]},{h['position_enu_m'][2]},{h['drive']},{h['target']}"
        for h in rows
    ]
    (sub / "field.csv").write_text("\n".join(lines) + "\n")
    demo_data["heliostats_csv"] = "field.csv"
    import yaml

    (sub / "f.yaml").write_text(yaml.safe_dump(demo_data))
    cfg = load_field_config(sub / "f.yaml")
    assert [h.id for h in cfg.heliostats] == [h["id"] for h in rows]
    np.testing.assert_allclose(cfg.heliostat_positions_enu_m()[4], rows[4]["position_enu_m"])


def test_heliostats_csv_bad_row_names_file_and_line(demo_data, tmp_path):
    demo_data.pop("heliostats")
    (tmp_path / "h.csv").write_text("id,e_m,n_m,u_m,drive,target\nH1,1,2,3,tr20,T1\nH2,x,2,3,tr20,T1\n")
    demo_data["heliostats_csv"] = "h.csv"
    import yaml

    (tmp_path / "f.yaml").write_text(yaml.safe_dump(demo_data))
    problems = _problems(tmp_path / "f.yaml")
    assert "h.csv" in problems[0] and "line 3" in problems[0]


def test_heliostats_csv_unknown_drive(demo_data, tmp_path):
    demo_data.pop("heliostats")
    (tmp_path / "h.csv").write_text("id,e_m,n_m,u_m,drive,target\nH1,1,2,3,tr20,T1\nH2,1,2,3,zz,T1\n")
    demo_data["heliostats_csv"] = "h.csv"
    import yaml

    (tmp_path / "f.yaml").write_text(yaml.safe_dump(demo_data))
    problems = _problems(tmp_path / "f.yaml")
    assert any("heliostats_csv(h.csv)[1].drive" in p and "zz" in p for p in problems)


def test_missing_file_and_bad_yaml(tmp_path):
    assert "file not found" in _problems(tmp_path / "nope.yaml")[0]
    bad = tmp_path / "bad.yaml"
    bad.write_text("site: [1, 2\n")
    assert "not valid YAML" in _problems(bad)[0]


def test_default_pressure_is_the_standard_atmosphere(demo_data, write_field):
    demo_data["site"].pop("pressure_hpa")
    demo_data["site"]["altitude_m"] = 0
    cfg = load_field_config(write_field(demo_data))
    assert cfg.site.pressure_hpa_effective == pytest.approx(1013.25, abs=0.1)


def test_target_frame_is_computed_once_per_normal_and_read_only(demo_field_path):
    cfg = load_field_config(demo_field_path)
    for t in cfg.targets:
        f = t.frame_enu
        assert f is t.frame_enu and not f.flags.writeable
        w = np.asarray(t.normal_enu, dtype=float)
        u = np.cross([0.0, 0.0, 1.0], w)
        u = u / np.linalg.norm(u)
        np.testing.assert_array_equal(f, np.stack([u, np.cross(w, u), w]))
        np.testing.assert_allclose(f @ f.T, np.eye(3), atol=1e-12)
    flat = cfg.targets[0].model_copy(update={"normal_enu": (0.0, 0.0, 1.0)})
    np.testing.assert_array_equal(flat.frame_enu[0], [1.0, 0.0, 0.0])  # a horizontal board: u east
    assert cfg.targets[0].frame_enu is not flat.frame_enu


CYLINDER = ROOT / "simulations" / "fields" / "dots_cylinder.yaml"


def test_a_standby_point_whose_beams_land_on_another_board_is_refused(write_field):
    """The centre board's standby point 15 m to its east (toward the east board) puts its heliostats'
    waiting beams on the east board; the shipped file keeps it 15 m below the board."""
    data = yaml.safe_load(CYLINDER.read_text())
    load_field_config(write_field(data))  # the shipped layout is valid
    data["targets"][1]["standby_offset_m"] = [-15.0, 0.0]
    with pytest.raises(ConfigError) as exc:
        load_field_config(write_field(data))
    msg = str(exc.value)
    assert "targets[1].standby_offset_m" in msg and "'TN'" in msg and "board of target 'TE'" in msg, msg


def test_a_board_in_front_of_another_is_refused_and_boards_meeting_edge_to_edge_are_not(write_field):
    """A board moved between the field and the centre board takes its heliostats' beams; two boards in
    one plane, one above the other and meeting at an edge (the Jülich tower's upper and lower targets),
    take none of each other's."""
    data = yaml.safe_load(CYLINDER.read_text())
    front = dict(data["targets"][0], center_enu_m=[0.0, 24.0, 95.0], normal_enu=data["targets"][1]["normal_enu"])
    data["targets"][0] = front
    with pytest.raises(ConfigError) as exc:
        load_field_config(write_field(data))
    assert "targets[1].center_enu_m" in str(exc.value) and "first" in str(exc.value), str(exc.value)
    data = yaml.safe_load(CYLINDER.read_text())
    tn = data["targets"][1]
    v = np.cross(tn["normal_enu"], np.cross([0.0, 0.0, 1.0], tn["normal_enu"]))
    v = v / np.linalg.norm(v)  # up the board
    # 2 cm farther from the field than TN, as surveyed boards are (the Jülich upper and lower targets): the beams
    # to TU's bottom edge graze TN's top edge
    w = np.asarray(tn["normal_enu"], dtype=float)
    above = dict(tn, id="TU", center_enu_m=(np.asarray(tn["center_enu_m"]) + 12.0 * v - 0.02 * w).round(6).tolist(),
                 standby_offset_m=[0.0, 15.0])
    data["targets"] = [data["targets"][0], tn, above, data["targets"][2]]
    data["cameras"].append(dict(data["cameras"][1], id="CU", target="TU"))
    data["heliostats"][0] = dict(data["heliostats"][0], target="TU")
    load_field_config(write_field(data))


def test_boards_without_standby_points_get_one_that_keeps_beams_off_the_other_boards(demo_data, write_field):
    """The demo's two boards stand side by side; without its stated standby point, T2's default one
    (beside it, toward T1) puts its waiting beams on T1 and the file is refused. ``clear_standby_points``
    (used by import-paint: PAINT has no standby points) puts it on the first side that clears."""
    from helicalib.config import clear_standby_points

    del demo_data["targets"][1]["standby_offset_m"]
    with pytest.raises(ConfigError) as exc:
        load_field_config(write_field(demo_data))
    assert "targets[1].standby_offset_m" in str(exc.value)
    cleared = clear_standby_points(demo_data)
    cfg = load_field_config(write_field(cleared, "cleared.yaml"))
    w = cfg.target("T2").size_m[0]
    default = [-(w / 2 + max(w / 2, 6.0)), 0.0]
    assert list(cfg.target("T2").standby_offset_m) not in ([], default)  # another side than the refused one
    assert cleared["targets"][0]["standby_offset_m"] == demo_data["targets"][0]["standby_offset_m"]  # stated: kept
    assert "standby_offset_m" not in demo_data["targets"][1]  # the input is not changed
