"""Frame retention on a synthetic campaign database with real PNG frames (many heliostats, many
visits): the rule holds row by row, deletions report progress and run outside the store's lock,
``prune-frames`` shows progress only when many files go, and a symlink out of the images folder is
never followed."""

from __future__ import annotations

import json
import shutil
import threading
from collections import defaultdict

import pytest

from helicalib.cli import main
from helicalib.config import load_field_config
from helicalib.errors import DataError
from helicalib.store import Store, retention
from helicalib.store.damage import loads
from helicalib.store.retention import retain_frames
from helicalib.store.synthetic import build_synthetic_campaign, open_for_synthesis

FIELD = "field_config/demo_north.yaml"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """40 heliostats over 12 plant days: commissioning, then checks every 2 days; 8x8 PNG frames."""
    path = tmp_path_factory.mktemp("ret") / "syn.db"
    with open_for_synthesis(path) as store:
        s = build_synthetic_campaign(store, load_field_config(FIELD), days=12, per_day=10, check_every_days=2.0,
                                     invalid_share=0.1, frame_shape=(8, 8))
    return path, s


@pytest.fixture()
def db(built, tmp_path):
    path, _ = built
    shutil.copy(path, tmp_path / "syn.db")
    shutil.copytree(path.parent / "images", tmp_path / "images")
    return tmp_path / "syn.db"


def _paths(o) -> tuple[str, ...]:
    return ((o.before_frame_path,) if o.before_frame_path else ()) + tuple(o.after_frame_paths)


def _files(s: Store) -> set[str]:
    return {p.relative_to(s.images_dir).as_posix() for p in s.images_dir.rglob("*.png")}


@pytest.mark.parametrize("keep_last, keep_invalid", [(2, True), (0, True), (3, False)])
def test_each_heliostat_keeps_its_newest_and_its_rejected_and_nothing_else(db, keep_last, keep_invalid):
    with Store.open(db, owner="test") as s:
        rows = s.observations()
        framed = defaultdict(list)
        for o in sorted(rows, key=lambda o: -o.id):
            if _paths(o):
                framed[o.heliostat_id].append(o)
        keep = {o.id for obs in framed.values() for k, o in enumerate(obs)
                if k < keep_last or (keep_invalid and not o.valid)}
        assert len(framed) == 40 and any(len(v) > keep_last + 2 for v in framed.values())
        r = retain_frames(s, keep_last, keep_invalid=keep_invalid)
        after = {o.id: o for o in s.observations()}
        assert sorted(after) == sorted(o.id for o in rows)  # every observation stays
        assert {i for i, o in after.items() if _paths(o)} == keep  # the synthetic readings share no frame
        on_disk = _files(s)
        assert on_disk == {p for o in after.values() for p in _paths(o)}  # nothing missing, nothing left over
        assert r.kept_files == len(on_disk) and r.observations == sum(1 for o in rows if _paths(o)) - len(keep)
        assert r.files == 2 * r.observations > 0


def test_deletions_report_progress_outside_the_store_s_lock(db, monkeypatch):
    monkeypatch.setattr(retention, "PROGRESS_FILES", 50)
    calls, lock_free = [], []
    with Store.open(db, owner="test") as s:
        def progress(done, total):
            calls.append((done, total))
            t = threading.Thread(target=lambda: lock_free.append(s._lock.acquire(blocking=False)
                                                                 and (s._lock.release() or True)))
            t.start()
            t.join()

        r = retain_frames(s, 1, progress=progress)
    assert r.files > 100
    assert calls[-1] == (r.files, r.files) and [d for d, _ in calls[:-1]] == list(range(50, r.files, 50))
    assert lock_free and all(lock_free)  # a writer thread of the same process is not held up by the deletions


def test_prune_frames_shows_progress_only_when_many_files_go(db, monkeypatch, capsys):
    monkeypatch.setattr(retention, "PROGRESS_FILES", 10**6)
    assert main(["prune-frames", str(db), "--keep-last", "8", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["files"] > 0 and err == ""  # a small pruning says nothing on stderr
    monkeypatch.setattr(retention, "PROGRESS_FILES", 20)
    assert main(["prune-frames", str(db), "--keep-last", "1"]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("deleted ") and "frame files deleted" in err and "prune-frames: done" in err


def test_a_symlink_out_of_the_images_folder_is_kept_and_not_followed(db, tmp_path):
    outside = tmp_path / "elsewhere.png"
    outside.write_bytes(b"not the store's")
    with Store.open(db, owner="test") as s:
        oldest = min((o for o in s.observations() if o.after_frame_paths), key=lambda o: o.id)
        link = s.images_dir / oldest.after_frame_paths[0]
        link.unlink()
        link.symlink_to(outside)
        retain_frames(s, 0, keep_invalid=False)
        again = {o.id: o for o in s.observations()}[oldest.id]
        assert again.after_frame_paths == oldest.after_frame_paths and link.is_symlink()
        assert outside.read_bytes() == b"not the store's"


def test_json_columns_are_checked_item_by_item():
    row = {"id": 7, "params_json": '{"a": 1, "b": 2.5}'}
    assert loads("x.db", "fits", row, "params_json") == {"a": 1, "b": 2.5}
    assert loads("x.db", "fits", {"id": 7, "params_json": "{}"}, "params_json") == {}
    for bad in ('{"a": true}', '{"a": "1"}', '{"a": null}'):
        with pytest.raises(DataError, match="x.db: table fits, row 7: params_json is not a JSON object of numbers"):
            loads("x.db", "fits", {"id": 7, "params_json": bad}, "params_json")
    with pytest.raises(DataError, match="after_frame_paths_json is not a JSON list of strings"):
        loads("x.db", "observations", {"id": 1, "after_frame_paths_json": '["a.png", 3]'}, "after_frame_paths_json")
