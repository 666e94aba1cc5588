"""The package's layers: the campaign cannot tell a simulated plant from a real one, and devices
know nothing of flux. Read from the source (every import statement, top level or inside a function)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "helicalib"


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


@pytest.mark.parametrize("package, forbidden", [("campaign", "helicalib.sim"), ("devices", "helicalib.flux"),
                                                ("devices", "helicalib.sim"), ("devices", "helicalib.campaign")])
def test_a_layer_imports_nothing_of_the_one_it_must_not_know(package, forbidden):
    files = sorted((SRC / package).glob("*.py"))
    assert files
    bad = {f.name: sorted(m for m in _imports(f) if m == forbidden or m.startswith(forbidden + "."))
           for f in files}
    assert not {k: v for k, v in bad.items() if v}, bad


def test_the_check_sees_an_import_inside_a_function(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from helicalib.sim.plant import SimulatedPlant\n    return SimulatedPlant\n")
    assert "helicalib.sim.plant" in _imports(f)
