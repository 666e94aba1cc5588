"""The campaign store: round trips on a real SQLite file, resume, and kill -9 losing nothing."""

from __future__ import annotations

from dataclasses import replace

import csv
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from helicalib.errors import ConfigError, MeasurementError
from helicalib.store import OBSERVATION_COLUMNS, SCHEMA_VERSION, Observation, Store


def _obs(cid, vid, i=0, *, valid=True, hid="H0001", t=1_750_000_000.0, error=1.25):
    return Observation(
        campaign_id=cid, heliostat_id=hid, target_id="T1", visit_id=vid, iteration=i, capture_time_s=t + i,
        strokes_cmd_mm=(812.5, 640.25), strokes_read_mm=(812.4, 640.3), sun_enu=(0.1, -0.6, float(np.sqrt(1 - 0.37))),
        sun_azimuth_deg=170.5, sun_elevation_deg=52.2, sun_rising=True, wind_ms=3.2, wind_direction_deg=270.0,
        dni_wm2=850.0, temperature_c=21.5, cleanliness=0.93, valid=valid,
        reason="ok" if valid else "no_spot", message="" if valid else "no spot in the difference image",
        offset_u_m=0.12 if valid else None, offset_v_m=-0.3 if valid else None,
        spot_x_px=640.5 if valid else None, spot_y_px=500.25 if valid else None, spot_area_px=1500.0 if valid else None,
        threshold=37.0, jitter_px=0.4 if valid else None, spot_enu_m=(0.12, 9.0, 119.7) if valid else None,
        error_mrad=error if valid else None, approach=(1, -1),
    )


@pytest.fixture
def store(tmp_path):
    s = Store.open(tmp_path / "db" / "campaign.db")
    yield s
    s.close()


def test_open_creates_wal_database_with_schema_version(tmp_path):
    path = tmp_path / "c.db"
    Store.open(f"sqlite:///{path}").close()
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert conn.execute("SELECT version FROM schema_version").fetchone()[0] == SCHEMA_VERSION
    conn.close()


def test_newer_schema_and_foreign_database_are_refused(tmp_path):
    newer = tmp_path / "newer.db"
    Store.open(newer).close()
    conn = sqlite3.connect(newer)
    conn.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION + 1,))
    conn.commit()
    conn.close()
    with pytest.raises(ConfigError, match="newer"):
        Store.open(newer)
    foreign = tmp_path / "foreign.db"
    conn = sqlite3.connect(foreign)
    conn.execute("CREATE TABLE stuff (x)")
    conn.commit()
    conn.close()
    with pytest.raises(ConfigError, match="not a helicalib database"):
        Store.open(foreign)


def test_version_1_database_is_migrated_in_place_and_keeps_its_rows(tmp_path):
    """A database of schema version 1 (no approach columns) opens, gains the columns, keeps every
    row (approach unknown: None) and takes new observations with their approach."""
    path = tmp_path / "v1.db"
    s = Store.open(path)
    cid = s.start_campaign(name="old", mode="simulate", started_s=1.0, heliostats=[("H0001", 0, "T1")])
    vid = s.begin_visit(cid, "H0001", "T1", 1_750_000_000.0)
    s.record_observation(_obs(cid, vid))
    s.close()
    conn = sqlite3.connect(path)  # make it what helicalib's schema version 1 wrote
    conn.execute("ALTER TABLE observations DROP COLUMN approach_1")
    conn.execute("ALTER TABLE observations DROP COLUMN approach_2")
    conn.execute("DROP TABLE operator_actions")
    conn.execute("ALTER TABLE observations DROP COLUMN exposure_ms")
    conn.execute("UPDATE schema_version SET version = 1")
    conn.commit()
    conn.close()
    s = Store.open(path)
    old = s.observations()
    assert len(old) == 1 and old[0].approach is None and old[0].strokes_read_mm == pytest.approx((812.4, 640.3))
    assert old[0].exposure_ms is None
    s.record_observation(replace(_obs(cid, vid, 1), exposure_ms=2.5))
    assert [o.approach for o in s.observations()] == [None, (1, -1)]
    assert [o.exposure_ms for o in s.observations()] == [None, 2.5]
    s.close()
    conn = sqlite3.connect(path)
    assert conn.execute("SELECT version FROM schema_version").fetchone()[0] == SCHEMA_VERSION == 4
    assert conn.execute("SELECT COUNT(*) FROM operator_actions").fetchone()[0] == 0  # version 3 made it
    conn.close()


def test_observation_round_trip_with_frames(store):
    cid = store.start_campaign(name="demo", mode="simulate", started_s=1.0, heliostats=[("H0001", 0, "T1")],
                               settings={"seed": 1})
    vid = store.begin_visit(cid, "H0001", "T1", 1_750_000_000.0)
    before = np.full((48, 64), 20, np.uint8)
    after = before.copy()
    after[10:20, 30:40] = 250
    obs = _obs(cid, vid)
    oid = store.record_observation(obs, before_frame=before, after_frames=[after, after])
    back = store.observations()[0]
    assert back.id == oid
    # every field given comes back unchanged
    for name in ("heliostat_id", "target_id", "visit_id", "iteration", "capture_time_s", "strokes_cmd_mm",
                 "strokes_read_mm", "approach", "sun_enu", "sun_rising", "wind_ms", "dni_wm2", "cleanliness", "valid",
                 "offset_u_m", "spot_enu_m", "error_mrad", "threshold", "jitter_px"):
        expected = getattr(obs, name)
        if isinstance(expected, (str, bool)) or expected is None:
            assert getattr(back, name) == expected, name
        else:
            assert getattr(back, name) == pytest.approx(expected), name
    assert len(back.after_frame_paths) == 2
    img = cv2.imread(str(store.images_dir / back.after_frame_path), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(img, after)
    assert np.array_equal(cv2.imread(str(store.images_dir / back.before_frame_path), cv2.IMREAD_UNCHANGED), before)
    assert store.images_dir == store.path.parent / "images"


def test_png_bytes_kept_and_jpeg_converted_and_garbage_refused(store):
    cid = store.start_campaign(name="x", mode="live", started_s=0.0, heliostats=[])
    img = (np.arange(32 * 32) % 251).astype(np.uint8).reshape(32, 32)
    png = cv2.imencode(".png", img)[1].tobytes()
    rel = store.save_frame(png, campaign_id=cid, heliostat_id="H/1", visit_id=None, iteration=0,
                           capture_time_s=5.0, kind="after")
    assert (store.images_dir / rel).read_bytes() == png
    assert "/" not in Path(rel).parent.name  # the odd id is made safe for a file name
    jpg = cv2.imencode(".jpg", img)[1].tobytes()
    rel2 = store.save_frame(jpg, campaign_id=cid, heliostat_id="H1", visit_id=3, iteration=1,
                            capture_time_s=5.0, kind="after")
    assert (store.images_dir / rel2).read_bytes().startswith(b"\x89PNG")
    # the same name twice does not overwrite the first frame
    rel3 = store.save_frame(jpg, campaign_id=cid, heliostat_id="H1", visit_id=3, iteration=1,
                            capture_time_s=5.0, kind="after")
    assert rel3 != rel2 and (store.images_dir / rel2).exists()
    with pytest.raises(MeasurementError, match="neither PNG nor JPEG"):
        store.save_frame(b"<html>oops</html>", campaign_id=cid, heliostat_id="H1", visit_id=3, iteration=1,
                         capture_time_s=5.0, kind="after")


def test_filters_fits_verdicts_events_and_progress(store):
    cid = store.start_campaign(name="a", mode="live", started_s=0.0,
                               heliostats=[("H0001", 0, "T1"), ("H0002", 1, "T1")])
    v1 = store.begin_visit(cid, "H0001", "T1", 10.0)
    store.record_observation(_obs(cid, v1, 0, valid=False))
    store.record_observation(_obs(cid, v1, 1, valid=True, error=0.8))
    store.end_visit(v1, ended_s=20.0, outcome="valid", iterations=2, first_error_mrad=None, final_error_mrad=0.8)
    v2 = store.begin_visit(cid, "H0002", "T1", 30.0)
    store.record_observation(_obs(cid, v2, 0, hid="H0002", error=2.5))
    assert [o.valid for o in store.observations(heliostat_id="H0001")] == [False, True]
    assert len(store.observations(valid=True)) == 2
    assert len(store.observations(heliostat_id="H0001", valid=False)) == 1
    assert store.count_observations(cid, valid=True) == 2

    assert store.latest_fit("H0001") is None
    store.record_fit(campaign_id=cid, heliostat_id="H0001", time_s=21.0, model="m", params={"a_mrad": 1.0},
                     sigma={"a_mrad": 0.1}, rms_mrad=0.5, n_points=1)
    store.record_fit(campaign_id=cid, heliostat_id="H0001", time_s=22.0, model="m", params={"a_mrad": np.float64(2.0)},
                     sigma={"a_mrad": 0.2}, rms_mrad=0.4, n_points=2)
    fit = store.latest_fit("H0001")
    assert fit.params == {"a_mrad": 2.0} and fit.n_points == 2 and fit.time_s == 22.0

    store.record_verdict(campaign_id=cid, heliostat_id="H0001", time_s=21.0, accepted=False, n_points=1,
                         rms_mrad=0.8, reasons=["too few"])
    store.record_verdict(campaign_id=cid, heliostat_id="H0001", time_s=40.0, accepted=True, n_points=5,
                         rms_mrad=0.7, reasons=[])
    verdicts = store.latest_verdicts(cid)
    assert set(verdicts) == {"H0001"} and verdicts["H0001"].accepted and verdicts["H0001"].time_s == 40.0

    store.record_event(campaign_id=cid, time_s=50.0, kind="stow", reason="wind 16.0 m/s > 15.0 m/s")
    store.record_event(campaign_id=cid, time_s=45.0, kind="gated", reason="DNI low", data={"dni_wm2": 120})
    events = store.events(cid)
    assert [e.kind for e in events] == ["gated", "stow"] and events[0].data == {"dni_wm2": 120}
    assert [e.kind for e in store.events(cid, kind="stow")] == ["stow"]

    rows = {r["heliostat_id"]: r for r in store.progress(cid)}
    assert rows["H0001"]["visits"] == 1 and rows["H0001"]["observations"] == 2 and rows["H0001"]["valid"] == 1
    assert rows["H0001"]["accepted"] is True and rows["H0002"]["accepted"] is None
    assert rows["H0002"]["last_error_mrad"] == pytest.approx(2.5)


def test_export_csv_has_flat_columns(store, tmp_path):
    cid = store.start_campaign(name="a", mode="live", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    store.record_observation(_obs(cid, None, 0))
    store.record_observation(_obs(cid, None, 1, valid=False))
    out = tmp_path / "out" / "obs.csv"
    assert store.export_observations_csv(out) == 2
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == OBSERVATION_COLUMNS
    assert float(rows[0]["stroke_cmd_1_mm"]) == 812.5 and rows[1]["error_mrad"] == ""
    assert store.export_observations_csv(tmp_path / "v.csv", valid=True) == 1


def test_fit_csv_export_reads_back_with_the_fit_reader(store, tmp_path):
    from helicalib.calibration.observations import read_observations

    cid = store.start_campaign(name="a", mode="live", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    store.record_observation(_obs(cid, None, 0))
    store.record_observation(_obs(cid, None, 1, valid=False))
    n = store.export_fit_csv(tmp_path / "fit.csv", campaign_id=cid)
    rows = read_observations(tmp_path / "fit.csv")
    assert n == 1 and len(rows) == 1
    row = rows[0]
    assert row.stroke1_mm == 812.4 and row.target_v_m == -0.3 and row.source == "campaign"
    assert row.utc_time.startswith("2025-06-15T15:06:40")


def test_resume_finds_newest_unfinished_campaign_and_closes_running_visits(tmp_path):
    path = tmp_path / "c.db"
    with Store.open(path) as s:
        old = s.start_campaign(name="old", mode="live", started_s=0.0, heliostats=[("H0001", 0, "T1")])
        s.finish_campaign(old, 5.0)
        cid = s.start_campaign(name="new", mode="live", started_s=10.0, heliostats=[("H0001", 0, "T1")],
                               config_sha256="abc")
        vid = s.begin_visit(cid, "H0001", "T1", 11.0)
        s.record_observation(_obs(cid, vid))
    with Store.open(path) as s:
        camp = s.unfinished_campaign()
        assert camp.id == cid and camp.config_sha256 == "abc" and camp.status == "running"
        assert s.unfinished_campaign(mode="simulate") is None
        assert s.close_interrupted_visits(cid, 99.0) == 1
        visit = s.visits(cid)[0]
        assert visit.outcome == "interrupted" and visit.ended_s == 99.0
        assert len(s.observations(cid)) == 1
        assert [h.heliostat_id for h in s.campaign_heliostats(cid)] == ["H0001"]
        s.finish_campaign(cid, 100.0)
        assert s.unfinished_campaign() is None


WRITER = textwrap.dedent("""
    import sys, numpy as np
    from helicalib.store import Observation, Store
    s = Store.open(sys.argv[1], durable=False)
    cid = s.start_campaign(name="k", mode="simulate", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    frame = np.zeros((240, 320), np.uint8)
    i = 0
    while True:
        frame[i % 240, :] = 255
        vid = s.begin_visit(cid, "H0001", "T1", float(i))
        oid = s.record_observation(Observation(
            campaign_id=cid, heliostat_id="H0001", target_id="T1", visit_id=vid, iteration=0,
            capture_time_s=float(i), strokes_cmd_mm=(1.0, 2.0), strokes_read_mm=None, sun_enu=(0.0, 0.0, 1.0),
            sun_azimuth_deg=0.0, sun_elevation_deg=90.0, valid=True, error_mrad=float(i)),
            before_frame=frame, after_frames=[frame])
        print(oid, flush=True)
        i += 1
""")


def test_kill_9_loses_no_recorded_observation(tmp_path):
    db = tmp_path / "k.db"
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    proc = subprocess.Popen([sys.executable, str(script), str(db)], stdout=subprocess.PIPE, text=True)
    reported = []
    try:
        for line in proc.stdout:
            reported.append(int(line))
            if len(reported) >= 40:
                break
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    # the kill may land mid-frame; make sure a half-written frame is there either way
    leftover = db.parent / "images" / "c1" / "H0001" / ".v999_i0_after0.png.4242.tmp"
    leftover.write_bytes(b"partial")
    with Store.open(db) as s:  # a reader sees everything and deletes nothing
        assert set(reported) <= {o.id for o in s.observations()}
    assert leftover.exists()
    with Store.open(db, owner="run") as s:  # the next owner removes the half-written frames
        stored = s.observations()
        ids = {o.id for o in stored}
        assert set(reported) <= ids  # every id the writer had been told about is there
        for o in stored:  # and no row points to a missing or partial frame
            for rel in (o.before_frame_path, *o.after_frame_paths):
                img = cv2.imread(str(s.images_dir / rel), cv2.IMREAD_UNCHANGED)
                assert img is not None and img.shape == (240, 320)
        assert not list(s.images_dir.rglob("*.tmp"))
        # the campaign can go on where it stopped
        camp = s.unfinished_campaign()
        s.record_observation(_obs(camp.id, None))
        assert len(s.observations()) == len(stored) + 1


def test_a_batched_store_commits_at_flush_and_close_and_reads_its_own_writes(tmp_path):
    db = tmp_path / "b.db"
    s = Store.open(db, durable=False, batched=True)
    cid = s.start_campaign(name="b", mode="simulate", started_s=0.0, heliostats=[("H0001", 0, "T1")])
    vid = s.begin_visit(cid, "H0001", "T1", 1.0)
    assert [v.id for v in s.visits()] == [vid]  # its own connection sees the pending write

    def visits_seen_by_another_reader() -> int:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
        try:
            return con.execute("SELECT COUNT(*) FROM visits").fetchone()[0]
        finally:
            con.close()

    assert visits_seen_by_another_reader() == 0  # not committed yet: batched
    s.flush()
    assert visits_seen_by_another_reader() == 1
    s.begin_visit(cid, "H0001", "T1", 2.0)
    s.close()  # the last batch is committed on close
    assert visits_seen_by_another_reader() == 2


def test_progress_of_more_heliostats_than_sqlite_takes_parameters(store):
    """A SQLite built with a small parameter limit (the default is 32 766): the progress of a field with
    more heliostats than that binds no list of them, so it never fails with 'too many SQL variables'."""
    n = 120
    cid = store.start_campaign(name="big", mode="simulate", started_s=0.0,
                               heliostats=[(f"H{i:04d}", i, "T1") for i in range(n)])
    for i in range(n):
        vid = store.begin_visit(cid, f"H{i:04d}", "T1", 1.0)
        store.record_observation(_obs(cid, vid, hid=f"H{i:04d}", error=0.01 * i))
    store._conn.setlimit(sqlite3.SQLITE_LIMIT_VARIABLE_NUMBER, 100)  # as a small build would have it
    rows = store.progress(cid)
    assert [r["last_error_mrad"] for r in rows] == pytest.approx([0.01 * i for i in range(n)])
