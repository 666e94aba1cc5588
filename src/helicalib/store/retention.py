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
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

from helicalib.errors import ConfigError
from helicalib.store.damage import loads


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
                  dry_run: bool = False) -> Retention:
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
    """
    if keep_last < 0:
        raise ConfigError(f"keep_last: expected a count >= 0, got {keep_last}")
    if not dry_run and store._lock_file is None:
        raise ConfigError(f"{store.path}: only the database's owner deletes frames (open it with owner=...)")
    with store._lock:  # one consistent pass, even beside a writer thread of the same process
        return _retain(store, keep_last, keep_invalid, campaign_id, dry_run)


def _retain(store, keep_last: int, keep_invalid: bool, campaign_id: int | None, dry_run: bool) -> Retention:
    images = store.images_dir.resolve()

    def inside(rel: str) -> bool:  # a frame path is the database's word: never touch a file outside the folder
        return (images / rel).resolve().is_relative_to(images)

    where, params = ("WHERE campaign_id = ?", (int(campaign_id),)) if campaign_id is not None else ("", ())
    rows = store._read("SELECT id, heliostat_id, visit_id, valid, before_frame_path, after_frame_paths_json "
                       f"FROM observations {where} ORDER BY id DESC", params, table="observations")
    running = {int(r[0]) for r in store._read("SELECT id FROM visits WHERE outcome = 'running'", table="visits")}
    seen: dict[str, int] = defaultdict(int)
    kept_paths: set[str] = set()
    dropped: list[tuple[int, str | None, list[str]]] = []
    for r in rows:
        before, after = r["before_frame_path"], loads(store.path, "observations", r, "after_frame_paths_json")
        paths = ([before] if before else []) + list(after)
        if not paths:
            continue
        hid = r["heliostat_id"]
        # kept: the newest, the rejected, a visit still under way (its next placement reuses its before
        # frame), and any path that does not lie inside the images folder (not ours to delete)
        if (seen[hid] < keep_last or (keep_invalid and not r["valid"]) or r["visit_id"] in running
                or not all(inside(p) for p in paths)):
            kept_paths.update(paths)
        else:
            dropped.append((int(r["id"]), before, after))
        seen[hid] += 1
    gone = {p for _i, before, after in dropped for p in ([before] if before else []) + after} - kept_paths
    present = {p for p in gone if (images / p).is_file()}
    if gone and not present:
        raise ConfigError(f"{store.images_dir}: none of the {len(gone)} frame files to delete is there; is it the "
                          "database's images folder (--images)? Nothing changed")
    size = sum((images / p).stat().st_size for p in present)
    changed = [(i, before, after) for i, before, after in dropped
               if (before in gone) or any(p in gone for p in after)]
    result = Retention(len(changed), len(present), int(size), len(kept_paths))
    if dry_run or not gone:
        return result
    # rows first, in one transaction, then the files: a kill in between leaves files that no row
    # points to, never a row that points to a missing file
    store.set_frame_paths([(i, None if before in gone else before, [p for p in after if p not in gone])
                           for i, before, after in changed])
    for p in present:
        (images / p).unlink(missing_ok=True)
    return result
