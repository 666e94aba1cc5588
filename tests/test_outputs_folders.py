"""Output folders (:mod:`helicalib.outdir`), fast cases without a campaign: the marker survives a
clear cut short, inputs inside a folder that would be cleared are refused, folders written before
the marker existed are recognised narrowly, and paths holding rich markup are printed as text."""

from __future__ import annotations

from pathlib import Path

import pytest

from helicalib import outdir
from helicalib.errors import StorageError
from helicalib.outdir import MARKER, clear, prepare, written_by


# ------------------------------------------------------------------------------ the marker
def test_clear_keeps_the_marker(tmp_path):
    out = prepare(tmp_path / "o", "report")
    for name in ("a", "b", "z"):
        (out / name).write_text(name)
    (out / "plots").mkdir()
    (out / "plots" / "p.png").write_bytes(b"png")
    clear(out)
    assert sorted(p.name for p in out.iterdir()) == [MARKER]
    assert written_by(out) == "report"


def test_a_clear_cut_short_leaves_a_folder_the_command_accepts(tmp_path, monkeypatch):
    out = prepare(tmp_path / "o", "report")
    for k in range(20):
        (out / f"d{k:02d}").mkdir()
    def failing_rmtree(path, *a, **k):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(outdir.shutil, "rmtree", failing_rmtree)
    with pytest.raises(StorageError):
        prepare(out, "report", replace=True)
    assert written_by(out) == "report"
    monkeypatch.undo()
    assert prepare(out, "report", replace=True) == out
    assert sorted(p.name for p in out.iterdir()) == [MARKER]
