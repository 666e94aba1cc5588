"""Helpers of the tests of inputs (field configs, PAINT records): ``validate``'s problem lines."""

from __future__ import annotations

from pathlib import Path

import yaml

from helicalib.cli import main


def validate_problems(capsys, data: dict, tmp_path: Path) -> list[str]:
    """Write ``data`` as a field config, run ``helicalib validate`` on it (expecting exit 1, no
    traceback, a closing count line) and return its problem lines without the file name."""
    path = tmp_path / "f.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    assert main(["validate", str(path), "--no-sweep"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().split("\n")
    assert lines[-1] == f"{path}: {len(lines) - 1} problem(s); not valid"
    return [ln[len(f"{path}: "):] for ln in lines[:-1]]
