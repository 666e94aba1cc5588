"""A field without cameras (what ``import-paint`` writes) is refused in one line by every command
that measures, before anything is started or written: it can be fitted, reported and exported."""

from __future__ import annotations

import pytest

from helicalib.cli import main


@pytest.mark.parametrize("argv", [["simulate", "{field}", "--days", "0.01", "--fidelity", "fast", "--out", "{out}"],
                                  ["sim-plant", "{field}", "--port", "0", "--camera-port", "0"],
                                  ["run", "{field}", "--json"],
                                  ["check", "{field}", "--heliostats", "H0001", "--json"],
                                  ["operate", "{field}", "--json"]])
def test_a_field_without_cameras_is_refused_by_commands_that_measure(argv, demo_data, write_field, tmp_path, capsys):
    demo_data["cameras"] = []
    field = write_field(demo_data)
    out = tmp_path / "out"
    assert main([a.format(field=field, out=out) for a in argv]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "cameras: none given" in err[0] and "Traceback" not in captured.err, captured.err
    assert not out.exists()
