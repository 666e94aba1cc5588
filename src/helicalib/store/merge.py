"""Merge the campaigns of several databases into one campaign of one database.

A simulation split over a cluster (:mod:`helicalib.app.split`) runs each group of boards into a
database of its own; :func:`merge_campaigns` writes them into ONE campaign that readers (``status``,
``report``, ``export-paint``, ``operate``) take for one run: every visit, observation, fit,
verdict, event and operator action of each source's newest campaign, in plant-time order across
the sources (a reader that walks ids walks time, as in one run), ids renumbered and every
reference remapped (an observation's visit, its frames' paths). Frames are hard-linked (copied
across file systems) into the destination's ``images/c<campaign>/`` under the names one run would
have given them (``v<visit>_...``). Field-wide events (no heliostat) that several sources recorded
alike, such as a wind stow every group saw, are kept once. The sources are only read.
"""

from __future__ import annotations

import heapq
import json
import os
import re
import shutil
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from helicalib.errors import ConfigError
from helicalib.store.records import CampaignHeliostat
from helicalib.store.sqlite import Store

CHUNK_ROWS = 5000
"""Rows inserted per ``executemany``."""
TIME_COLUMN = {"visits": "started_s", "observations": "capture_time_s", "fits": "time_s", "verdicts": "time_s",
               "events": "time_s", "operator_actions": "requested_wall_s"}
"""The tables merged, in the order they are written (visits first: observations point to them),
and the plant time each is ordered by."""
_FRAME = re.compile(r"^c\d+/(?P<helio>[^/]+)/v(?P<visit>\d+)_(?P<rest>[^/]+)$")


@dataclass(frozen=True)
class MergeResult:
    """The merged campaign's id and the rows written per table (events: after dropping duplicates)."""

    campaign_id: int
    rows: dict[str, int] = field(default_factory=dict)
    frames: int = 0
    duplicate_events: int = 0


def merge_campaigns(sources: Sequence[str | Path], dest: str | Path, *, name: str, mode: str, started_s: float,
                    ended_s: float | None, heliostats: Iterable[CampaignHeliostat | tuple[str, int, str]],
                    status: str = "finished", config_path: str = "", settings: dict[str, Any] | None = None,
                    owner: str = "merge") -> MergeResult:
    """Write the newest campaign of each database in ``sources`` into one new campaign of ``dest``.

    ``heliostats`` are the merged campaign's (all that were planned, also those of a source that
    is missing); ``name``, ``mode``, ``started_s``, ``config_path`` and ``settings`` its row;
    ``ended_s`` and ``status`` (``finished`` or ``stopped``) are set once every row is in. The rows
    are written in one transaction: a merge that fails leaves no half campaign.

    Raises
    ------
    ConfigError
        A source is not a helicalib database of this schema, or holds no campaign.
    """
    with Store.open(dest, "images", durable=False, owner=owner, batched=False) as out:
        cid = out.start_campaign(name=name, mode=mode, started_s=started_s, heliostats=heliostats,
                                 config_path=config_path, settings=settings)
        readers = [_Source(Store.open(path, readonly=True), k) for k, path in enumerate(sources)]
        try:
            return _merge(out, cid, readers, ended_s, status)
        finally:
            for r in readers:
                r.store.close()


class _Source:
    """One source database, its newest campaign and the id maps of what was written from it."""

    def __init__(self, store: Store, index: int):
        self.store, self.index = store, index
        campaigns = store.campaigns()
        if not campaigns:
            raise ConfigError(f"{store.path}: no campaign to merge")
        self.campaign_id = campaigns[-1].id
        self.images = store.campaign_images_dir(self.campaign_id)
        self.visits: dict[int, int] = {}

    def rows(self, table: str, columns: Sequence[str]) -> Iterator[tuple]:
        """The campaign's rows of ``table`` as ``(time, source, old id, row dict)``, in time order."""
        conn = self.store._conn  # the store package's own connection: a read, never a write
        cur = conn.execute(f"SELECT {', '.join(columns)} FROM {table} WHERE campaign_id = ? "
                           f"ORDER BY {TIME_COLUMN[table]}, id", (self.campaign_id,))
        for values in cur:
            row = dict(zip(columns, values))
            yield (float(row[TIME_COLUMN[table]]), self.index, int(row["id"]), row)


def _merge(out: Store, cid: int, sources: list[_Source], ended_s: float | None, status: str) -> MergeResult:
    conn = out._conn
    counts: dict[str, int] = {}
    links: list[tuple[Path, Path]] = []
    duplicates = 0
    with out._writing(), conn:
        for table in TIME_COLUMN:
            columns = [r[1] for r in conn.execute(f"PRAGMA table_info({table})")]
            next_id = int(conn.execute(f"SELECT coalesce(max(id), 0) FROM {table}").fetchone()[0]) + 1
            seen_field_events: set[tuple] = set()
            batch: list[tuple] = []
            written = 0
            for _t, k, old_id, row in heapq.merge(*(s.rows(table, columns) for s in sources)):
                src = sources[k]
                if table == "events" and row["heliostat_id"] is None:
                    key = (row["time_s"], row["kind"], row["reason"], row["data_json"])
                    if key in seen_field_events:
                        duplicates += 1
                        continue
                    seen_field_events.add(key)
                row["id"], row["campaign_id"] = next_id, cid
                if table == "visits":
                    src.visits[old_id] = next_id
                elif table == "observations":
                    _remap_observation(row, src, out, cid, links)
                elif table == "events":
                    _remap_event(row, src)
                batch.append(tuple(row[c] for c in columns))
                next_id += 1
                written += 1
                if len(batch) >= CHUNK_ROWS:
                    _insert(conn, table, columns, batch)
            _insert(conn, table, columns, batch)
            counts[table] = written
        for src_file, dst_file in links:  # before the commit: no row points to a missing frame
            _link(src_file, dst_file)
        conn.execute("UPDATE campaigns SET ended_s = ?, status = ? WHERE id = ?",
                     (None if ended_s is None else float(ended_s), status, cid))
    return MergeResult(cid, counts, len(links), duplicates)


def _insert(conn, table: str, columns: Sequence[str], batch: list[tuple]) -> None:
    if batch:
        conn.executemany(f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))})",
                         batch)
        batch.clear()


def _remap_event(row: dict, src: _Source) -> None:
    """An event that names its visit (a check's ``visit_id``) names the merged visit."""
    text = row.get("data_json")
    if not text or '"visit_id"' not in text:
        return
    data = json.loads(text)
    if isinstance(data, dict) and isinstance(data.get("visit_id"), int) and data["visit_id"] in src.visits:
        data["visit_id"] = src.visits[data["visit_id"]]
        row["data_json"] = json.dumps(data, sort_keys=True)


def _remap_observation(row: dict, src: _Source, out: Store, cid: int, links: list[tuple[Path, Path]]) -> None:
    """The observation's visit id and frame paths in the merged campaign; its frames queued for linking."""
    import json

    if row["visit_id"] is not None:
        row["visit_id"] = src.visits.get(int(row["visit_id"]))

    def moved(rel: str) -> str:
        m = _FRAME.match(rel)
        if m and int(m["visit"]) in src.visits:
            new = f"c{cid}/{m['helio']}/v{src.visits[int(m['visit'])]}_{m['rest']}"
        else:  # not a name the store gives: kept apart, under the source's number
            new = f"c{cid}/g{src.index + 1}/{rel}"
        if (src.images / rel).is_file():
            links.append((src.images / rel, out.images_dir / new))
        return new

    if row["before_frame_path"]:
        row["before_frame_path"] = moved(row["before_frame_path"])
    after = json.loads(row["after_frame_paths_json"] or "[]")
    if after:
        row["after_frame_paths_json"] = json.dumps([moved(p) for p in after], sort_keys=True)


def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists():
        return
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)
