"""docs/register-maps.md shows the shipped maps exactly as the map files say (generated tables)."""

from __future__ import annotations

from pathlib import Path

from helicalib.devices.regdoc import BLOCK, markdown, render_doc
from helicalib.devices.regmap import load_register_map, shipped_maps

DOC = Path(__file__).resolve().parents[1] / "docs" / "register-maps.md"


def test_the_doc_holds_the_generated_table_of_every_shipped_map():
    text = DOC.read_text(encoding="utf-8")
    blocks = {m.group("name"): m.group("body") for m in BLOCK.finditer(text)}
    assert sorted(blocks) == shipped_maps()
    for name, body in blocks.items():
        assert body == markdown(load_register_map(name)), f"{name}: run python -m helicalib.devices.regdoc {DOC}"
    assert render_doc(text) == text


def test_the_table_names_every_quantity_with_its_registers():
    m = load_register_map("scs-b")
    table = markdown(m)
    rows = [line for line in table.splitlines() if line.startswith("| `")]
    assert len(rows) == len(m.q)
    assert "| `plant.clock.time` | input | 0–2 | u32, low word first + u16 × 0.001 |  | s |" in table
    assert "| `heliostats.command.strokes_mm[0]` | holding | +1–2 | i32, low word first | × 0.01 | mm |" in table
    assert "bit 0 tracking, bit 1 moving, bit 2 holding" in table and "handshake `execute`" in table
    edited = table.replace("+1–2", "+1–3")
    assert render_doc(f"<!-- regmap scs-b -->\n{edited}<!-- /regmap -->") != f"<!-- regmap scs-b -->\n{edited}<!-- /regmap -->"
