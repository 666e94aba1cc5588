"""Output folders: helicalib never deletes or overwrites what it did not create.

Every command that writes a folder of results (``demo``, ``simulate``, ``report``, ``export-paint``,
``import-paint``, ``sweep``) asks :func:`prepare` for it after its inputs have been read and checked.
A folder is accepted when it does not exist yet, is empty, or carries the marker file
:data:`MARKER` that the same command wrote when it created the folder (its first line is the
command's name). Anything else is refused with one line, before a file is touched::

    --out p: folder exists and is not a helicalib demo output (it holds notes); give an empty or new folder (or move this one aside: mv p p.old)

So are folders no command may ever own: the working directory and any folder that holds it (``.``,
``..``, ``/``), the home folder, and a path that is a file. With ``replace=True`` the folder's
contents go (a fresh output: ``demo``, ``report``, ``export-paint``, ``import-paint``); without,
they stay (``simulate`` resumes its campaign, ``sweep`` skips its finished runs). A folder that holds
one of the command's own inputs (``report --out d d/my.db``) is refused too, before it is cleared.

A folder an older helicalib wrote, before the marker, is taken up when it holds exactly what the
command wrote then and nothing else (:data:`LEGACY`, :func:`is_legacy_output`).

:func:`check_file_output` is the same rule for a command that writes files rather than a folder
(``sim-field --out FIELD.yaml``): a file is overwritten only when the same command wrote it.
"""

from __future__ import annotations

import os
import shlex
import shutil
from collections.abc import Iterable
from pathlib import Path

from helicalib.errors import ConfigError, StorageError

MARKER = ".helicalib-output"
"""The file that makes a folder a helicalib output; its first line names the command that wrote it."""
ADVICE = "give an empty or new folder"
SHOWN = 3
"""Entries of a refused folder named in the error."""


def prepare(path: str | Path, command: str, *, replace: bool = False, option: str = "--out",
            advice: str = ADVICE, inputs: Iterable = ()) -> Path:
    """Make ``path`` the output folder of ``command`` (module docstring) and return it.

    Parameters
    ----------
    path : str or Path
        The folder as the user gave it (named so in errors).
    command : str
        The helicalib command writing it (``demo``, ``report``...): the marker's content.
    replace : bool
        Remove the folder's contents first (only ever a folder of the same command's output).
    option : str
        The option that named the folder, for the error lines.
    advice : str
        What the error lines tell the user to do.
    inputs : iterable of str or Path
        The files and folders the command reads (None skipped): refused when one is inside the
        folder (:func:`refuse_inputs`), where ``replace`` would delete it before it is read.

    Raises
    ------
    ConfigError
        The folder may not receive this output (one line: which folder, why, what to give).
    StorageError
        The folder cannot be created or cleared (permissions, a full disk).
    """
    folder = check(path, command, option=option, advice=advice, inputs=inputs)
    try:
        if replace and folder.is_dir():
            clear(folder)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / MARKER).write_text(f"{command}\nwritten by helicalib {command}; helicalib {command} may replace "
                                     "everything in this folder\n", encoding="utf-8")
    except OSError as err:
        raise StorageError(f"{option} {path}: cannot write the folder ({err.strerror or err})") from None
    return folder


def check(path: str | Path, command: str, *, option: str = "--out", advice: str = ADVICE,
          inputs: Iterable = ()) -> Path:
    """Refuse ``path`` as ``command``'s output folder unless it is new, empty or marked as its output,
    and when it holds one of ``inputs`` (:func:`refuse_inputs`); touches nothing. Returns the path."""
    folder = Path(path).expanduser()
    _refuse_special(folder, path, option, advice)
    if folder.is_file() or (folder.exists() and not folder.is_dir()):
        raise ConfigError(f"{option} {path}: is a file, not a folder; {advice}")
    if not folder.exists():
        _check_parent(folder, path, option, advice)
        return folder
    try:
        entries = sorted(os.listdir(folder))
    except OSError as err:
        raise StorageError(f"{option} {path}: cannot read the folder ({err.strerror or err})") from None
    refuse_inputs(folder, inputs, path, option)
    owner = written_by(folder)
    if not entries or owner == command or (owner is None and is_legacy_output(folder, command)):
        return folder
    if owner is not None:
        raise ConfigError(f"{option} {path}: folder is a helicalib {owner} output, not a {command} output; "
                          f"{advice}")
    shown = ", ".join(entries[:SHOWN]) + (f" and {len(entries) - SHOWN} more" if len(entries) > SHOWN else "")
    aside = f" (or move this one aside: mv {shlex.quote(str(path))} {shlex.quote(str(path) + '.old')})" \
        if advice == ADVICE else ""
    raise ConfigError(f"{option} {path}: folder exists and is not a helicalib {command} output (it holds {shown}); "
                      f"{advice}{aside}")


# ---------------------------------------------------------------------------- folders written before the marker
def is_legacy_output(folder: Path, command: str) -> bool:
    """Whether ``folder`` (unmarked) holds what ``command`` wrote before helicalib marked its output
    folders (2026-11-28) and nothing else: :data:`LEGACY` names, per command, the entries required and
    the files and folders allowed, each with a check of its contents (a campaign database must be a
    helicalib SQLite database, a summary a JSON object with the summary's keys...). Such a folder is
    accepted as the command's own and marked by :func:`prepare`; anything else is still refused."""
    layout = LEGACY.get(command)
    if layout is None:
        return False
    required, files, folders = layout
    try:
        entries = list(os.scandir(folder))
        if not required <= {e.name for e in entries}:
            return False
        for e in entries:
            if e.is_symlink():
                return False
            allowed = folders if e.is_dir() else files if e.is_file() else {}
            if e.name not in allowed or not allowed[e.name](Path(e.path)):
                return False
        return True
    except (OSError, ValueError, UnicodeDecodeError):
        return False


def _any(path: Path) -> bool:
    return True


def _campaign_database(path: Path) -> bool:
    """A helicalib SQLite database: the file header, the schema's tables and a version row."""
    import sqlite3

    with open(path, "rb") as f:
        if f.read(16) != b"SQLite format 3\x00":
            return False
    try:
        conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=1.0)
    except sqlite3.Error:
        return False
    try:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if not {"schema_version", "campaigns", "visits", "observations"} <= tables:
            return False
        version = conn.execute("SELECT version FROM schema_version").fetchone()
        return version is not None and type(version[0]) is int and version[0] >= 1
    except sqlite3.Error:
        return False
    finally:
        conn.close()


def _json_object(*keys: str):
    """A JSON file holding an object with ``keys``."""
    def valid(path: Path) -> bool:
        import json

        data = json.loads(path.read_text(encoding="utf-8"))
        return isinstance(data, dict) and all(k in data for k in keys)
    return valid


def _yaml_mapping(*keys: str):
    """A YAML file holding a mapping with ``keys``."""
    def valid(path: Path) -> bool:
        import yaml

        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8-sig"))
        except yaml.YAMLError:
            return False
        return isinstance(data, dict) and all(k in data for k in keys)
    return valid


def _first_line(prefix: str):
    """A text file whose first line begins with ``prefix``."""
    def valid(path: Path) -> bool:
        with open(path, encoding="utf-8") as f:
            return f.readline().startswith(prefix)
    return valid


def _frames(path: Path) -> bool:
    """A campaign database's frames folder: only ``c<campaign id>`` folders in it."""
    return all(e.is_dir(follow_symlinks=False) and e.name[:1] == "c" and e.name[1:].isdigit()
               for e in os.scandir(path))


def _folders(path: Path) -> bool:
    """Folders only (a sweep's cells; each run folder is checked when its run starts)."""
    return all(e.is_dir(follow_symlinks=False) for e in os.scandir(path))


def _report(path: Path) -> bool:
    return written_by(path) == "report" or is_legacy_output(path, "report")


_DATABASE = {"helicalib.db": _campaign_database, "helicalib.db-wal": _any, "helicalib.db-shm": _any,
             "helicalib.db-journal": _any, "helicalib.db.lock": _any}
_CAMPAIGN_FILES = {**_DATABASE, "summary.json": _json_object("visits", "heliostats"), "observations.csv": _any}
LEGACY = {
    "demo": ({"helicalib.db", "summary.json", "observations.csv", "report"}, _CAMPAIGN_FILES,
             {"images": _frames, "report": _report}),
    "simulate": ({"helicalib.db", "summary.json"}, _CAMPAIGN_FILES, {"images": _frames, "report": _report}),
    "report": ({"index.html", "report.json"},
               {"index.html": _first_line("<!"), "report.json": _json_object("summary", "status")},
               {"plots": _any, "heliostats": _any}),
    "import-paint": ({"field.yaml", "observations.csv"},
                     {"field.yaml": _any, "observations.csv": _first_line("# helicalib import-paint from ")}, {}),
    "sweep": ({"sweep.yaml", "cells"},
              {"sweep.yaml": _yaml_mapping("field", "seeds"), "results.csv": _any, "results.parquet": _any,
               "summary.json": _json_object("cells", "runs"), "failures.txt": _any},
              {"cells": _folders}),
    "sweep run": ({"run.log", "helicalib.db"},
                  {**_DATABASE, "observations.csv": _any, "run.log": _any, "result.json": _any,
                   "result.json.tmp": _any},
                  {"images": _frames}),
}
"""Per command, the folders it wrote before the marker (:func:`is_legacy_output`): (entries required,
{file allowed: check}, {folder allowed: check}). Nothing else may be in such a folder."""



def refuse_inputs(folder: str | Path, inputs: Iterable, given, option: str = "--out") -> None:
    """Refuse ``folder`` in one line when one of ``inputs`` (paths a command reads; None skipped) is the
    folder or inside it, links resolved: clearing the folder would delete the input before it is read."""
    try:
        real = Path(folder).expanduser().resolve()
    except (OSError, RuntimeError):
        return                                    # check() says what is wrong with the folder itself
    for item in inputs:
        if item is None:
            continue
        try:
            where = Path(item).expanduser().resolve()
        except (OSError, RuntimeError):
            continue                              # the command's own checks name an unreadable input
        if where.is_relative_to(real):
            raise ConfigError(f"{option} {given}: holds {item}, an input of this command, which clearing the "
                              "folder would delete; give a folder that holds none of the inputs")


def written_by(folder: str | Path) -> str | None:
    """The command named by ``folder``'s marker file, or None (no marker, unreadable)."""
    marker = Path(folder) / MARKER
    try:
        if marker.is_symlink() or not marker.is_file():
            return None
        first = marker.read_text(encoding="utf-8").split("\n", 1)[0].strip()
    except (OSError, UnicodeDecodeError):
        return None
    return first or None


def clear(folder: Path) -> None:
    """Remove everything inside ``folder`` (a checked output folder) but its marker, so that a clear cut
    short (a kill, a full disk) leaves a folder the same command still accepts; links are removed,
    never followed."""
    for entry in folder.iterdir():
        if entry.name == MARKER:
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def _refuse_special(folder: Path, given, option: str, advice: str = ADVICE) -> None:
    """The working directory, a folder that holds it, the home folder: never an output."""
    try:
        real = folder.resolve()
        cwd = Path.cwd().resolve()
    except (OSError, RuntimeError) as err:   # a symlink loop, a deleted working directory
        raise ConfigError(f"{option} {given}: cannot resolve the path ({err})") from None
    if real == cwd or real in cwd.parents:
        raise ConfigError(f"{option} {given}: is the working directory or holds it; {advice}")
    if real == Path.home().resolve():
        raise ConfigError(f"{option} {given}: is the home folder; {advice}")


def _check_parent(folder: Path, given, option: str, advice: str = ADVICE) -> None:
    """A new folder needs folders (not files) above it."""
    for parent in folder.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise ConfigError(f"{option} {given}: {parent} is a file, not a folder; {advice}")
            return


def check_file_output(path: str | Path, signature: str, command: str, *, option: str = "--out") -> Path:
    """Refuse to overwrite ``path`` unless it is missing or begins with ``signature`` (the first
    line the same command writes); a folder is refused too. Touches nothing; returns the path."""
    file = Path(path).expanduser()
    if file.is_dir():
        raise ConfigError(f"{option} {path}: is a folder; give a file name")
    if file.exists():
        try:
            with open(file, encoding="utf-8", errors="replace") as f:
                first = f.readline().rstrip("\n")
        except OSError as err:
            raise StorageError(f"{option} {path}: cannot read the file ({err.strerror or err})") from None
        if first != signature:
            raise ConfigError(f"{option} {path}: file exists and was not written by helicalib {command}; give a new "
                              "file name")
    else:
        _check_parent(file, path, option)
    return file
