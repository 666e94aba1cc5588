"""One exception family: every error a user sees is one line naming what is wrong and where."""

from __future__ import annotations


class HelicalibError(Exception):
    """Base of every error helicalib raises on purpose; ``str(err)`` is one readable line."""


class ConfigError(HelicalibError):
    """A field config (or another input file) is malformed; the message names file and key path.

    ``problems`` holds one line per problem (``FILE: key.path: what is wrong``).
    """

    def __init__(self, message: str, problems: list[str] | None = None):
        super().__init__(message)
        self.problems = list(problems) if problems else [message]


class PlantError(HelicalibError):
    """The plant refused a command, did not answer, or answered something outside the contract."""


class MeasurementError(HelicalibError):
    """A frame or a measurement cannot be used; the message says why."""


class GeometryError(HelicalibError):
    """A pose is unreachable or a stroke lies outside the drive's range."""


class DataError(HelicalibError):
    """Stored data is damaged (a database row, a JSON column, a frame file); the message names the
    table and row (or file) so a crew can find it."""


class StorageError(HelicalibError):
    """The campaign database or its frames folder cannot be written (full disk, read-only file or
    folder); the message names the file and what the system said."""
