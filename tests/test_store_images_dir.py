"""Where a reader finds a campaign's frames: the database's own frames folder when it holds them (a
database moved or copied with its frames), else the folder recorded at the campaign's start."""

from __future__ import annotations

import shutil

from helicalib.store.sqlite import Store


def _campaign_with_a_frame(db, images) -> int:
    with Store.open(db, images) as store:
        cid = store.start_campaign(name="t", mode="simulate", started_s=0.0, heliostats=[("H0001", 0, "T1")])
        (store.images_dir / f"c{cid}").mkdir(parents=True)
        (store.images_dir / f"c{cid}" / "frame.png").write_bytes(b"\x89PNG")
        return cid


def test_frames_beside_the_database_are_recorded_relative_and_move_with_it(tmp_path):
    cid = _campaign_with_a_frame(tmp_path / "a" / "c.db", "img")
    with Store.open(tmp_path / "a" / "c.db", readonly=True) as store:
        assert store.campaign(cid).settings["images_dir"] == "img"
        assert store.campaign_images_dir(cid) == tmp_path / "a" / "img"
    shutil.copytree(tmp_path / "a", tmp_path / "b")  # the database archived with its frames
    shutil.rmtree(tmp_path / "a")
    with Store.open(tmp_path / "b" / "c.db", readonly=True) as store:
        assert store.campaign_images_dir(cid) == tmp_path / "b" / "img"


def test_frames_written_elsewhere_are_found_where_they_were_written(tmp_path):
    elsewhere = tmp_path / "frames"
    cid = _campaign_with_a_frame(tmp_path / "a" / "c.db", elsewhere)
    with Store.open(tmp_path / "a" / "c.db", readonly=True) as store:  # a reader: images beside the database
        assert store.images_dir == tmp_path / "a" / "images"
        assert store.campaign_images_dir(cid) == elsewhere.resolve()


def test_a_copy_with_its_own_frames_shows_its_own_not_the_originals(tmp_path):
    cid = _campaign_with_a_frame(tmp_path / "a" / "c.db", tmp_path / "frames")
    (tmp_path / "b").mkdir()
    shutil.copy(tmp_path / "a" / "c.db", tmp_path / "b" / "c.db")
    shutil.copytree(tmp_path / "frames", tmp_path / "b" / "images")
    with Store.open(tmp_path / "b" / "c.db", readonly=True) as store:
        assert store.campaign_images_dir(cid) == tmp_path / "b" / "images"
