"""Output folders: helicalib never deletes or overwrites what it did not create.

Every command that writes a folder (demo, simulate, report, export-paint, import-paint, sweep) or
files (sim-field) reads its inputs first, then accepts only a new or empty folder or one its own
earlier run marked; anything else (a folder of the user's, the working directory or a folder
holding it, the home folder, a file) is refused in one line and left as it was.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from helicalib.cli import main
from helicalib.errors import ConfigError
from helicalib.outdir import MARKER, check, prepare, written_by

ROOT = Path(__file__).resolve().parents[1]
FIELD = ROOT / "field_config" / "demo_north.yaml"
PAINT = ROOT / "tests" / "data" / "paint"
SWEEP = {"field": str(FIELD), "days": 0.01, "seeds": [1], "planners": ["gaps"], "heliostats": 1, "fidelity": "fast"}


def _one_error_line(capsys, argv, command: str) -> str:
    assert main([str(a) for a in argv]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().split("\n")
    assert len(lines) == 1, err
    assert lines[0].startswith(f"helicalib {command}: error: "), err
    return lines[0]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """A tiny simulated campaign (fast sensor, one heliostat, 0.05 plant days) with its report
    (``--report``): its database."""
    out = tmp_path_factory.mktemp("outputs") / "sim"
    assert main(["simulate", str(FIELD), "--fidelity", "fast", "--days", "0.05", "--heliostats", "H0001",
                 "--start", "2026-06-01T02:00:00Z", "--out", str(out), "--report", "--json"]) == 0
    assert written_by(out) == "simulate"
    return out / "helicalib.db"


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory) -> Path:
    import yaml

    path = tmp_path_factory.mktemp("sweepfile") / "sweep.yaml"
    path.write_text(yaml.safe_dump(SWEEP), encoding="utf-8")
    return path


def _argv(command: str, out, campaign: Path, sweep_file: Path) -> list:
    """The cheapest call of each command that writes a folder, with ``--out out``."""
    return {"demo": ["demo", FIELD, "--days", "0.01"],
            "simulate": ["simulate", FIELD, "--fidelity", "fast", "--days", "0.01", "--heliostats", "H0001"],
            "report": ["report", campaign, "--no-frames", "--jobs", "1"],
            "export-paint": ["export-paint", campaign, "--no-frames"],
            "import-paint": ["import-paint", PAINT],
            "sweep": ["sweep", sweep_file, "--workers", "1"]}[command] + ["--out", out]


COMMANDS = ("demo", "simulate", "report", "export-paint", "import-paint", "sweep")


# ------------------------------------------------------------------------------ the scenario
def test_demo_with_a_missing_field_leaves_the_folder_alone(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "notes").write_text("mine")
    line = _one_error_line(capsys, ["demo", "field_config/no_such.yaml", "--out", "p"], "demo")
    assert "no_such.yaml" in line and "not found" in line
    assert (tmp_path / "p" / "notes").read_text() == "mine"
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == ["notes"]


def test_demo_refuses_a_folder_that_is_not_its_output(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "notes").write_text("mine")
    line = _one_error_line(capsys, ["demo", FIELD, "--out", "p"], "demo")
    assert line == ("helicalib demo: error: --out p: folder exists and is not a helicalib demo output (it holds "
                    "notes); give an empty or new folder (or move this one aside: mv p p.old)")
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == ["notes"]


# ------------------------------------------------------------------------------ every command
@pytest.mark.parametrize("command", COMMANDS)
def test_a_folder_of_the_users_is_refused_and_kept(command, tmp_path, capsys, campaign, sweep_file):
    out = tmp_path / "mine"
    out.mkdir()
    for name in ("a.txt", "b.txt", "c.txt", "d.txt"):
        (out / name).write_text(name)
    line = _one_error_line(capsys, _argv(command, out, campaign, sweep_file), command)
    assert line == (f"helicalib {command}: error: --out {out}: folder exists and is not a helicalib {command} output "
                    f"(it holds a.txt, b.txt, c.txt and 1 more); give an empty or new folder (or move this one aside: "
                    f"mv {out} {out}.old)")
    assert sorted(p.name for p in out.iterdir()) == ["a.txt", "b.txt", "c.txt", "d.txt"]


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("given", [".", "..", "/"])
def test_the_working_directory_and_its_parents_are_refused(command, given, tmp_path, capsys, campaign, sweep_file,
                                                           monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    (work / MARKER).write_text(f"{command}\n")      # even a folder marked as the command's own
    (work / "keep").write_text("mine")
    monkeypatch.chdir(work)
    line = _one_error_line(capsys, _argv(command, given, campaign, sweep_file), command)
    assert line == (f"helicalib {command}: error: --out {given}: is the working directory or holds it; give an empty "
                    "or new folder")
    assert (work / "keep").read_text() == "mine"


@pytest.mark.parametrize("command", COMMANDS)
def test_the_home_folder_is_refused(command, tmp_path, capsys, campaign, sweep_file, monkeypatch):
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    line = _one_error_line(capsys, _argv(command, home, campaign, sweep_file), command)
    assert line.endswith(f"--out {home}: is the home folder; give an empty or new folder")
    assert list(home.iterdir()) == []


@pytest.mark.parametrize("command", COMMANDS)
def test_a_file_given_as_out_is_refused_and_kept(command, tmp_path, capsys, campaign, sweep_file):
    file = tmp_path / "notes.txt"
    file.write_text("mine")
    line = _one_error_line(capsys, _argv(command, file, campaign, sweep_file), command)
    assert line.endswith(f"--out {file}: is a file, not a folder; give an empty or new folder")
    assert file.read_text() == "mine"
    below = file / "sub"
    line = _one_error_line(capsys, _argv(command, below, campaign, sweep_file), command)
    assert line.endswith(f"--out {below}: {file} is a file, not a folder; give an empty or new folder")


def test_report_onto_a_system_file_is_one_line(campaign, capsys):
    if not Path("/etc/passwd").is_file():
        pytest.skip("no /etc/passwd here")
    line = _one_error_line(capsys, ["report", campaign, "--out", "/etc/passwd"], "report")
    assert line == "helicalib report: error: --out /etc/passwd: is a file, not a folder; give an empty or new folder"


def test_another_commands_output_is_refused(tmp_path, capsys, campaign):
    out = tmp_path / "rep"
    prepare(out, "report")
    (out / "index.html").write_text("<html>")
    line = _one_error_line(capsys, ["export-paint", campaign, "--out", out], "export-paint")
    assert line.endswith(f"--out {out}: folder is a helicalib report output, not a export-paint output; give an "
                         "empty or new folder")
    assert (out / "index.html").is_file()


# ------------------------------------------------------------------------------ previous outputs
def test_a_previous_report_is_replaced(tmp_path, capsys, campaign):
    out = tmp_path / "rep"
    prepare(out, "report")
    (out / "heliostats").mkdir()
    (out / "heliostats" / "H9999.html").write_text("a heliostat of an older report")
    assert main(["report", str(campaign), "--out", str(out), "--no-frames", "--jobs", "1"]) == 0
    assert not (out / "heliostats" / "H9999.html").exists()
    assert (out / "index.html").is_file() and (out / "heliostats" / "H0001.html").is_file()
    assert written_by(out) == "report"


def test_export_and_import_replace_their_previous_output(tmp_path, capsys, campaign):
    out = tmp_path / "paint"
    prepare(out, "export-paint")
    (out / "stale.json").write_text("{}")
    assert main(["export-paint", str(campaign), "--out", str(out), "--no-frames", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["records"] > 0
    assert not (out / "stale.json").exists() and (out / "catalog.json").is_file()
    back = tmp_path / "back"
    prepare(back, "import-paint")
    (back / "stale.csv").write_text("x")
    assert main(["import-paint", str(out), "--out", str(back)]) == 0
    assert not (back / "stale.csv").exists() and (back / "field.yaml").is_file()
    assert written_by(back) == "import-paint"


def test_the_demos_report_folder_can_be_rebuilt_by_report(tmp_path, capsys, campaign):
    """simulate --report marks OUT/report as a report, so the demo's suggested rebuild is accepted."""
    import shutil

    out = tmp_path / "sim"
    shutil.copytree(campaign.parent, out)                      # the fixture's simulate --report output
    assert written_by(out) == "simulate" and written_by(out / "report") == "report"
    (out / "report" / "heliostats" / "H9999.html").write_text("a heliostat of an older report")
    assert main(["report", str(out / "helicalib.db"), "--out", str(out / "report"), "--no-frames", "--jobs", "1"]) == 0
    assert not (out / "report" / "heliostats" / "H9999.html").exists()
    # and simulate accepts its own folder again (the campaign resumes or a new one starts; nothing is cleared)
    assert check(out, "simulate") == out
    assert prepare(out, "simulate") == out
    assert (out / "report" / "index.html").is_file() and (out / "helicalib.db").is_file()


def test_prepare_replaces_only_its_own_folder_and_never_follows_links(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "precious").write_text("mine")
    out = prepare(tmp_path / "demo_out", "demo")
    (out / "images").mkdir()
    (out / "images" / "f.png").write_bytes(b"png")
    (out / "link").symlink_to(outside, target_is_directory=True)
    prepare(out, "demo", replace=True)
    assert sorted(p.name for p in out.iterdir()) == [MARKER]
    assert (outside / "precious").read_text() == "mine"
    assert prepare(tmp_path / "empty", "demo") == tmp_path / "empty"     # a new folder is made and marked
    assert written_by(tmp_path / "empty") == "demo"


# ------------------------------------------------------------------------------ sweep runs, sim-field
def test_a_sweep_run_folder_that_is_not_a_runs_is_never_cleared(tmp_path):
    from helicalib.sweep.spec import load_sweep
    from helicalib.sweep.task import RUN_OUTPUT, RunFailed, finished_record, run_one
    import yaml

    file = tmp_path / "s.yaml"
    file.write_text(yaml.safe_dump(SWEEP), encoding="utf-8")
    sweep = load_sweep(file)
    run = sweep.runs(tmp_path / "o")[0]
    folder = Path(run.run_dir)
    folder.mkdir(parents=True)
    (folder / "notes").write_text("mine")
    with pytest.raises(RunFailed) as exc:
        run_one(run, sweep.cfg, sweep.scenarios[run.scenario])
    assert f"run folder {folder}: folder exists and is not a helicalib sweep run output (it holds notes)" in str(exc.value)
    assert (folder / "notes").read_text() == "mine"
    (folder / "notes").unlink()
    assert prepare(folder, RUN_OUTPUT, option="run folder") == folder   # an empty folder is a run's (marked)
    (folder / "stale").write_text("an interrupted run's file")
    record = run_one(run, sweep.cfg, sweep.scenarios[run.scenario])     # its own folder starts afresh
    assert not (folder / "stale").exists()
    assert written_by(folder) == RUN_OUTPUT
    assert finished_record(run) == record and record["summary"]["heliostats"] == 1


def test_sim_field_overwrites_only_what_it_wrote(tmp_path, capsys):
    mine = tmp_path / "field.yaml"
    mine.write_text("site: {}\n")
    line = _one_error_line(capsys, ["sim-field", "--n", "3", "--site", "35,10", "--out", mine], "sim-field")
    assert line.endswith(f"--out {mine}: file exists and was not written by helicalib sim-field; give a new file name")
    assert mine.read_text() == "site: {}\n"
    csv = tmp_path / "gen.csv"
    csv.write_text("id,e_m\nmine,1\n")
    line = _one_error_line(capsys, ["sim-field", "--n", "3", "--site", "35,10", "--out", tmp_path / "gen.yaml"],
                           "sim-field")
    assert f"{csv} exists and was not written by helicalib sim-field" in line
    assert csv.read_text() == "id,e_m\nmine,1\n"
    out = tmp_path / "sim.yaml"
    assert main(["sim-field", "--n", "3", "--site", "35,10", "--out", str(out)]) == 0
    assert main(["sim-field", "--n", "4", "--site", "35,10", "--out", str(out)]) == 0     # its own: overwritten
    assert len((tmp_path / "sim.csv").read_text().strip().splitlines()) == 5


# ------------------------------------------------------------------------------ inputs inside the folder
INSIDE = ("report-db", "report-field", "report-images", "export-paint-db", "export-paint-field", "import-paint",
          "demo", "sweep")


@pytest.mark.parametrize("case", INSIDE)
def test_a_folder_holding_the_commands_input_is_refused_before_it_is_cleared(case, tmp_path, capsys, campaign):
    """A folder the command would replace (or, for sweep, whose run folders it would clear) may not hold
    what the command reads: it would be deleted first and the command would fail on a missing input."""
    import shutil

    import yaml

    command = case.split("-db")[0].split("-field")[0].split("-images")[0]
    out = prepare(tmp_path / "rv", command)
    if case.endswith("-db"):
        given = out / "my.db"
        shutil.copy(campaign, given)
        argv = [command, given, "--no-frames", "--out", out]
    elif case.endswith("-field"):
        given = out / "field.yaml"
        shutil.copy(FIELD, given)
        argv = [command, campaign, "--field", given, "--no-frames", "--out", out]
    elif case == "report-images":
        given = out / "images"
        given.mkdir()
        argv = ["report", campaign, "--images", given, "--no-frames", "--out", out]
    elif case == "import-paint":
        given = out / "paint"
        shutil.copytree(PAINT, given)
        argv = ["import-paint", given, "--out", out]
    elif case == "demo":
        given = out / "field.yaml"
        shutil.copy(FIELD, given)
        argv = ["demo", given, "--days", "0.01", "--out", out]
    else:
        given = out / "cells" / "s.yaml"
        given.parent.mkdir()
        given.write_text(yaml.safe_dump(SWEEP), encoding="utf-8")
        argv = ["sweep", given, "--workers", "1", "--out", out]
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    line = _one_error_line(capsys, argv, command)
    assert line == (f"helicalib {command}: error: --out {out}: holds {given}, an input of this command, which clearing "
                    "the folder would delete; give a folder that holds none of the inputs")
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before


# ------------------------------------------------------------------------------ demo checks before it replaces
def test_demo_checks_what_simulate_checks_before_replacing_its_folder(tmp_path, capsys):
    """A field without cameras (a PAINT import) passes the field config's own checks but not simulate's:
    the previous demo's output stays as it was."""
    imported = tmp_path / "imported"
    assert main(["import-paint", str(PAINT), "--out", str(imported), "--json"]) == 0
    capsys.readouterr()
    out = prepare(tmp_path / "rv_demo", "demo")
    (out / "summary.json").write_text('{"visits": 3}')
    line = _one_error_line(capsys, ["demo", imported / "field.yaml", "--out", out], "demo")
    assert "cameras: none given" in line
    assert (out / "summary.json").read_text() == '{"visits": 3}'
    assert written_by(out) == "demo"


def test_simulate_refuses_a_report_folder_of_the_users_before_the_campaign(tmp_path, capsys):
    out = prepare(tmp_path / "sim", "simulate")
    (out / "report").mkdir()
    (out / "report" / "notes").write_text("mine")
    line = _one_error_line(capsys, ["simulate", FIELD, "--fidelity", "fast", "--days", "0.01", "--heliostats", "H0001",
                                    "--out", out, "--report"], "simulate")
    assert line == (f"helicalib simulate: error: --out {out / 'report'}: folder exists and is not a helicalib report "
                    f"output (it holds notes); give an empty or new folder (or move this one aside: mv {out / 'report'} "
                    f"{out / 'report'}.old)")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "report"]  # nothing run, nothing written
    assert (out / "report" / "notes").read_text() == "mine"
    field = out / "report" / "field.yaml"                               # nor one holding simulate's input
    (out / "report" / "notes").unlink()
    field.write_text(FIELD.read_text())
    line = _one_error_line(capsys, ["simulate", field, "--fidelity", "fast", "--days", "0.01", "--heliostats", "H0001",
                                    "--out", out, "--report"], "simulate")
    assert line.endswith(f"--out {out / 'report'}: holds {field}, an input of this command, which clearing the folder "
                         "would delete; give a folder that holds none of the inputs")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "report"]


# ------------------------------------------------------------------------------ folders written before the marker
def _legacy_campaign(tmp_path, campaign: Path, name: str) -> Path:
    """A demo output as helicalib wrote it before the marker: the campaign's files and a report folder."""
    import shutil

    out = tmp_path / name
    shutil.copytree(campaign.parent, out, ignore=shutil.ignore_patterns("report"))
    (out / MARKER).unlink()
    report = out / "report"
    (report / "plots").mkdir(parents=True)
    (report / "heliostats").mkdir()
    (report / "index.html").write_text("<!DOCTYPE html>\n<html></html>\n")
    (report / "report.json").write_text(json.dumps({"status": {}, "summary": {"visits": 1}}))
    return out


def test_a_demo_output_written_before_the_marker_is_replaced(tmp_path, campaign):
    out = _legacy_campaign(tmp_path, campaign, "demo_out")
    assert check(out / "report", "report") == out / "report"
    prepare(out, "demo", replace=True)
    assert sorted(p.name for p in out.iterdir()) == [MARKER] and written_by(out) == "demo"


def test_a_simulate_output_written_before_the_marker_is_resumed(tmp_path, capsys, campaign):
    import shutil

    sim = _legacy_campaign(tmp_path, campaign, "sim")
    shutil.rmtree(sim / "report")
    before = sorted(p.relative_to(sim) for p in sim.rglob("*"))
    # not a demo's (an old demo always wrote its report): refused, untouched
    line = _one_error_line(capsys, ["demo", FIELD, "--days", "0.01", "--out", sim], "demo")
    assert "is not a helicalib demo output" in line
    assert prepare(sim, "simulate") == sim and written_by(sim) == "simulate"   # resumed: nothing cleared
    assert sorted(p.relative_to(sim) for p in sim.rglob("*")) == sorted(before + [Path(MARKER)])


def test_an_old_sweep_and_its_run_folders_are_taken_up(tmp_path):
    import yaml

    from helicalib.sweep.spec import load_sweep
    from helicalib.sweep.task import RUN_OUTPUT

    out = tmp_path / "sweep_out"
    file = tmp_path / "s.yaml"
    file.write_text(yaml.safe_dump(SWEEP), encoding="utf-8")
    run = load_sweep(file).runs(out)[0]
    folder = Path(run.run_dir)
    folder.mkdir(parents=True)
    (out / "sweep.yaml").write_text(file.read_text())
    (out / "results.csv").write_text("cell,seed\n")
    (out / "summary.json").write_text(json.dumps({"cells": {}, "runs": {}}))
    assert check(out, "sweep") == out
    assert prepare(out, "sweep") == out and written_by(out) == "sweep"
    assert (out / "results.csv").read_text() == "cell,seed\n"
    # an interrupted run of then: its log and database, no result; taken up only with a real database
    (folder / "run.log").write_text("")
    (folder / "helicalib.db").write_bytes(b"not a database")
    with pytest.raises(ConfigError, match="not a helicalib sweep run output"):
        prepare(folder, RUN_OUTPUT, replace=True, option="run folder")
    (folder / "helicalib.db").unlink()
    _real_database(folder / "helicalib.db")
    prepare(folder, RUN_OUTPUT, replace=True, option="run folder")
    assert sorted(p.name for p in folder.iterdir()) == [MARKER]


def _real_database(path: Path) -> None:
    from helicalib.store.sqlite import Store

    Store.open(path, path.parent / "images").close()


@pytest.mark.parametrize("extra", ["notes.txt", "no summary", "not a database", "no report", "a link"])
def test_only_the_old_layout_itself_is_taken_up(extra, tmp_path, capsys, campaign):
    out = _legacy_campaign(tmp_path, campaign, "demo_out")
    if extra == "notes.txt":
        (out / "notes.txt").write_text("mine")
    elif extra == "no summary":                     # a plant's database and frames: never a demo's
        (out / "summary.json").unlink()
    elif extra == "not a database":
        (out / "helicalib.db").write_text("SQLite format 3 is what this file says, not what it is")
    elif extra == "no report":
        __import__("shutil").rmtree(out / "report")
    else:
        (out / "images").mkdir(exist_ok=True)
        (out / "images" / "c1").symlink_to(tmp_path, target_is_directory=True)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    line = _one_error_line(capsys, ["demo", FIELD, "--days", "0.01", "--out", out], "demo")
    assert line.startswith(f"helicalib demo: error: --out {out}: folder exists and is not a helicalib demo output (it "
                           "holds ")
    assert line.endswith(f"; give an empty or new folder (or move this one aside: mv {out} {out}.old)")
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before


def test_an_import_written_before_the_marker_is_replaced(tmp_path, capsys):
    out = tmp_path / "imported"
    assert main(["import-paint", str(PAINT), "--out", str(out), "--json"]) == 0
    (out / MARKER).unlink()
    assert check(out, "import-paint") == out
    (out / "notes").write_text("mine")
    with pytest.raises(ConfigError, match="not a helicalib import-paint output"):
        check(out, "import-paint")
