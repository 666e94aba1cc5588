"""Frame retention on a real SQLite file with real PNG frames: bounded disk, every row kept,
no row pointing to a missing file."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from helicalib.errors import ConfigError
from helicalib.store import Store
from helicalib.store.retention import retain_frames
from test_store_sqlite import _obs

FRAME = np.zeros((24, 32), np.uint8)


def _campaign(db, visits=5, heliostats=("H0001", "H0002"), invalid_every=3):
    """Per heliostat ``visits`` visits of two placements sharing the visit's before frame; every
    ``invalid_every``-th placement rejected. Returns {heliostat: [observation ids, oldest first]}."""
    ids = {h: [] for h in heliostats}
    with Store.open(db, owner="test") as s:
        cid = s.start_campaign(name="r", mode="simulate", started_s=0.0,
                               heliostats=[(h, i, "T1") for i, h in enumerate(heliostats)])
        n = 0
        for v in range(visits):
            for h in heliostats:
                vid = s.begin_visit(cid, h, "T1", float(v))
                before = None
                for i in range(2):
                    n += 1
                    frame = FRAME.copy()
                    frame[n % 24] = 255
                    valid = n % invalid_every != 0
                    obs = _obs(cid, vid, i, valid=valid, hid=h, t=1_750_000_000.0 + 100 * n)
                    if before is not None:
                        obs = dataclasses.replace(obs, before_frame_path=before)
                    oid = s.record_observation(obs, before_frame=frame if before is None else None, after_frames=[frame])
                    before = before or s.observations(heliostat_id=h)[-1].before_frame_path
                    ids[h].append(oid)
                s.end_visit(vid, ended_s=float(v) + 0.5, outcome="converged", iterations=2)
    return ids


def _files(s: Store) -> set[str]:
    return {p.relative_to(s.images_dir).as_posix() for p in s.images_dir.rglob("*.png")}


def _referenced(s: Store) -> set[str]:
    return {p for o in s.observations() for p in ((o.before_frame_path,) if o.before_frame_path else ())
            + tuple(o.after_frame_paths)}


def test_keeps_the_newest_and_the_rejected_and_every_row(tmp_path):
    db = tmp_path / "r.db"
    ids = _campaign(db)
    with Store.open(db, owner="test") as s:
        before_rows = s.observations()
        files_before = _files(s)
        assert files_before == _referenced(s)
        dry = retain_frames(s, 2, dry_run=True)
        assert _files(s) == files_before  # a dry run deletes nothing
        result = retain_frames(s, 2)
        assert dataclasses.astuple(result) == dataclasses.astuple(dry)
        rows = {o.id: o for o in s.observations()}
        assert len(rows) == len(before_rows)  # every observation stays
        files = _files(s)
        assert _referenced(s) <= files  # no row points to a missing file
        assert files == _referenced(s)  # and nothing is left unreferenced
        assert len(files_before) - len(files) == result.files > 0
        for h, oids in ids.items():
            newest = oids[-2:]
            rejected = [i for i in oids if not rows[i].valid]
            for i in oids:
                o = rows[i]
                has = bool(o.after_frame_paths)
                assert has == (i in newest or i in rejected), (h, i)
                if i in newest or i in rejected:  # its before frame stays too, shared or not
                    assert o.before_frame_path in files
        assert result.observations == sum(1 for o in before_rows if o.after_frame_paths) - sum(
            1 for o in rows.values() if o.after_frame_paths)


def test_a_shared_before_frame_stays_while_one_placement_keeps_it(tmp_path):
    db = tmp_path / "r.db"
    ids = _campaign(db, visits=2, heliostats=("H0001",), invalid_every=1000)
    with Store.open(db, owner="test") as s:
        retain_frames(s, 1)  # the newest placement only: the older placement of that visit loses its after frame
        rows = {o.id: o for o in s.observations()}
        last, second_last = rows[ids["H0001"][-1]], rows[ids["H0001"][-2]]
        assert last.visit_id == second_last.visit_id
        assert not second_last.after_frame_paths and second_last.before_frame_path == last.before_frame_path
        assert (s.images_dir / last.before_frame_path).is_file()
        first_visit = [rows[i] for i in ids["H0001"][:2]]
        assert all(o.before_frame_path is None and not o.after_frame_paths for o in first_visit)


def test_disk_stays_bounded_as_the_database_grows(tmp_path):
    db = tmp_path / "r.db"
    sizes = []
    for visits in (3, 6, 12):
        _campaign(db, visits=visits, invalid_every=10**6)
        with Store.open(db, owner="test") as s:
            retain_frames(s, 4)
            sizes.append(len(_files(s)))
            assert len(s.observations()) > 0
    # two heliostats x 4 newest placements: at most 4 after frames and 4 before frames each
    assert sizes[-1] == sizes[0] and sizes[-1] <= 2 * (4 + 4)


def test_only_the_owner_prunes(tmp_path):
    db = tmp_path / "r.db"
    _campaign(db, visits=2)
    with Store.open(db, readonly=True) as s:
        with pytest.raises(ConfigError, match="only the database's owner"):
            retain_frames(s, 0)
        assert retain_frames(s, 0, dry_run=True).files > 0  # a reader may count
    with Store.open(db, owner="test") as s, pytest.raises(ConfigError, match="keep_last"):
        retain_frames(s, -1)


def test_prune_frames_command(tmp_path):
    db = tmp_path / "r.db"
    _campaign(db, visits=3)
    cmd = [sys.executable, "-m", "helicalib", "prune-frames", str(db), "--keep-last", "1", "--json"]
    with Store.open(db, owner="a running campaign"):  # the owner lock is held: refused, one line
        busy = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert busy.returncode == 1 and "in use by helicalib" in busy.stderr and len(busy.stderr.strip().splitlines()) == 1
    dry = subprocess.run(cmd + ["--dry-run"], capture_output=True, text=True, timeout=60)
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert dry.returncode == 0 and done.returncode == 0, (dry.stderr, done.stderr)
    a, b = json.loads(dry.stdout), json.loads(done.stdout)
    assert a["dry_run"] and not b["dry_run"] and a["files"] == b["files"] > 0
    again = json.loads(subprocess.run(cmd, capture_output=True, text=True, timeout=60).stdout)
    assert again["files"] == 0  # nothing more to delete
    bad = subprocess.run(cmd[:-3] + ["--keep-last", "-2"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--keep-last" in bad.stderr


def test_never_a_file_outside_the_images_folder_nor_of_a_visit_under_way(tmp_path):
    db = tmp_path / "r.db"
    ids = _campaign(db, visits=3, heliostats=("H0001",), invalid_every=10**6)
    precious = tmp_path / "precious.txt"
    precious.write_text("not a frame")
    with Store.open(db, owner="test") as s:
        oldest = ids["H0001"][0]
        s.set_frame_paths([(oldest, None, ["../precious.txt"])])  # a path the database should never hold
        running_visit = s.begin_visit(s.campaigns()[-1].id, "H0001", "T1", 99.0)  # a visit under way
        frame = FRAME.copy()
        oid = s.record_observation(_obs(s.campaigns()[-1].id, running_visit, 0, t=1_800_000_000.0),
                                   before_frame=frame, after_frames=[frame])
        before_of_running = s.observations()[-1].before_frame_path
        retain_frames(s, 0)
        assert precious.read_text() == "not a frame"
        rows = {o.id: o for o in s.observations()}
        assert rows[oldest].after_frame_paths == ("../precious.txt",)  # not ours: left as it was
        assert rows[oid].before_frame_path == before_of_running and (s.images_dir / before_of_running).is_file()


def test_a_wrong_images_folder_is_refused_and_changes_nothing(tmp_path):
    db = tmp_path / "r.db"
    _campaign(db, visits=3)
    with Store.open(db, tmp_path / "elsewhere", owner="test") as s:
        rows = s.observations()
        with pytest.raises(ConfigError, match="none of the .* frame files to delete is there"):
            retain_frames(s, 1)
        assert s.observations() == rows
