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


# ------------------------------------------------------------------------------ paths are text, not markup
ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"


def test_demo_prints_a_path_holding_markup_as_text(tmp_path, capsys, monkeypatch):
    """demo's lines name the field and the folder as given; the campaign itself is replaced by one that
    writes a summary (the lines around it are what is tested, and a demo takes tens of seconds)."""
    import json
    import shutil

    from helicalib.cli import main
    from helicalib.commands import simulate

    ran = []

    def campaign(args, inputs, out):
        ran.append(out)
        (out / "summary.json").write_text(json.dumps({"visits": 1}))
        return 0

    monkeypatch.setattr(simulate, "run_campaign", campaign)
    field = tmp_path / "f[/]" / "[bold]x.yaml"
    field.parent.mkdir(parents=True)
    shutil.copy(FIELD, field)
    out = tmp_path / "o[/]"
    assert main(["demo", str(field), "--days", "0.01", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert ran == [out]
    assert f"campaign on {field}, against" in err
    assert f"goes to {out / 'helicalib.db'}" in err
    assert f"report: {out / 'report' / 'index.html'}" in err
    assert f"--out {out / 'report'}" in err


def test_progress_bar_prints_a_description_holding_markup_as_text():
    import io

    from helicalib.commands._progress import ProgressReporter

    stream = io.StringIO()
    with ProgressReporter("simulate", 10, stream=stream, terminal=True) as bar:
        bar.update(1, "writing o[/]x [bold]b")
    assert "writing o[/]x [bold]b" in stream.getvalue()
