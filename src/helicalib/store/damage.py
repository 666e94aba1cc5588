"""Damaged stored data and failed writes, each as one line naming where.

helicalib writes every column as its schema declares it, but a database file can be damaged after
it was written: a disk fault or a copy cut short (pages SQLite reports as "database disk image is
malformed"), or a hand edit (text in a REAL column, a JSON column that is not JSON). Every reader of
the store checks what it reads (:class:`RowCheck`, :func:`loads`) and raises
:class:`~helicalib.errors.DataError` naming the database, the table, the row and the column, e.g.
``runs/x.db: table events, row 17: data_json is not JSON``; damaged pages give one line that names
the database and how to check it (:func:`read_error`). A write the disk or the file system refuses
(full disk, read-only file or folder) raises :class:`~helicalib.errors.StorageError` naming the
database (or frame file) and what SQLite or the system said (:func:`write_error`,
:func:`os_write_error`).
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

from helicalib.errors import DataError, StorageError

CORRUPT = ("SQLITE_CORRUPT",)
"""SQLite's result codes of damaged pages (extended codes start with these names)."""
CANNOT_WRITE = ("SQLITE_READONLY", "SQLITE_CANTOPEN", "SQLITE_FULL", "SQLITE_IOERR", "SQLITE_PERM", "SQLITE_BUSY",
                "SQLITE_LOCKED")
"""SQLite's result codes of a file or folder that cannot be written (full disk, read-only file or
folder, I/O error, another writer holding it past the timeout)."""

_ALLOWED = {"REAL": (int, float), "INTEGER": (int,), "TEXT": (str,)}
"""Python types a column of each declared type holds when it is intact (SQLite's affinity turns
whatever helicalib wrote into these; anything else came from outside helicalib)."""

_KIND_WORDS = {"REAL": "a number", "INTEGER": "an integer", "TEXT": "text"}

JSON_SHAPES: dict[tuple[str, str], tuple[type, type | tuple[type, ...] | None]] = {
    ("campaigns", "settings_json"): (dict, None),
    ("fits", "params_json"): (dict, (int, float)),
    ("fits", "sigma_json"): (dict, (int, float)),
    ("verdicts", "reasons_json"): (list, str),
    ("verdicts", "details_json"): (dict, None),
    ("events", "data_json"): (dict, None),
    ("observations", "after_frame_paths_json"): (list, str),
    ("operator_actions", "heliostats_json"): (list, str),
}
"""Every JSON column: (container it holds, type of its items or values; None: anything)."""


def integrity_hint(db: str | Path) -> str:
    return f"check it with: sqlite3 {db} 'PRAGMA integrity_check'"


def is_corrupt(exc: sqlite3.Error) -> bool:
    name = getattr(exc, "sqlite_errorname", "") or ""
    return name.startswith(CORRUPT) or "malformed" in str(exc)


def cannot_write(exc: sqlite3.Error) -> bool:
    return (getattr(exc, "sqlite_errorname", "") or "").startswith(CANNOT_WRITE)


def read_error(db: str | Path, exc: sqlite3.Error, table: str | None = None) -> DataError:
    """A reader's one line for a SQLite error: damaged pages name the database and the check to run."""
    where = f"table {table}: " if table else ""
    if is_corrupt(exc):
        return DataError(f"{db}: {where}database disk image is malformed (damaged pages); {integrity_hint(db)}")
    return DataError(f"{db}: {where}cannot be read ({exc})")


def write_error(db: str | Path, exc: sqlite3.Error) -> StorageError:
    """A writer's one line for a SQLite error (full disk, read-only file or folder, damaged pages)."""
    hint = f"; {integrity_hint(db)}" if is_corrupt(exc) else ""
    return StorageError(f"{db}: cannot write the database: {exc}{hint}")


def os_write_error(path: str | Path, exc: OSError, what: str = "write") -> StorageError:
    """One line for a file or folder the system would not write (frames, the owner lock, folders)."""
    return StorageError(f"{path}: cannot {what}: {exc.strerror or exc}")


def _row_label(table: str, row: sqlite3.Row) -> str:
    keys = row.keys()
    return f"table {table}, row {row['id']}" if "id" in keys else f"table {table}"


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


class RowCheck:
    """Checks rows read from the store against the declared column types (per connection, cached)."""

    def __init__(self, conn: sqlite3.Connection, db: str | Path):
        self._conn = conn
        self.db = db
        self._columns: dict[str, dict[str, tuple[tuple[type, ...], str]]] = {}

    def _declared(self, table: str) -> dict[str, tuple[tuple[type, ...], str]]:
        """Column → (allowed Python types, word for the declared type), from the schema itself."""
        if table not in self._columns:
            out = {}
            for _cid, name, decl, notnull, _default, pk in self._conn.execute(f"PRAGMA table_info({table})"):
                kind = str(decl).upper()
                if kind in _ALLOWED:
                    allowed = _ALLOWED[kind] + (() if notnull or pk else (type(None),))
                    out[name] = (allowed, _KIND_WORDS[kind])
            self._columns[table] = out
        return self._columns[table]

    def check(self, table: str, rows: list[sqlite3.Row]) -> None:
        """Raise :class:`DataError` for the first value of ``rows`` whose type its column does not allow."""
        if not rows:
            return
        declared = self._declared(table)
        for i, name in enumerate(rows[0].keys()):
            if name not in declared:
                continue
            allowed, word = declared[name]
            column = [r[i] for r in rows]
            if set(map(type, column)) <= set(allowed):
                continue
            for r, value in zip(rows, column):
                if type(value) not in allowed:
                    found = "empty (NULL)" if value is None else f"not {word} ({type(value).__name__} {_shown(value)})"
                    raise DataError(f"{self.db}: {_row_label(table, r)}: {name} is {found}")


_ITEM_TYPES = {(int, float): frozenset({int, float}), str: frozenset({str})}
"""The exact types a decoded JSON value's items may have (``json`` makes no subclasses; a bool is
not a number here)."""


def loads(db: str | Path, table: str, row: sqlite3.Row, column: str) -> Any:
    """The JSON value of ``row[column]``, checked against :data:`JSON_SHAPES`; :class:`DataError`
    naming database, table, row and column when it is not JSON or not of the stored shape."""
    text = row[column]
    container, items = JSON_SHAPES[(table, column)]
    try:
        value = json.loads(text)
    except (TypeError, ValueError, RecursionError):
        raise DataError(f"{_where(db, table, row, column)} is not JSON ({_shown(text)})") from None
    noun = "object" if container is dict else "list"
    if not isinstance(value, container):
        raise DataError(f"{_where(db, table, row, column)} is not a JSON {noun} ({_shown(value)})")
    if items is not None and value:  # the where is built only for a damaged value: readers decode 10⁵ rows
        values = value.values() if container is dict else value
        if not set(map(type, values)) <= _ITEM_TYPES[items]:
            word = "numbers" if items == (int, float) else "strings"
            raise DataError(f"{_where(db, table, row, column)} is not a JSON {noun} of {word} ({_shown(value)})")
    return value


def _where(db: str | Path, table: str, row: sqlite3.Row, column: str) -> str:
    return f"{db}: {_row_label(table, row)}: {column}"
