"""The campaign store: one SQLite file (WAL) plus PNG frames in an images directory beside it.

Every write is its own transaction, committed before the call returns, and every frame file is
renamed into place before the row that points to it is inserted: a campaign killed with
``kill -9`` at any instant loses nothing it had recorded, and no row points to a missing frame.
Resuming is reopening the file and continuing :meth:`Store.unfinished_campaign`.

The store is safe to share between threads (one connection behind a lock).
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from helicalib.errors import ConfigError
from helicalib.store import frames as _frames
from helicalib.store.damage import (RowCheck, cannot_write, is_corrupt, loads, os_write_error, read_error,
                                    write_error)
from helicalib.store.observation_rows import OBSERVATION_COLUMNS, observation_from_row, observation_to_row
from helicalib.store.records import (Campaign, CampaignHeliostat, Event, Fit, Observation, OperatorAction, Verdict,
                                     Visit)
from helicalib.store.schema import check_schema, ensure_schema

FrameData = bytes | np.ndarray
BATCH_ROWS = 500
"""A batched store commits after this many writes ..."""
BATCH_S = 2.0
"""... or this many seconds after its last commit."""


def _json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, default=_json_default)


def _json_default(value: Any):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (set, frozenset, tuple)):
        return list(value)
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


class Store:
    """A campaign database. Build it with :meth:`Store.open`.

    Parameters
    ----------
    conn : sqlite3.Connection
        Open connection (WAL mode, schema checked).
    path : Path
        The database file.
    images_dir : Path
        Directory of the frame PNGs; observation rows hold paths relative to it.
    durable : bool
        fsync frames and use ``synchronous=FULL`` (survives power loss); False keeps the kill -9
        guarantee (``synchronous=NORMAL`` in WAL) and is faster for simulations.
    batched : bool
        Simulations only: writes are committed together, every :data:`BATCH_ROWS` writes or
        :data:`BATCH_S` seconds and at :meth:`flush` / :meth:`close`, instead of one transaction
        each (a killed simulation loses at most its last batch; live runs never batch).
    """

    def __init__(self, conn: sqlite3.Connection, path: Path, images_dir: Path, durable: bool,
                 batched: bool = False):
        self.batched = bool(batched)
        self._pending = 0
        self._batch_t0 = time.monotonic()
        self._conn = conn
        self._check = RowCheck(conn, path)
        self._lock = threading.RLock()
        self._lock_file = None
        self.path = path
        self.images_dir = images_dir
        self.durable = durable

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(cls, path: str | Path, images_dir: str | Path | None = None, *, durable: bool = True,
             readonly: bool = False, owner: str | None = None, batched: bool = False) -> "Store":
        """Create the database at ``path`` or reopen it.

        Parameters
        ----------
        path : str or Path
            Database file; a ``sqlite:///`` URL is accepted too. Parent directories are created
            (not with ``readonly``).
        images_dir : str or Path, optional
            Frames directory; default ``images`` beside the database. Relative paths are taken
            relative to the database's directory.
        durable : bool
            See :class:`Store`.
        readonly : bool
            A reader (``status``, ``report``): the file must exist and be a helicalib database of
            this schema version; nothing is created, migrated, written or deleted, so a reader can
            open the database of a running campaign at any time.
        owner : str, optional
            Take the ownership (:meth:`take_ownership`, ``owner`` says what runs) before the schema
            is created or migrated: a campaign command opens its database this way.
        batched : bool
            See :class:`Store` (simulations only).

        Raises
        ------
        ConfigError
            The file is not a helicalib database, is of a newer schema, or cannot be opened.
        StorageError
            A writer: the database, its folder or its lock file cannot be written (read-only file or
            folder, a path through a file, full disk).
        DataError
            The file's pages are damaged.
        """
        db = database_path(path)
        images = Path(images_dir) if images_dir is not None else Path("images")
        if not images.is_absolute():
            images = db.parent / images
        if readonly:
            return cls(_connect_readonly(db), db, images, durable)
        try:
            db.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise os_write_error(db.parent, exc, "create the database's folder") from None
        real = db.resolve()  # every path to one file (a symlink, dir/../dir/x.db) shares one lock and one WAL
        lock_file = _owner_lock(_lock_file_of(real), owner) if owner is not None else None
        try:
            conn = sqlite3.connect(real, timeout=30.0, check_same_thread=False)
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute(f"PRAGMA synchronous={'FULL' if durable else 'NORMAL'}")
            conn.execute("PRAGMA foreign_keys=ON")
            ensure_schema(conn, str(db))
            _probe_write(conn)
        except sqlite3.DatabaseError as exc:
            if lock_file is not None:
                lock_file.close()
            raise _open_error(db, exc, writing=True) from None
        except BaseException:
            if lock_file is not None:
                lock_file.close()
            raise
        store = cls(conn, db, images, durable, batched=batched)
        if lock_file is not None:
            store._lock_file = lock_file
            _frames.clean_temporary(images)
        return store

    # ------------------------------------------------------------------ ownership
    def take_ownership(self, what: str = "campaign") -> int:
        """Become the one process that runs campaigns on this database; clean what a killed owner left.

        Takes an exclusive lock on ``<database>.lock`` (held until :meth:`close`; the kernel
        releases it when the process dies, even by ``kill -9``), then removes the ``*.tmp`` frame
        files a killed writer left. Only an owner deletes anything: readers never do. Returns how
        many temporary files were removed.

        Raises
        ------
        ConfigError
            Another process holds the database (its pid and what it runs are named).
        """
        if self._lock_file is None:
            self._lock_file = _owner_lock(self.lock_path, what)
        return _frames.clean_temporary(self.images_dir)

    @property
    def lock_path(self) -> Path:
        """``<database>.lock`` beside the resolved database file (the one lock of every path to it)."""
        return _lock_file_of(self.path)

    def owner(self) -> str | None:
        """Who holds the database now ("pid 123: run"), or None when no campaign process runs on it."""
        return _lock_holder(self.lock_path)

    def remove_orphan_frames(self, campaign_id: int) -> int:
        """Delete the frames of a campaign's interrupted visits that no observation points to;
        returns how many.

        A visit saves its "before" frame when it starts and the observation that points to it at
        its first measurement; a process killed in between leaves the frame alone on disk. The owner
        calls this after :meth:`close_interrupted_visits`. Frames of visits that ended otherwise are
        never deleted (a failed visit's observation points to its before frame).
        """
        if self._lock_file is None:
            raise RuntimeError("remove_orphan_frames needs take_ownership() first")
        folder = self.images_dir / f"c{int(campaign_id)}"
        if not folder.is_dir():
            return 0
        interrupted = {int(r[0]) for r in self._read("SELECT id FROM visits WHERE campaign_id = ? AND outcome = "
                                                     "'interrupted'", (int(campaign_id),), table="visits")}
        referenced = set()
        for r in self._read("SELECT id, before_frame_path, after_frame_paths_json FROM observations"
                            " WHERE campaign_id = ?", (int(campaign_id),), table="observations"):
            if r["before_frame_path"]:
                referenced.add(r["before_frame_path"])
            referenced.update(loads(self.path, "observations", r, "after_frame_paths_json"))
        removed = 0
        for f in folder.rglob("v*_*.png"):
            visit = f.name[1:].split("_", 1)[0]
            if (visit.isdigit() and int(visit) in interrupted
                    and f.relative_to(self.images_dir).as_posix() not in referenced):
                f.unlink(missing_ok=True)
                removed += 1
        return removed

    def close(self) -> None:
        """Close the connection (every write is already committed) and release the ownership.

        The connection is closed and the ownership released even when a batched store's last
        commit fails (:class:`StorageError`, raised after)."""
        with self._lock:
            try:
                if self.batched:
                    with self._writing():
                        self._conn.commit()
            finally:
                self._conn.close()
                if self._lock_file is not None:
                    self._lock_file.close()
                    self._lock_file = None

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """The store's lock; a write SQLite refuses (full disk, read-only file or folder, damaged
        pages) leaves as one :class:`StorageError` line naming the database and what SQLite said."""
        with self._lock:
            try:
                yield
            except sqlite3.Error as exc:
                raise write_error(self.path, exc) from None

    def _write(self, sql: str, params: Sequence[Any] = ()) -> int:
        if not self.batched:
            with self._writing(), self._conn:
                cur = self._conn.execute(sql, params)
                return int(cur.lastrowid or 0)
        with self._writing():
            cur = self._conn.execute(sql, params)
            self._pending += 1
            if self._pending >= BATCH_ROWS or time.monotonic() - self._batch_t0 >= BATCH_S:
                self.flush()
            return int(cur.lastrowid or 0)

    def flush(self) -> None:
        """Commit the writes of a batched store now (a no-op otherwise: each write is committed)."""
        with self._writing():
            self._conn.commit()
            self._pending, self._batch_t0 = 0, time.monotonic()

    def _read(self, sql: str, params: Sequence[Any] = (), *, table: str | None = None) -> list[sqlite3.Row]:
        """The rows of a query; with ``table``, each value checked against its declared column type.

        Raises :class:`DataError` naming the database, table, row and column for a value the column
        cannot hold, and one line for damaged pages (:mod:`helicalib.store.damage`)."""
        with self._lock:
            try:
                cur = self._conn.execute(sql, params)
                cur.row_factory = sqlite3.Row
                rows = cur.fetchall()
                if table is not None:  # under the lock: the check reads the schema on the shared connection
                    self._check.check(table, rows)
            except sqlite3.Error as exc:
                raise read_error(self.path, exc, table) from None
        return rows

    # ------------------------------------------------------------------ campaigns
    def start_campaign(self, *, name: str, mode: str, started_s: float,
                       heliostats: Iterable[CampaignHeliostat | tuple[str, int, str]],
                       config_path: str | Path = "", config_sha256: str = "",
                       settings: dict[str, Any] | None = None) -> int:
        """Record a new campaign and its heliostats (id, plant block index, target); returns its id.

        The campaign's frames folder is recorded in its settings (``images_dir``, absolute), so that a
        reader opened without the writer's ``images_dir`` finds the frames (:meth:`campaign_images_dir`).
        """
        settings = dict(settings or {})
        settings.setdefault("images_dir", _recorded_folder(self.images_dir, self.path))
        rows = [h if isinstance(h, CampaignHeliostat) else CampaignHeliostat(str(h[0]), int(h[1]), str(h[2]))
                for h in heliostats]
        with self._writing(), self._conn:
            cur = self._conn.execute(
                "INSERT INTO campaigns (name, mode, started_s, status, config_path, config_sha256, settings_json)"
                " VALUES (?, ?, ?, 'running', ?, ?, ?)",
                (name, mode, float(started_s), str(config_path), config_sha256, _json(settings or {})),
            )
            cid = int(cur.lastrowid)
            self._conn.executemany(
                "INSERT INTO heliostats (campaign_id, heliostat_id, block_index, target_id) VALUES (?, ?, ?, ?)",
                [(cid, h.heliostat_id, h.block_index, h.target_id) for h in rows],
            )
        return cid

    def campaign_images_dir(self, campaign_id: int) -> Path:
        """The folder that holds the campaign's frames (its ``c<id>/`` sub-folder).

        This store's own frames folder when it holds them (a database moved or copied with its
        frames); else the folder recorded at the campaign's start (relative to the database when it
        lay beside it, else absolute: a run with ``--images`` elsewhere); else this store's.
        """
        sub = f"c{int(campaign_id)}"
        if (self.images_dir / sub).is_dir():
            return self.images_dir
        recorded = (self.campaign(campaign_id).settings or {}).get("images_dir")
        if isinstance(recorded, str) and recorded:
            folder = Path(recorded)
            folder = folder if folder.is_absolute() else self.path.parent / folder
            if (folder / sub).is_dir():
                return folder
        return self.images_dir

    def finish_campaign(self, campaign_id: int, ended_s: float, status: str = "finished") -> None:
        """Mark a campaign ended: ``finished`` (its end time came) or ``stopped`` (Ctrl-C, SIGTERM)."""
        self._write("UPDATE campaigns SET ended_s = ?, status = ? WHERE id = ?", (float(ended_s), status, int(campaign_id)))

    def reopen_campaign(self, campaign_id: int) -> None:
        """Mark a campaign ``running`` again (a run resumes it)."""
        self._write("UPDATE campaigns SET ended_s = NULL, status = 'running' WHERE id = ?", (int(campaign_id),))

    def campaign(self, campaign_id: int) -> Campaign:
        rows = self._read("SELECT * FROM campaigns WHERE id = ?", (int(campaign_id),), table="campaigns")
        if not rows:
            raise ConfigError(f"{self.path}: no campaign {campaign_id}")
        return _campaign(self.path, rows[0])

    def campaigns(self) -> list[Campaign]:
        """All campaigns, oldest first."""
        return [_campaign(self.path, r) for r in self._read("SELECT * FROM campaigns ORDER BY id", table="campaigns")]

    def unfinished_campaign(self, mode: str | None = None) -> Campaign | None:
        """The newest campaign still ``'running'`` (optionally of one mode), or None: what ``run`` resumes."""
        sql = "SELECT * FROM campaigns WHERE status = 'running'"
        params: tuple = ()
        if mode is not None:
            sql += " AND mode = ?"
            params = (mode,)
        rows = self._read(sql + " ORDER BY id DESC LIMIT 1", params, table="campaigns")
        return _campaign(self.path, rows[0]) if rows else None

    def campaign_heliostats(self, campaign_id: int) -> list[CampaignHeliostat]:
        rows = self._read("SELECT rowid AS id, heliostat_id, block_index, target_id FROM heliostats WHERE campaign_id = ?"
                          " ORDER BY block_index", (int(campaign_id),), table="heliostats")
        return [CampaignHeliostat(r["heliostat_id"], int(r["block_index"]), r["target_id"]) for r in rows]

    # ------------------------------------------------------------------ visits
    def begin_visit(self, campaign_id: int, heliostat_id: str, target_id: str, started_s: float) -> int:
        """Open a visit (outcome ``'running'``); returns its id."""
        return self._write(
            "INSERT INTO visits (campaign_id, heliostat_id, target_id, started_s) VALUES (?, ?, ?, ?)",
            (int(campaign_id), heliostat_id, target_id, float(started_s)),
        )

    def end_visit(self, visit_id: int, *, ended_s: float, outcome: str, reason: str = "", iterations: int = 0,
                  first_error_mrad: float | None = None, final_error_mrad: float | None = None) -> None:
        """Close a visit with its outcome (``'converged'``, ``'invalid'``, ``'fault'``, ``'aborted'`` …; see Visit) and reason."""
        self._write(
            "UPDATE visits SET ended_s = ?, outcome = ?, reason = ?, iterations = ?, first_error_mrad = ?,"
            " final_error_mrad = ? WHERE id = ?",
            (float(ended_s), outcome, reason, int(iterations), _opt(first_error_mrad), _opt(final_error_mrad), int(visit_id)),
        )

    def close_interrupted_visits(self, campaign_id: int | None, time_s: float) -> int:
        """Mark visits left ``'running'`` by a killed process ``'interrupted'`` (of one campaign, or of
        all with None: the owner at its start); returns how many."""
        where, params = _where(campaign_id=None if campaign_id is None else int(campaign_id))
        with self._writing(), self._conn:
            cur = self._conn.execute(
                "UPDATE visits SET outcome = 'interrupted', reason = 'process ended during the visit', ended_s = ?"
                + (where + " AND" if where else " WHERE") + " outcome = 'running'", (float(time_s), *params))
            return int(cur.rowcount)

    def visits(self, campaign_id: int | None = None, heliostat_id: str | None = None, *,
               outcome: str | None = None, newest: int | None = None) -> list[Visit]:
        """Visits in recording order, filtered by campaign, heliostat and outcome; ``newest``: only
        the newest N of them (still oldest first)."""
        where, params = _where(campaign_id=campaign_id, heliostat_id=heliostat_id, outcome=outcome)
        if newest is None:
            sql = f"SELECT * FROM visits{where} ORDER BY id"
        else:  # "+campaign_id": walk the rows newest first and stop at N (the index would sort them all)
            sql = (f"SELECT * FROM (SELECT * FROM visits{where.replace('campaign_id =', '+campaign_id =')}"
                   f" ORDER BY id DESC LIMIT {max(0, int(newest))}) ORDER BY id")
        return [Visit(**{k: r[k] for k in r.keys()}) for r in self._read(sql, params, table="visits")]

    def visits_of(self, campaign_id: int, heliostat_ids: Sequence[str]) -> dict[str, list[Visit]]:
        """The visits of each of ``heliostat_ids`` in a campaign (recording order), by heliostat id,
        in one query (heliostats without a visit are left out); as :meth:`visits` for each of them."""
        return self._rows_of("visits", campaign_id, heliostat_ids, lambda r: Visit(**{k: r[k] for k in r.keys()}))

    def _rows_of(self, table: str, campaign_id: int, heliostat_ids: Sequence[str], make) -> dict[str, list]:
        """``make(row)`` of each row of ``table`` of a campaign and of ``heliostat_ids``, in recording
        order, by heliostat id (one query)."""
        ids = list(heliostat_ids)
        out: dict[str, list] = {}
        if ids:
            rows = self._read(f"SELECT * FROM {table} WHERE campaign_id = ? AND heliostat_id IN ({_marks(ids)}) "
                              "ORDER BY id", (int(campaign_id), *ids), table=table)
            for r in rows:
                out.setdefault(r["heliostat_id"], []).append(make(r))
        return out

    def count_visits(self, campaign_id: int) -> int:
        """How many visits a campaign has (any outcome, running ones too)."""
        return int(self._read("SELECT COUNT(*) FROM visits WHERE campaign_id = ?", (int(campaign_id),))[0][0])

    def last_outcomes(self, campaign_id: int) -> dict[str, str]:
        """Each heliostat's newest ended visit's outcome (a running visit is not ended), by heliostat id."""
        rows = self._read("SELECT id, heliostat_id, outcome FROM visits WHERE id IN (SELECT MAX(id) FROM visits "
                          "WHERE campaign_id = ? AND outcome != 'running' GROUP BY heliostat_id)",
                          (int(campaign_id),), table="visits")
        return {r["heliostat_id"]: r["outcome"] for r in rows}

    # ------------------------------------------------------------------ observations
    def save_frame(self, frame: FrameData, *, campaign_id: int, heliostat_id: str, visit_id: int | None,
                   iteration: int, capture_time_s: float, kind: str) -> str:
        """Write one frame as PNG (atomically) and return its path relative to ``images_dir``.

        ``capture_time_s`` is the camera's (untrusted) stamp: it is not part of the file name."""
        data = _frames.to_png_bytes(frame)
        with self._lock:  # write_atomic: StorageError naming the frame file when it cannot be written
            rel = _frames.unique_path(self.images_dir, _frames.frame_relpath(
                campaign_id, heliostat_id, visit_id, iteration, kind))
            _frames.write_atomic(self.images_dir / rel, data, durable=self.durable)
        return rel.as_posix()

    def record_observation(self, obs: Observation, *, before_frame: FrameData | None = None,
                           after_frames: Sequence[FrameData] | FrameData | None = None) -> int:
        """Save the frames, then insert the observation in its own transaction; returns its id.

        Frames given here are written first and their paths replace ``obs.before_frame_path`` /
        ``obs.after_frame_paths``; already-saved paths in ``obs`` are kept when no frame is given.
        """
        if isinstance(after_frames, (bytes, bytearray, np.ndarray)):
            after_frames = [after_frames]
        key = dict(campaign_id=obs.campaign_id, heliostat_id=obs.heliostat_id, visit_id=obs.visit_id,
                   iteration=obs.iteration, capture_time_s=obs.capture_time_s)
        before_path = obs.before_frame_path
        if before_frame is not None:
            before_path = self.save_frame(before_frame, kind="before", **key)
        after_paths = tuple(obs.after_frame_paths)
        if after_frames:
            after_paths = tuple(self.save_frame(f, kind=f"after{i}", **key) for i, f in enumerate(after_frames))
        row = observation_to_row(obs, before_path, after_paths)
        cols = ", ".join(row)
        marks = ", ".join("?" for _ in row)
        return self._write(f"INSERT INTO observations ({cols}) VALUES ({marks})", tuple(row.values()))

    def set_frame_paths(self, rows: Sequence[tuple[int, str | None, Sequence[str]]]) -> None:
        """Replace the frame paths of observations ``(id, before_frame_path, after_frame_paths)``
        in one transaction (frame retention, :mod:`helicalib.store.retention`)."""
        with self._writing():
            self.flush()
            with self._conn:
                self._conn.executemany(
                    "UPDATE observations SET before_frame_path = ?, after_frame_paths_json = ? WHERE id = ?",
                    [(before, _json(list(after)), int(i)) for i, before, after in rows])

    def observations(self, campaign_id: int | None = None, heliostat_id: str | None = None,
                     valid: bool | None = None) -> list[Observation]:
        """Observations in recording order, filtered by campaign, heliostat and validity."""
        where, params = _where(campaign_id=campaign_id, heliostat_id=heliostat_id,
                               valid=None if valid is None else int(bool(valid)))
        return [observation_from_row(r, self.path)
                for r in self._read(f"SELECT * FROM observations{where} ORDER BY id", params, table="observations")]

    def observations_of(self, campaign_id: int, heliostat_ids: Sequence[str]) -> dict[str, list[Observation]]:
        """The observations of each of ``heliostat_ids`` in a campaign (recording order), by heliostat
        id, in one query (heliostats without one are left out); as :meth:`observations` for each."""
        return self._rows_of("observations", campaign_id, heliostat_ids, lambda r: observation_from_row(r, self.path))

    def observations_frame(self, campaign_id: int | None = None, heliostat_id: str | None = None,
                           valid: bool | None = None):
        """The same selection as :meth:`observations` as a pandas DataFrame of the flat columns."""
        import pandas as pd

        where, params = _where(campaign_id=campaign_id, heliostat_id=heliostat_id,
                               valid=None if valid is None else int(bool(valid)))
        rows = self._read(f"SELECT {', '.join(OBSERVATION_COLUMNS)} FROM observations{where} ORDER BY id", params,
                          table="observations")
        for r in rows:  # the frame keeps the text; a reader that decodes it later must find JSON there
            loads(self.path, "observations", r, "after_frame_paths_json")
        frame = pd.DataFrame([tuple(r) for r in rows], columns=list(OBSERVATION_COLUMNS))
        frame["valid"] = frame["valid"].astype(bool)
        return frame

    def latest_by_target(self, campaign_id: int, with_frames: bool = False) -> dict[str, Observation]:
        """Each target's newest observation of a campaign (``with_frames``: the newest with a before and
        an after frame), by target id."""
        frames = " AND before_frame_path IS NOT NULL AND after_frame_paths_json != '[]'" if with_frames else ""
        rows = self._read(f"SELECT * FROM observations WHERE id IN (SELECT MAX(id) FROM observations WHERE "
                          f"campaign_id = ?{frames} GROUP BY target_id)", (int(campaign_id),), table="observations")
        return {r["target_id"]: observation_from_row(r, self.path) for r in rows}

    def count_observations(self, campaign_id: int | None = None, valid: bool | None = None) -> int:
        where, params = _where(campaign_id=campaign_id, valid=None if valid is None else int(bool(valid)))
        return int(self._read(f"SELECT COUNT(*) FROM observations{where}", params, table="observations")[0][0])

    def export_observations_csv(self, path: str | Path, campaign_id: int | None = None,
                                valid: bool | None = None) -> int:
        """Write the observations (flat columns, see ``docs/campaign.md``) to CSV; returns the row count."""
        frame = self.observations_frame(campaign_id=campaign_id, valid=valid)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        frame.to_csv(path, index=False, float_format="%.10g")
        return len(frame)

    def export_fit_csv(self, path: str | Path, campaign_id: int | None = None,
                       spot_method: str = "grlm-centroid") -> int:
        """Write the VALID observations in the fit-input format of :mod:`helicalib.calibration.observations`.

        ``helicalib fit`` reads that file. Strokes are the read-back ones (commanded when none was
        read); ``target_u_m``/``target_v_m`` are the offsets from the aim point (the board centre);
        ``record_id`` is the observation's row id, ``source`` is ``campaign``. Returns the row count.
        """
        from helicalib.calibration.observations import write_observations
        from helicalib.store.stream import fit_row

        rows = [r for o in self.observations(campaign_id=campaign_id, valid=True)
                if (r := fit_row(o, spot_method)) is not None]
        write_observations(path, rows, comments=[f"helicalib campaign database {self.path}"
                                                 + ("" if campaign_id is None else f", campaign {campaign_id}")])
        return len(rows)

    # ------------------------------------------------------------------ fits, verdicts, events
    def record_fit(self, *, campaign_id: int, heliostat_id: str, time_s: float, model: str,
                   params: dict[str, float], sigma: dict[str, float], rms_mrad: float, n_points: int) -> int:
        """Record one error-model fit (named parameters and their 1-sigma); returns its id."""
        return self._write(
            "INSERT INTO fits (campaign_id, heliostat_id, time_s, model, params_json, sigma_json, rms_mrad, n_points)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (int(campaign_id), heliostat_id, float(time_s), model, _json(params), _json(sigma), float(rms_mrad), int(n_points)),
        )

    def latest_fit(self, heliostat_id: str, campaign_id: int | None = None) -> Fit | None:
        """The newest fit of a heliostat (in a campaign, or in any when ``campaign_id`` is None)."""
        where, params = _where(campaign_id=campaign_id, heliostat_id=heliostat_id)
        rows = self._read(f"SELECT * FROM fits{where} ORDER BY id DESC LIMIT 1", params, table="fits")
        return _fit(self.path, rows[0]) if rows else None

    def latest_fits(self, heliostat_ids: Sequence[str], campaign_id: int | None = None) -> dict[str, Fit]:
        """The newest fit of each of ``heliostat_ids`` (in a campaign, or in any when ``campaign_id`` is
        None), by heliostat id, in one query; as :meth:`latest_fit` for each (none: left out)."""
        ids = list(heliostat_ids)
        if not ids:
            return {}
        where = "" if campaign_id is None else "campaign_id = ? AND "
        params = (() if campaign_id is None else (int(campaign_id),)) + tuple(ids)
        rows = self._read(f"SELECT * FROM fits WHERE id IN (SELECT MAX(id) FROM fits WHERE {where}heliostat_id IN "
                          f"({_marks(ids)}) GROUP BY heliostat_id)", params, table="fits")
        return {r["heliostat_id"]: _fit(self.path, r) for r in rows}

    def fits(self, campaign_id: int | None = None, heliostat_id: str | None = None) -> list[Fit]:
        where, params = _where(campaign_id=campaign_id, heliostat_id=heliostat_id)
        return [_fit(self.path, r) for r in self._read(f"SELECT * FROM fits{where} ORDER BY id", params, table="fits")]

    def record_verdict(self, *, campaign_id: int, heliostat_id: str, time_s: float, accepted: bool,
                       n_points: int, rms_mrad: float | None, reasons: Sequence[str],
                       details: dict[str, Any] | None = None) -> int:
        """Record one acceptance verdict; returns its id."""
        return self._write(
            "INSERT INTO verdicts (campaign_id, heliostat_id, time_s, accepted, n_points, rms_mrad, reasons_json, details_json)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (int(campaign_id), heliostat_id, float(time_s), int(bool(accepted)), int(n_points), _opt(rms_mrad),
             _json(list(reasons)), _json(details or {})),
        )

    def verdicts(self, campaign_id: int, heliostat_id: str | None = None) -> list[Verdict]:
        """Every verdict of a campaign (or of one heliostat in it), oldest first."""
        where, params = _where(campaign_id=campaign_id, heliostat_id=heliostat_id)
        return [_verdict(self.path, r)
                for r in self._read(f"SELECT * FROM verdicts{where} ORDER BY time_s, id", params, table="verdicts")]

    def latest_verdicts(self, campaign_id: int, after_id: int = 0) -> dict[str, Verdict]:
        """The newest verdict of each heliostat of a campaign, by heliostat id; ``after_id``: only
        of the heliostats with a verdict recorded after that row id (verdicts are only ever added,
        so a reader holding the result for ``after_id`` updates it with this)."""
        rows = self._read(
            "SELECT * FROM verdicts WHERE id IN (SELECT MAX(id) FROM verdicts WHERE campaign_id = ? AND id > ? "
            "GROUP BY heliostat_id)", (int(campaign_id), int(after_id)), table="verdicts")
        return {r["heliostat_id"]: _verdict(self.path, r) for r in rows}

    def record_event(self, *, campaign_id: int, time_s: float, kind: str, reason: str,
                     heliostat_id: str | None = None, data: dict[str, Any] | None = None) -> int:
        """Record a stow, resume, gated, fault, ... event with its reason sentence; returns its id."""
        return self._write(
            "INSERT INTO events (campaign_id, time_s, kind, heliostat_id, reason, data_json) VALUES (?, ?, ?, ?, ?, ?)",
            (int(campaign_id), float(time_s), kind, heliostat_id, reason, _json(data or {})),
        )

    def events(self, campaign_id: int | None = None, kind: str | None = None, *,
               kinds: Sequence[str] | None = None, newest: int | None = None, data: bool = True) -> list[Event]:
        """Events in plant-time order (then recording order), filtered by campaign and kind (``kinds``:
        any of several); ``newest``: only the newest N of them (still oldest first); ``data`` False:
        each event's ``data`` left empty, not read (an event log shows the reasons only)."""
        where, params = _where(campaign_id=campaign_id, kind=kind)
        if kinds is not None:
            where += (" AND" if where else " WHERE") + f" kind IN ({', '.join('?' * len(kinds)) or 'NULL'})"
            params += tuple(kinds)
        # "+time_s" when by kinds: the kind index finds the few rows, sorting them is cheap
        sql = f"SELECT * FROM events{where} ORDER BY {'+time_s' if kinds is not None else 'time_s'}, id"
        if newest is not None:
            sql = (f"SELECT * FROM (SELECT * FROM events{where} ORDER BY time_s DESC, id DESC "
                   f"LIMIT {max(0, int(newest))}) ORDER BY time_s, id")
        if not data:
            sql = sql.replace("SELECT *", "SELECT id, campaign_id, time_s, kind, heliostat_id, reason, '{}' AS data_json")
        return [_event(self.path, r) for r in self._read(sql, params, table="events")]

    def last_event(self, campaign_id: int) -> Event | None:
        """A campaign's event recorded last (the highest row id, whatever its plant time)."""
        rows = self._read("SELECT * FROM events WHERE +campaign_id = ? ORDER BY id DESC LIMIT 1", (int(campaign_id),),
                          table="events")
        return _event(self.path, rows[0]) if rows else None

    def event_kinds(self, campaign_id: int) -> list[str]:
        """The kinds of event a campaign has recorded, sorted."""
        return sorted(r[0] for r in self._read("SELECT DISTINCT kind FROM events WHERE campaign_id = ?",
                                               (int(campaign_id),), table="events"))

    # ------------------------------------------------------------------ operator actions (the console)
    def request_action(self, *, campaign_id: int, kind: str, heliostat_ids: Sequence[str] = (), who: str,
                       requested_wall_s: float, requested_s: float | None) -> int:
        """Record a crew's request (pending until :meth:`finish_action`); returns its id."""
        return self._write(
            "INSERT INTO operator_actions (campaign_id, kind, heliostats_json, who, requested_wall_s, requested_s)"
            " VALUES (?, ?, ?, ?, ?, ?)",
            (int(campaign_id), kind, _json(list(heliostat_ids)), who, float(requested_wall_s), _opt(requested_s)))

    def finish_action(self, action_id: int, *, done_s: float, outcome: str) -> None:
        """Mark an action applied at plant time ``done_s``, with what it did."""
        self._write("UPDATE operator_actions SET done_s = ?, outcome = ? WHERE id = ?",
                    (float(done_s), outcome, int(action_id)))

    def actions(self, campaign_id: int, pending: bool | None = None) -> list[OperatorAction]:
        """A campaign's operator actions, oldest first (``pending`` True: not applied yet; False: applied)."""
        extra = "" if pending is None else (" AND done_s IS NULL" if pending else " AND done_s IS NOT NULL")
        return [OperatorAction(id=r["id"], campaign_id=r["campaign_id"], kind=r["kind"],
                               heliostat_ids=tuple(loads(self.path, "operator_actions", r, "heliostats_json")),
                               who=r["who"],
                               requested_wall_s=r["requested_wall_s"], requested_s=r["requested_s"],
                               done_s=r["done_s"], outcome=r["outcome"])
                for r in self._read(f"SELECT * FROM operator_actions WHERE campaign_id = ?{extra} ORDER BY id",
                                    (int(campaign_id),), table="operator_actions")]

    # ------------------------------------------------------------------ summary
    def progress(self, campaign_id: int) -> list[dict[str, Any]]:
        """Per heliostat of a campaign (in block order): target, visits, observations, valid ones,
        last valid error, and the newest verdict (accepted, RMS, reasons).

        The table ``helicalib status`` prints. A few grouped passes over the indexes, not one query
        per heliostat: about 0.2 s for 10⁴ heliostats and 10⁵ observations.
        """
        cid = (int(campaign_id),)
        helios = self._read("SELECT heliostat_id, target_id FROM heliostats WHERE campaign_id = ? ORDER BY block_index",
                            cid, table="heliostats")
        visits = {r[0]: r[1] for r in self._read(
            "SELECT heliostat_id, COUNT(*) FROM visits WHERE campaign_id = ? GROUP BY heliostat_id", cid)}
        obs = {r["heliostat_id"]: (r["n"], r["n_valid"] or 0, r["error_mrad"]) for r in self._read(
            "SELECT a.heliostat_id, a.n, a.n_valid, o.id, o.error_mrad FROM (SELECT heliostat_id, COUNT(*) AS n, "
            "SUM(valid = 1) AS n_valid, MAX(CASE WHEN valid = 1 THEN id END) AS last_id FROM observations "
            "WHERE campaign_id = ? GROUP BY heliostat_id) AS a LEFT JOIN observations AS o ON o.id = a.last_id", cid,
            table="observations")}
        verdicts = {r["heliostat_id"]: r for r in self._read(
            "SELECT id, heliostat_id, accepted, rms_mrad, reasons_json FROM verdicts WHERE id IN "
            "(SELECT MAX(id) FROM verdicts WHERE campaign_id = ? GROUP BY heliostat_id)", cid, table="verdicts")}
        out = []
        for r in helios:
            hid = r["heliostat_id"]
            n_obs, n_valid, error = obs.get(hid, (0, 0, None))
            v = verdicts.get(hid)
            out.append({"heliostat_id": hid, "target_id": r["target_id"], "visits": visits.get(hid, 0),
                        "observations": n_obs, "valid": n_valid, "last_error_mrad": error,
                        "accepted": None if v is None else bool(v["accepted"]),
                        "rms_mrad": None if v is None else v["rms_mrad"],
                        "reasons": () if v is None or v["reasons_json"] == "[]"  # most: parsing 10⁴ of them costs
                        else tuple(loads(self.path, "verdicts", v, "reasons_json"))})
        return out


# ---------------------------------------------------------------------- helpers

def _recorded_folder(images_dir: Path, db: Path) -> str:
    """How a campaign records its frames folder: relative to the database's folder when inside it
    (it moves with the database), else absolute."""
    folder, base = Path(images_dir).resolve(), Path(db).resolve().parent
    try:
        return folder.relative_to(base).as_posix() or "."
    except ValueError:
        return str(folder)


def database_path(path: str | Path) -> Path:
    """The database file of a path or a ``sqlite:///`` URL."""
    text = str(path)
    return Path(text[len("sqlite:///"):] if text.startswith("sqlite:///") else text)


def existing_database(path: str | Path) -> Path:
    """:func:`database_path`, refused with one line when the file is not there (a command that must
    not create a database: ``status``, ``console``, ``export-paint``, ``prune-frames``)."""
    db = database_path(path)
    if not db.is_file():
        raise ConfigError(f"{path}: no such database file")
    return db


def _connect_readonly(db: Path) -> sqlite3.Connection:
    """A read-only connection that never creates, migrates, writes or deletes a file.

    While a campaign process owns the database (or its write-ahead log exists), ``mode=ro``: WAL
    readers see each committed transaction whole, beside the writer. Otherwise nothing can change
    the file while it is read, and ``immutable=1`` keeps SQLite from creating the ``-wal``/``-shm``
    files a WAL reader would otherwise leave behind."""
    if not db.is_file():
        raise ConfigError(f"{db}: no such database file")
    db = db.resolve()  # the -wal and .lock files sit beside the real file, not beside a symlink
    quiet = not db.with_name(db.name + "-wal").exists() and _lock_holder(_lock_file_of(db)) is None
    try:
        conn = sqlite3.connect(f"{db.resolve().as_uri()}?{'immutable=1' if quiet else 'mode=ro'}", uri=True,
                               timeout=30.0, check_same_thread=False)
        check_schema(conn, str(db))
    except sqlite3.DatabaseError as exc:
        raise _open_error(db, exc) from None
    return conn


def _open_error(db: Path, exc: sqlite3.DatabaseError, writing: bool = False) -> Exception:
    """Damaged pages name the check to run (:class:`DataError`); a writer refused by the file system
    (read-only file or folder, full disk) is a :class:`StorageError`; any other failure to open the
    file as a SQLite database (not one, say) is a :class:`ConfigError`."""
    if is_corrupt(exc):
        return read_error(db, exc)
    if writing and cannot_write(exc):
        return write_error(db, exc)
    return ConfigError(f"{db}: cannot open as a SQLite database ({exc})")


def _probe_write(conn: sqlite3.Connection) -> None:
    """Ask SQLite for a write transaction and roll it back: a file SQLite could open only for reading
    (read-only file, folder or medium) fails here, at the open, not at the first record."""
    try:
        conn.execute("UPDATE schema_version SET version = version WHERE 0")
    finally:
        conn.rollback()


def _lock_file_of(db: Path) -> Path:
    """The owner lock of a database: ``<name>.lock`` beside the file a path resolves to, so that a
    symlink, ``dir/../dir/x.db`` or a symlinked folder all contend for the same lock."""
    real = Path(db).resolve()
    return real.with_name(real.name + ".lock")


def _owner_lock(path: Path, what: str):
    """An exclusive ``flock`` on ``path`` (created), with ``pid: what`` written in it; the open file."""
    import fcntl
    import os

    try:
        fh = open(path, "a+")
    except OSError as exc:
        raise os_write_error(path, exc, "create the database's owner lock") from None
    for attempt in range(20):  # a reader's momentary probe (see _lock_holder) is not an owner: try again
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except OSError:
            if attempt < 19:
                time.sleep(0.05)
    else:
        fh.seek(0)
        holder = fh.read().strip() or "another process"
        fh.close()
        raise ConfigError(f"{path.with_suffix('')}: in use by helicalib ({holder}); one campaign process per "
                          "database: stop it first") from None
    fh.seek(0)
    fh.truncate()
    fh.write(f"pid {os.getpid()}: {what}\n")
    fh.flush()
    return fh


def _lock_holder(path: Path) -> str | None:
    """What holds ``path``'s lock, or None (the file is only opened for reading, never created)."""
    import fcntl

    try:
        fh = open(path)
    except OSError:
        return None
    with fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return fh.read().strip() or "another process"
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
        return None


def _opt(value: float | None) -> float | None:
    return None if value is None else float(value)


def _marks(values: Sequence[Any]) -> str:
    """``?, ?, ...``: one parameter mark for each of ``values`` (an ``IN (...)`` list)."""
    return ", ".join("?" * len(values))


def _where(**filters: Any) -> tuple[str, tuple]:
    parts, params = [], []
    for column, value in filters.items():
        if value is not None:
            parts.append(f"{column} = ?")
            params.append(value)
    return (" WHERE " + " AND ".join(parts) if parts else ""), tuple(params)


def _campaign(db: Path, r: sqlite3.Row) -> Campaign:
    return Campaign(id=r["id"], name=r["name"], mode=r["mode"], started_s=r["started_s"], ended_s=r["ended_s"],
                    status=r["status"], config_path=r["config_path"], config_sha256=r["config_sha256"],
                    settings=loads(db, "campaigns", r, "settings_json"))


def _fit(db: Path, r: sqlite3.Row) -> Fit:
    return Fit(id=r["id"], campaign_id=r["campaign_id"], heliostat_id=r["heliostat_id"], time_s=r["time_s"],
               model=r["model"], params=loads(db, "fits", r, "params_json"), sigma=loads(db, "fits", r, "sigma_json"),
               rms_mrad=r["rms_mrad"], n_points=r["n_points"])


def _verdict(db: Path, r: sqlite3.Row) -> Verdict:
    return Verdict(id=r["id"], campaign_id=r["campaign_id"], heliostat_id=r["heliostat_id"], time_s=r["time_s"],
                   accepted=bool(r["accepted"]), n_points=r["n_points"], rms_mrad=r["rms_mrad"],
                   reasons=tuple(loads(db, "verdicts", r, "reasons_json")),
                   details=loads(db, "verdicts", r, "details_json"))


def _event(db: Path, r: sqlite3.Row) -> Event:
    return Event(id=r["id"], campaign_id=r["campaign_id"], time_s=r["time_s"], kind=r["kind"], reason=r["reason"],
                 heliostat_id=r["heliostat_id"], data=loads(db, "events", r, "data_json"))
