"""The SQLite schema of a campaign database (version 4) and its creation.

One file holds every campaign run against it. Times are plant time in UTC seconds (REAL);
vectors are stored one column per component; JSON columns hold dictionaries and lists.
The ``schema_version`` table holds one row; a database of a newer version is refused, one of an
older version is brought up to date in place (:data:`MIGRATIONS`: version 2 added each
observation's approach directions, ``approach_1`` / ``approach_2``, NULL in older rows; version 3
the ``operator_actions`` table of the crew console, :mod:`helicalib.console`; version 4 each
observation's camera exposure, ``exposure_ms``, NULL in older rows and for cameras without one).
"""

from __future__ import annotations

import sqlite3

from helicalib.errors import ConfigError, DataError

SCHEMA_VERSION = 4

OPERATOR_ACTIONS = (
    """CREATE TABLE IF NOT EXISTS operator_actions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    kind TEXT NOT NULL,               -- pause, resume, recheck, repaired, out_of_service, in_service
    heliostats_json TEXT NOT NULL DEFAULT '[]',
    who TEXT NOT NULL,                -- the name the operator gave, and the address the request came from
    requested_wall_s REAL NOT NULL,   -- the controller's wall clock [UTC s]
    requested_s REAL,                 -- plant time [UTC s] (NULL when the plant clock could not be read)
    done_s REAL,                      -- plant time the runner applied it (NULL while pending)
    outcome TEXT NOT NULL DEFAULT ''
)""",
    "CREATE INDEX IF NOT EXISTS operator_actions_pending ON operator_actions (campaign_id, done_s)",
)
"""The crew console's actions (version 3): created with the schema, and by the migration."""

READ_INDEXES = (
    "CREATE INDEX IF NOT EXISTS events_by_kind ON events (campaign_id, kind)",
    "CREATE INDEX IF NOT EXISTS observations_by_target ON observations (campaign_id, target_id)",
    "CREATE INDEX IF NOT EXISTS visits_by_outcome ON visits (campaign_id, heliostat_id, outcome)",
)
"""Indexes for the crew's reads (``status``, the console) at 10⁴ heliostats. Not part of the
version: a writer that opens a database of the current version adds the missing ones; a reader
works without them (slower), and an older helicalib reads a database that has them."""

DDL = """
CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL);

CREATE TABLE IF NOT EXISTS campaigns (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    mode TEXT NOT NULL,
    started_s REAL NOT NULL,
    ended_s REAL,
    status TEXT NOT NULL DEFAULT 'running',
    config_path TEXT NOT NULL DEFAULT '',
    config_sha256 TEXT NOT NULL DEFAULT '',
    settings_json TEXT NOT NULL DEFAULT '{}'
);

CREATE TABLE IF NOT EXISTS heliostats (
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    heliostat_id TEXT NOT NULL,
    block_index INTEGER NOT NULL,
    target_id TEXT NOT NULL,
    PRIMARY KEY (campaign_id, heliostat_id)
);

CREATE TABLE IF NOT EXISTS visits (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    heliostat_id TEXT NOT NULL,
    target_id TEXT NOT NULL,
    started_s REAL NOT NULL,
    ended_s REAL,
    outcome TEXT NOT NULL DEFAULT 'running',
    reason TEXT NOT NULL DEFAULT '',
    iterations INTEGER NOT NULL DEFAULT 0,
    first_error_mrad REAL,
    final_error_mrad REAL
);
CREATE INDEX IF NOT EXISTS visits_by_heliostat ON visits (campaign_id, heliostat_id);

CREATE TABLE IF NOT EXISTS observations (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    heliostat_id TEXT NOT NULL,
    target_id TEXT NOT NULL,
    visit_id INTEGER REFERENCES visits(id),
    iteration INTEGER NOT NULL,
    capture_time_s REAL NOT NULL,
    stroke_cmd_1_mm REAL,            -- NULL: no stroke was commanded (a failure before any move)
    stroke_cmd_2_mm REAL,
    stroke_read_1_mm REAL,
    stroke_read_2_mm REAL,
    approach_1 INTEGER,              -- direction of actuator 1's last motion before the hold (+1/-1), NULL if unknown
    approach_2 INTEGER,
    sun_e REAL NOT NULL,
    sun_n REAL NOT NULL,
    sun_u REAL NOT NULL,
    sun_azimuth_deg REAL NOT NULL,
    sun_elevation_deg REAL NOT NULL,
    sun_rising INTEGER,
    wind_ms REAL,
    wind_direction_deg REAL,
    dni_wm2 REAL,
    temperature_c REAL,
    cleanliness REAL,                -- the plant's register (PLANT_INTERFACE), NULL if it gave none
    cleanliness_measured REAL,       -- measured from the spot's power (flux.visit), NULL if not estimated
    exposure_ms REAL,                -- the camera's exposure of the reading (interface 1.1), NULL if it has none
    valid INTEGER NOT NULL,
    reason TEXT NOT NULL,
    message TEXT NOT NULL,
    offset_u_m REAL,
    offset_v_m REAL,
    spot_x_px REAL,
    spot_y_px REAL,
    spot_area_px REAL,
    threshold REAL,
    jitter_px REAL,
    spot_e_m REAL,
    spot_n_m REAL,
    spot_u_m REAL,
    error_mrad REAL,
    before_frame_path TEXT,
    after_frame_paths_json TEXT NOT NULL DEFAULT '[]'
);
CREATE INDEX IF NOT EXISTS observations_by_heliostat ON observations (campaign_id, heliostat_id, valid);

CREATE TABLE IF NOT EXISTS fits (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    heliostat_id TEXT NOT NULL,
    time_s REAL NOT NULL,
    model TEXT NOT NULL,
    params_json TEXT NOT NULL,
    sigma_json TEXT NOT NULL,
    rms_mrad REAL NOT NULL,
    n_points INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS fits_by_heliostat ON fits (heliostat_id, id);

CREATE TABLE IF NOT EXISTS verdicts (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    heliostat_id TEXT NOT NULL,
    time_s REAL NOT NULL,
    accepted INTEGER NOT NULL,
    n_points INTEGER NOT NULL,
    rms_mrad REAL,
    reasons_json TEXT NOT NULL,
    details_json TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS verdicts_by_heliostat ON verdicts (campaign_id, heliostat_id, id);

CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    time_s REAL NOT NULL,
    kind TEXT NOT NULL,
    heliostat_id TEXT,
    reason TEXT NOT NULL,
    data_json TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS events_by_campaign ON events (campaign_id, time_s);
""" + "".join(stmt + ";\n" for stmt in OPERATOR_ACTIONS + READ_INDEXES)


MIGRATIONS: dict[int, tuple[str, ...]] = {
    2: ("ALTER TABLE observations ADD COLUMN approach_1 INTEGER",
        "ALTER TABLE observations ADD COLUMN approach_2 INTEGER"),
    3: OPERATOR_ACTIONS,
    4: ("ALTER TABLE observations ADD COLUMN exposure_ms REAL",),
}
"""Statements that take a database from the version before the key to the key's version."""


def _version(conn: sqlite3.Connection, where: str) -> int:
    """The version in ``schema_version`` (0 when the row is missing); :class:`DataError` when it is
    not a whole number (a damaged row)."""
    row = conn.execute("SELECT rowid, version FROM schema_version").fetchone()
    if row is None:
        return 0
    if type(row[1]) is not int:
        raise DataError(f"{where}: table schema_version, row {row[0]}: version is not an integer ({row[1]!r:.40})")
    return row[1]


def check_schema(conn: sqlite3.Connection, where: str) -> int:
    """The schema version of an existing database, checked without writing anything (readers).

    Raises :class:`ConfigError` for an empty file, a file that is not a helicalib database, one of
    a newer version, and one of an older version (a campaign command migrates it; a reader may not).
    """
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    if not tables:
        raise ConfigError(f"{where}: empty database, no helicalib campaign in it")
    if "schema_version" not in tables:
        raise ConfigError(f"{where}: not a helicalib database (tables {sorted(tables)[:5]} but no schema_version)")
    version = _version(conn, where)
    if version > SCHEMA_VERSION:
        raise ConfigError(
            f"{where}: database schema version {version} is newer than this helicalib's ({SCHEMA_VERSION}); upgrade helicalib")
    if version < SCHEMA_VERSION:
        raise ConfigError(f"{where}: database schema version {version} is older than this helicalib's "
                          f"({SCHEMA_VERSION}); a campaign command (run, check, simulate) migrates it, a reader does not")
    return version


def ensure_schema(conn: sqlite3.Connection, where: str) -> int:
    """Create the tables of an empty database or check the version of an existing one.

    Returns the schema version. Raises :class:`ConfigError` for a database written by a newer
    helicalib (its version is higher than :data:`SCHEMA_VERSION`) or a file that is not a
    helicalib database (tables present but no version). An older version is migrated in place, in
    one transaction.
    """
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    if tables and "schema_version" not in tables:
        raise ConfigError(f"{where}: not a helicalib database (tables {sorted(tables)[:5]} but no schema_version)")
    if "schema_version" in tables:
        version = _version(conn, where)
        if version > SCHEMA_VERSION:
            raise ConfigError(
                f"{where}: database schema version {version} is newer than this helicalib's ({SCHEMA_VERSION}); upgrade helicalib"
            )
        if version == SCHEMA_VERSION:
            _add_read_indexes(conn)
            return version
        if version >= 1:
            with conn:
                for v in range(version + 1, SCHEMA_VERSION + 1):
                    for stmt in MIGRATIONS[v]:
                        conn.execute(stmt)
                conn.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION,))
            _add_read_indexes(conn)
            return SCHEMA_VERSION
    with conn:
        conn.executescript(DDL)
        conn.execute("DELETE FROM schema_version")
        conn.execute("INSERT INTO schema_version (version) VALUES (?)", (SCHEMA_VERSION,))
    return SCHEMA_VERSION


def _add_read_indexes(conn: sqlite3.Connection) -> None:
    """Create the :data:`READ_INDEXES` a database of the current version lacks (one transaction)."""
    have = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'index'")}
    missing = [stmt for stmt in READ_INDEXES if stmt.split(" EXISTS ", 1)[1].split()[0] not in have]
    if missing:
        with conn:
            for stmt in missing:
                conn.execute(stmt)
