"""kill -9 at a plant's size loses nothing: a campaign of 10⁴ heliostats, written as a live run
writes (one committed transaction per write, real PNG frames), killed while it records and again
while its nightly frame retention deletes files, then resumed.

The writer is a real process killed with SIGKILL. The database it resumes holds 10⁴ enrolled
heliostats with a visit, a reading and every 4th its frame (built once per module, through the
store's API), so the retention pass it runs scans and prunes a database of that size. (``run --arm``
against ``sim-plant`` at 10⁴ heliostats is the live path; the store underneath is what is killed
here.)
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest
from test_store_sqlite import _obs

from helicalib.store import Store

N = 10_000
FRAME_SHAPE = (12, 16)

WRITER = textwrap.dedent("""
    import dataclasses, sys, time, numpy as np
    sys.path.insert(0, sys.argv[2])
    from test_store_sqlite import _obs
    from helicalib.store import Store
    from helicalib.store import retention
    retention.PROGRESS_FILES = 25  # a progress line every 25 files: the test kills on the first
    s = Store.open(sys.argv[1], durable=False, owner="run (test)")  # a live run: every write committed
    camp = s.unfinished_campaign()
    s.close_interrupted_visits(camp.id, 2e9)
    s.remove_orphan_frames(camp.id)
    start = int(sys.argv[3])

    def deleting(done, total):
        print("deleting", done, total, flush=True)
        time.sleep(3600)  # the test's SIGKILL lands here, inside the pass (else the writer may go on to its next visit)

    frame = np.zeros((12, 16), np.uint8)
    for k in range(start, start + 10**6):
        hid = f"H{k % 10000:05d}"
        vid = s.begin_visit(camp.id, hid, "T1", 1.9e9 + k)
        before = None
        for it in range(2):  # two placements sharing the visit's before frame, as a visit records them
            frame[k % 12, it] = 255
            obs = _obs(camp.id, vid, it, hid=hid, t=1.9e9 + 100 * k, valid=(k % 7 != 3))
            if before is not None:
                obs = dataclasses.replace(obs, before_frame_path=before)
            oid = s.record_observation(obs, before_frame=frame if before is None else None, after_frames=[frame])
            before = before or s._read("SELECT before_frame_path FROM observations WHERE id = ?", (oid,))[0][0]
            print("obs", oid, flush=True)
        s.end_visit(vid, ended_s=1.9e9 + k + 50, outcome="converged", iterations=2)
        if k % 40 == 39:  # the nightly retention, in the writer's process, as operate runs it
            print("prune", flush=True)
            retention.retain_frames(s, 1, progress=deleting)
            print("pruned", flush=True)
""")


@pytest.fixture(scope="module")
def field_db(tmp_path_factory):
    """10⁴ enrolled heliostats, one finished visit with a reading each; every 4th reading has its frame
    (frames cost most of the build; the retention scans the readings with frames)."""
    db = tmp_path_factory.mktemp("k9") / "plant.db"
    ids = [f"H{i:05d}" for i in range(N)]
    frame = np.zeros(FRAME_SHAPE, np.uint8)
    with Store.open(db, durable=False, batched=True) as s:
        cid = s.start_campaign(name="10k", mode="live", started_s=1.8e9,
                               heliostats=[(h, i, f"T{i % 8 + 1}") for i, h in enumerate(ids)])
        for i, h in enumerate(ids):
            vid = s.begin_visit(cid, h, "T1", 1.8e9 + i)
            frame[i % 12, i % 16] ^= 255
            s.record_observation(_obs(cid, vid, hid=h, t=1.8e9 + i), after_frames=[frame] if i % 4 == 0 else None)
            s.end_visit(vid, ended_s=1.8e9 + i + 30, outcome="converged", iterations=1)
    return db


def _writer(db, tmp_path, start: int):
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    here = os.path.dirname(os.path.abspath(__file__))
    return subprocess.Popen([sys.executable, str(script), str(db), here, str(start)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _kill_when(proc, stop) -> tuple[list[int], list[str]]:
    """Read the writer's lines until ``stop(line)``, then SIGKILL it; (observation ids it reported, lines)."""
    ids, lines = [], []
    try:
        for line in proc.stdout:
            lines.append(line.strip())
            if line.startswith("obs "):
                ids.append(int(line.split()[1]))
            if stop(line):
                break
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
        err = proc.stderr.read()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL, err
    return ids, lines


def _consistent(db) -> list:
    """Every frame a row points to is on disk, and those the writer wrote are whole PNGs (a kill may
    land mid-frame); returns the observations."""
    with Store.open(db, readonly=True) as s:
        rows = s.observations()
        root = str(s.images_dir) + os.sep
        for o in rows:
            for rel in (o.before_frame_path, *o.after_frame_paths):
                if rel:
                    assert os.path.isfile(root + rel), (o.id, rel)
                    if o.id > N:
                        img = cv2.imread(root + rel, cv2.IMREAD_UNCHANGED)
                        assert img is not None and img.shape == FRAME_SHAPE, (o.id, rel)
    return rows


def test_kill_9_while_recording_and_while_pruning_loses_nothing_at_10k(field_db, tmp_path):
    from helicalib.store.retention import retain_frames

    db = tmp_path / "plant.db"
    shutil.copy(field_db, db)
    # hard links: the writer's retention deletes links, never the module fixture's files
    shutil.copytree(field_db.parent / "images", tmp_path / "images", copy_function=os.link)

    # killed while it records (mid-visit, after 30 readings)
    ids1, _ = _kill_when(_writer(db, tmp_path, 0),
                         lambda line: line.startswith("obs ") and int(line.split()[1]) >= N + 30)
    rows = _consistent(db)
    assert set(ids1) <= {o.id for o in rows}

    # resumed, then killed while its nightly retention deletes files (the rows' transaction done)
    ids2, lines = _kill_when(_writer(db, tmp_path, 120), lambda line: line.startswith("deleting"))
    assert "prune" in lines and "pruned" not in lines  # the kill landed inside the pass
    done, total = (int(x) for x in lines[-1].split()[1:])
    rows = _consistent(db)  # no row points to a missing or partial frame
    assert set(ids1) | set(ids2) <= {o.id for o in rows} and len({o.id for o in rows}) == len(rows)

    # the next owner: temporary files gone, the interrupted visits closed, the retention completes
    with Store.open(db, owner="test") as s:
        assert not list((s.images_dir / "c1").glob("*/.*.tmp"))
        camp = s.unfinished_campaign()
        assert camp is not None and len(s.campaigns()) == 1
        s.close_interrupted_visits(camp.id, 2e9)
        assert not [v for v in s.visits(camp.id) if v.outcome == "running"]
        r = retain_frames(s, 1)
        assert r.files == 0  # the killed pass had committed its rows: nothing more to prune
        after = s.observations()
        assert [o.id for o in after] == [o.id for o in rows]  # every observation row stays, pruned or not
        assert len({h.heliostat_id for h in s.campaign_heliostats(camp.id)}) == N
    rows = _consistent(db)
    with Store.open(db, readonly=True) as s:  # what the kill cost: at most the rest of that pass's files, on disk
        on_disk = {p.relative_to(s.images_dir).as_posix() for p in s.images_dir.rglob("*.png")}
    referenced = {p for o in rows for p in ((o.before_frame_path,) if o.before_frame_path else ()) + o.after_frame_paths}
    assert referenced <= on_disk and len(on_disk - referenced) <= total - done
    # the newest valid placement keeps its frames (its visit mate keeps only the shared before frame)
    framed = [o for o in rows if o.after_frame_paths and o.valid]
    assert all(len([o for o in framed if o.heliostat_id == h]) <= 1 for h in ("H00000", "H00001", "H00150"))
