"""``helicalib validate`` names how the SCS is reached and refuses a broken register map in one line
per problem naming the map file and the key."""

from __future__ import annotations

import json
import shutil

from conftest import ROOT

from helicalib.cli import main


def test_validate_names_protocol_and_map(capsys):
    for name, expect in (("demo_north", ("modbus", "plant-interface-1")), ("scs_b_demo", ("modbus", "scs-b"))):
        assert main(["validate", str(ROOT / "field_config" / f"{name}.yaml"), "--no-sweep", "--json"]) == 0
        plant = json.loads(capsys.readouterr().out)["plant"]
        assert (plant["protocol"], plant["register_map"]) == expect
    assert main(["validate", str(ROOT / "field_config" / "opcua_demo.yaml"), "--no-sweep", "--json"]) == 0
    plant = json.loads(capsys.readouterr().out)["plant"]
    assert plant["protocol"] == "opcua" and plant["scs"].startswith("opc.tcp://127.0.0.1:")


def test_a_broken_register_map_is_named(tmp_path, capsys):
    cfg = tmp_path / "field.yaml"
    text = (ROOT / "field_config" / "scs_b_demo.yaml").read_text()
    cfg.write_text(text.replace("register_map: scs-b", "register_map: ours.yaml", 1))
    shutil.copy(ROOT / "src" / "helicalib" / "devices" / "maps" / "scs-b.yaml", tmp_path / "ours.yaml")
    assert main(["validate", str(cfg), "--no-sweep"]) == 0
    broken = (tmp_path / "ours.yaml").read_text().replace("type: i32", "type: i33", 1)
    (tmp_path / "ours.yaml").write_text(broken)
    assert main(["validate", str(cfg), "--no-sweep"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"{tmp_path / 'ours.yaml'}: ") and "heliostats.command.strokes_mm[0].type: " in err[0]
    assert err[-1] == f"{cfg}: 1 problem(s); not valid"
