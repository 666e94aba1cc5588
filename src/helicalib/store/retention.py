"""Frame retention: bounded disk for a database that runs for months.

Every observation stays in the database for ever; its frames (PNG files beside it, 0.5–1 MB per
observation) need not. :func:`retain_frames` keeps, per heliostat, the frames of its newest
``keep_last`` observations that have frames, and (by default) those of every observation that was
rejected (not valid: a crew wants to see why), and deletes the rest. A frame file is deleted only
when no kept observation points to it (a visit's "before" frame serves all its placements); the
observations whose frames went have their frame paths cleared in the same transaction, so no row
ever points to a missing file, and the count of such observations is returned.

Only the database's owner prunes (the process that holds its lock: ``helicalib prune-frames``
when no campaign runs); readers never delete anything. The frames of a visit still under way are
kept, and so is any file a path leads to outside the images folder (not the store's to delete); a
folder that holds none of the files to delete (a wrong ``--images``) is refused.

At a plant's size (10⁴ heliostats, months) a pass reads only the observations that still have
frames, in chunks (rows whose frames went before are skipped by the query), resolves each frame
folder once rather than each file, and deletes the files after the rows' transaction, outside the
store's lock: a writer thread of the same process waits only for the scan and the update.
"""

from __future__ import annotations

import os
import sqlite3
import stat
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from helicalib.errors import ConfigError
from helicalib.store.damage import loads

CHUNK_ROWS = 5000
"""Observation rows read at a time."""
PROGRESS_FILES = 2000
"""Files deleted between two calls of ``progress``."""


@dataclass(frozen=True)
class Retention:
    """What a pruning removed (or, with ``dry_run``, would remove).

    Attributes
    ----------
    observations : observations whose frames were removed (their rows stay, paths cleared)
    files : frame files deleted
    bytes : their size on disk [bytes]
    kept_files : frame files still referenced after the pruning
    """

    observations: int
    files: int
    bytes: int
    kept_files: int

    def as_dict(self) -> dict:
        return {"observations": self.observations, "files": self.files, "bytes": self.bytes,
                "kept_files": self.kept_files}


def retain_frames(store, keep_last: int, *, keep_invalid: bool = True, campaign_id: int | None = None,
                  dry_run: bool = False, progress: Callable[[int, int], None] | None = None) -> Retention:
    """Delete the frames of all but each heliostat's newest ``keep_last`` observations (module docstring).

    Parameters
    ----------
    store : Store
        Opened as the owner (``Store.open(..., owner=...)``).
    keep_last : int
        Observations with frames kept per heliostat (0: keep only the rejected ones' frames).
    keep_invalid : bool
        Keep every rejected (not valid) observation's frames as well.
    campaign_id : int, optional
        Only this campaign's observations (default every campaign of the database).
    dry_run : bool
        Count what would go; delete and change nothing (no ownership needed).
    progress : callable, optional
        ``progress(files_deleted, files_to_delete)``, every :data:`PROGRESS_FILES` files deleted and
        after the last (not called when fewer go).
    """
    if keep_last < 0:
        raise ConfigError(f"keep_last: expected a count >= 0, got {keep_last}")
    if not dry_run and store._lock_file is None:
        raise ConfigError(f"{store.path}: only the database's owner deletes frames (open it with owner=...)")
    images = store.images_dir.resolve()
    with store._lock:  # one consistent scan and update, even beside a writer thread of the same process
        files = _Files(images)
        changed, gone, kept_paths = _plan(store, files, keep_last, keep_invalid, campaign_id)
        present = {p: files.sizes[p] for p in gone if p in files.sizes}
        if gone and not present:
            raise ConfigError(f"{store.images_dir}: none of the {len(gone)} frame files to delete is there; is it "
                              "the database's images folder (--images)? Nothing changed")
        result = Retention(len(changed), len(present), int(sum(present.values())), len(kept_paths))
        if dry_run or not gone:
            return result
        # rows first, in one transaction, then the files: a kill in between leaves files that no row
        # points to, never a row that points to a missing file
        store.set_frame_paths([(i, None if before in gone else before, [p for p in after if p not in gone])
                               for i, before, after in changed])
    root = str(images) + os.sep
    for n, p in enumerate(present, 1):  # no row points to these any more: no lock needed
        try:
            os.unlink(root + p)
        except FileNotFoundError:
            pass
        if progress is not None and (n % PROGRESS_FILES == 0 or n == len(present) >= PROGRESS_FILES):
            progress(n, len(present))
    return result


def _plan(store, files: _Files, keep_last: int, keep_invalid: bool, campaign_id: int | None):
    """(observations losing frames as (id, before, after), frame paths to delete, frame paths kept);
    ``files`` learns the size of each path to delete."""
    running = {int(r[0]) for r in store._read("SELECT id FROM visits WHERE outcome = 'running'", table="visits")}
    seen: dict[str, int] = defaultdict(int)
    kept_paths: set[str] = set()
    dropped: list[tuple[int, str | None, list[str]]] = []
    for r in _rows_with_frames(store, campaign_id):
        before, after = r["before_frame_path"], loads(store.path, "observations", r, "after_frame_paths_json")
        paths = ([before] if before else []) + list(after)
        if not paths:
            continue
        hid = r["heliostat_id"]
        # kept: the newest, the rejected, a visit still under way (its next placement reuses its before
        # frame), and any path that does not lie inside the images folder (not ours to delete)
        if (seen[hid] < keep_last or (keep_invalid and not r["valid"]) or r["visit_id"] in running
                or not all(files.inside(p) for p in paths)):
            kept_paths.update(paths)
        else:
            dropped.append((int(r["id"]), before, after))
        seen[hid] += 1
    gone = {p for _i, before, after in dropped for p in ([before] if before else []) + after} - kept_paths
    changed = [(i, before, after) for i, before, after in dropped
               if (before in gone) or any(p in gone for p in after)]
    return changed, gone, kept_paths


def _rows_with_frames(store, campaign_id: int | None) -> Iterator[sqlite3.Row]:
    """The observations that still have a frame path, newest first, read :data:`CHUNK_ROWS` at a time
    (paged by id) through the store's checked reader."""
    where = "(before_frame_path IS NOT NULL OR after_frame_paths_json != '[]')"
    params: tuple = ()
    if campaign_id is not None:
        where, params = f"campaign_id = ? AND {where}", (int(campaign_id),)
    last = None
    while True:
        older, extra = ("", ()) if last is None else (" AND id < ?", (last,))
        rows = store._read("SELECT id, heliostat_id, visit_id, valid, before_frame_path, after_frame_paths_json"
                           f" FROM observations WHERE {where}{older} ORDER BY id DESC LIMIT {CHUNK_ROWS}",
                           params + extra, table="observations")
        yield from rows
        if len(rows) < CHUNK_ROWS:
            return
        last = int(rows[-1]["id"])


class _Files:
    """What the images folder holds at the frame paths asked about: whether each lies inside it
    (resolved: a symlink out of it is outside; each folder resolved once) and, for the regular files
    among them, their size (one ``lstat`` per path, on strings: 10⁵ paths a pass at a plant's size)."""

    def __init__(self, images: Path):
        self.images = images
        self._root = str(images) + os.sep
        self._folders: dict[str, bool] = {}
        self.sizes: dict[str, int] = {}

    def inside(self, rel: str) -> bool:
        folder, _, name = rel.rpartition("/")
        if folder not in self._folders:
            self._folders[folder] = (self.images / folder).resolve().is_relative_to(self.images)
        if not self._folders[folder] or name in ("", ".", ".."):
            return False
        try:
            st = os.lstat(self._root + rel)
        except OSError:  # no file there: nothing to delete, nothing outside
            return True
        if stat.S_ISLNK(st.st_mode):
            target = (self.images / rel).resolve()
            if not target.is_relative_to(self.images):
                return False
            st = target.stat() if target.exists() else st
        if stat.S_ISREG(st.st_mode):
            self.sizes[rel] = st.st_size
        return True
