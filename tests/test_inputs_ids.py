"""Ids and names in a field config: heliostat, target and camera ids and drive names keep to a safe
alphabet and length (no markup, no path separators, no control characters), ``site.name`` is
printable text of bounded length; each refusal is one line naming the key path. Every id the
shipped fields, the simulated fields and PAINT use still passes."""

from __future__ import annotations

import pytest

from helicalib.config import parse_field_config
from helicalib.errors import ConfigError

from inputs_helpers import validate_problems

MAX_ID_LENGTH = 64  # docs/field-config.md

HOSTILE_IDS = ["[/]", "[link=http://evil.example]H3[/link]", "H<script>x</script>", "../escaped", "H 03", "H/03",
               "-H03", ".hidden", "Hé03", "H\u202e03", "H\t03", "", "x" * (MAX_ID_LENGTH + 1), "H" * 100_000]



@pytest.mark.parametrize("bad", HOSTILE_IDS, ids=lambda s: repr(s)[:30])
def test_a_hostile_heliostat_id_is_refused_in_one_short_line(tmp_path, demo_data, bad, capsys):
    demo_data["heliostats"][3]["id"] = bad
    problems = validate_problems(capsys, demo_data, tmp_path)
    assert len(problems) == 1 and problems[0].startswith("heliostats[3].id: ")
    assert len(problems[0]) < 200  # the 100 000-character id is not echoed


@pytest.mark.parametrize("where", ["targets", "cameras"])
def test_hostile_target_and_camera_ids_are_refused(tmp_path, demo_data, where, capsys):
    demo_data[where][1]["id"] = "[link=http://e.x]T2[/link]"
    problems = validate_problems(capsys, demo_data, tmp_path)
    assert problems[0].startswith(f"{where}[1].id: ") and "letters A-Z" in problems[0]


def test_a_hostile_drive_name_is_refused(tmp_path, demo_data, capsys):
    demo_data["drives"]["[/]"] = demo_data["drives"]["tr20"]
    problems = validate_problems(capsys, demo_data, tmp_path)
    assert problems == ["drives: '[/]': an id holds only the letters A-Z and a-z, digits, '.', '_' and '-', "
                        "and starts with a letter or digit"]


def test_a_hostile_id_in_a_heliostat_csv_names_its_row(tmp_path, demo_data, capsys):
    rows = ["id,e_m,n_m,u_m,drive,target"] + [
        f"{h['id']},{h['position_enu_m'][0]},{h['position_enu_m'][1]},{h['position_enu_m'][2]},{h['drive']},{h['target']}"
        for h in demo_data.pop("heliostats")]
    rows[3] = "[/]" + rows[3][5:]
    (tmp_path / "h.csv").write_text("\n".join(rows) + "\n")
    demo_data["heliostats_csv"] = "h.csv"
    problems = validate_problems(capsys, demo_data, tmp_path)
    assert problems == ["heliostats_csv(h.csv)[2].id: '[/]': an id holds only the letters A-Z and a-z, digits, "
                        "'.', '_' and '-', and starts with a letter or digit"]


@pytest.mark.parametrize("name, says", [
    ("Demo\x1b[31m plant", "control or format character U+001B"),
    ("Demo\u202eplant", "control or format character U+202E"),
    ("line\nbreak", "control or format character U+000A"),
    ("x" * 100_000, "a name of 100000 characters: at most 200"),
    ("   ", "expected a non-empty name"),
])
def test_site_name_is_printable_text_of_bounded_length(tmp_path, demo_data, name, says, capsys):
    demo_data["site"]["name"] = name
    assert validate_problems(capsys, demo_data, tmp_path) == [f"site.name: {says}" if says.startswith(("a name", "expected"))
                                                       else f"site.name: expected printable text, got the {says}"]


@pytest.mark.parametrize("name", ["[/]", "[link=http://evil.example]Plant[/link]", "Jülich solar tower (PAINT import)",
                                  "敦煌 100 MW"])
def test_site_name_may_hold_any_printable_text(demo_data, name):
    # brackets are text: the views print the name as text, never as markup
    demo_data["site"]["name"] = name
    assert parse_field_config(demo_data).site.name == name


@pytest.mark.parametrize("hid", ["AA39", "AA23", "H0001", "H00001", "T1", "solar_tower_juelich_upper",
                                 "multi_focus_tower", "paint_AA39", "h-1.2_b", "x" * MAX_ID_LENGTH])
def test_every_id_in_use_passes(demo_data, hid):
    demo_data["heliostats"][0]["id"] = hid
    demo_data["targets"][0]["id"] = hid
    for c in demo_data["cameras"]:
        c["target"] = hid if c["target"] == "T1" else c["target"]
    for h in demo_data["heliostats"]:
        h["target"] = hid if h["target"] == "T1" else h["target"]
    demo_data["cameras"][0]["id"] = hid
    cfg = parse_field_config(demo_data)
    assert cfg.heliostats[0].id == hid and cfg.target(hid).id == hid


def test_config_error_names_the_key_in_memory(demo_data):
    demo_data["heliostats"][0]["id"] = "[/]"
    with pytest.raises(ConfigError) as exc:
        parse_field_config(demo_data)
    assert exc.value.problems[0].startswith("heliostats[0].id: '[/]': ")
