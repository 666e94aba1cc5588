"""The epochs a heliostat's fits stand on after confirmed drifts and repairs, replayed from a real
SQLite store (stored_epochs, stored_basis, earlier_points)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helicalib.campaign import book
from helicalib.campaign.basis import stored_basis
from helicalib.campaign.book import fit_size
from helicalib.store import Observation, Store
from helicalib.store.history import stored_epochs

DAY = 86400.0
T0 = 1_780_000_000.0


def _obs(cid, vid, t, valid=True):
    el = np.radians(20.0 + (vid % 7) * 8.0)
    az = np.radians(90.0 + vid * 17.0)
    return Observation(
        campaign_id=cid, heliostat_id="H0001", target_id="T1", visit_id=vid, iteration=0, capture_time_s=t,
        strokes_cmd_mm=(812.5, 640.25), strokes_read_mm=(812.4, 640.3),
        sun_enu=(float(np.sin(az) * np.cos(el)), float(np.cos(az) * np.cos(el)), float(np.sin(el))),
        sun_azimuth_deg=float(np.degrees(az)), sun_elevation_deg=float(np.degrees(el)), sun_rising=True, wind_ms=3.2,
        wind_direction_deg=270.0, dni_wm2=850.0, temperature_c=21.5, cleanliness=0.93, valid=valid,
        reason="ok" if valid else "no_spot", message="" if valid else "no spot in the difference image",
        offset_u_m=0.12 if valid else None, offset_v_m=-0.3 if valid else None,
        spot_x_px=640.5 if valid else None, spot_y_px=500.25 if valid else None,
        spot_area_px=1500.0 if valid else None, threshold=37.0, jitter_px=0.4 if valid else None,
        spot_enu_m=(0.12, 9.0, 119.7) if valid else None, error_mrad=1.0 if valid else None, approach=(1, -1))


@pytest.fixture
def store(tmp_path):
    s = Store.open(tmp_path / "campaign.db")
    cid = s.start_campaign(name="c", mode="operate", started_s=T0, heliostats=[("H0001", 0, "T1")])
    for day in range(10):  # one visit a day, days 0..9; day 4's is invalid
        vid = s.begin_visit(cid, "H0001", "T1", T0 + day * DAY)
        s.record_observation(_obs(cid, vid, T0 + day * DAY + 60.0, valid=day != 4))
    yield s, cid
    s.close()


def _drift(s, cid, since_day, confirmed_day):
    s.record_event(campaign_id=cid, time_s=T0 + confirmed_day * DAY, kind="drift", reason="drift confirmed",
                   heliostat_id="H0001", data={"since_s": T0 + since_day * DAY, "prior_params": [0.0] * 15})


def _days(points):
    return [round((p.capture_time_s - T0) / DAY) for p in points]


def test_each_point_before_the_drifts_keeps_the_epoch_it_was_measured_in(store):
    s, cid = store
    _drift(s, cid, 3, 3.5)
    _drift(s, cid, 7, 7.5)
    ep = stored_epochs(s, cid)["H0001"]
    assert ep.drifted and ep.boundaries == (T0 + 3 * DAY, T0 + 7 * DAY) and ep.floor_s == -math.inf
    points, prior, earlier = stored_basis(s, cid, "H0001")
    assert _days(points) == [7, 8, 9]  # the book: since the newest drift
    assert _days(earlier.points) == [0, 1, 2, 3, 5, 6]  # before it, located only (day 4 was invalid)
    assert earlier.epoch.tolist() == [2, 2, 2, 1, 1, 1]  # 1: between the drifts, 2: before the first
    assert prior is None  # the fits centre on the nominal: the earlier points carry the model before
    assert fit_size(points, earlier) == 9
    # as the store stood at the first confirmation: one earlier epoch
    points, _prior, earlier = stored_basis(s, cid, "H0001", until_s=T0 + 3.6 * DAY)
    assert _days(points) == [3] and _days(earlier.points) == [0, 1, 2] and earlier.epoch.tolist() == [1, 1, 1]


def test_a_repair_is_the_floor_of_the_earlier_epochs(store):
    s, cid = store
    _drift(s, cid, 3, 3.5)
    a = s.request_action(campaign_id=cid, kind="repaired", heliostat_ids=["H0001"], who="crew",
                         requested_wall_s=0.0, requested_s=None)
    s.finish_action(a, done_s=T0 + 5.5 * DAY, outcome="model reset")
    points, _prior, earlier = stored_basis(s, cid, "H0001")
    assert _days(points) == [6, 7, 8, 9] and earlier is None  # nothing before the repair counts
    _drift(s, cid, 8, 8.5)
    points, _prior, earlier = stored_basis(s, cid, "H0001")
    assert _days(points) == [8, 9]
    assert _days(earlier.points) == [6, 7] and earlier.epoch.tolist() == [1, 1]  # the repair to the drift


def test_without_epochs_the_points_before_a_drift_leave_the_fits(store, monkeypatch):
    s, cid = store
    _drift(s, cid, 3, 3.5)
    monkeypatch.setattr(book, "EPOCHS_AFTER_DRIFT", False)
    points, prior, earlier = stored_basis(s, cid, "H0001")
    assert _days(points) == [3, 5, 6, 7, 8, 9] and earlier is None
    np.testing.assert_array_equal(prior, np.zeros(15))  # centred on the model from before the drift


def test_the_earlier_points_are_thinned_to_the_cap_less_the_cap_after_a_drift(store, monkeypatch):
    s, cid = store
    monkeypatch.setattr(book, "MAX_VISIT_POINTS", 6)
    monkeypatch.setattr(book, "MAX_VISIT_POINTS_AFTER_DRIFT", 2)
    _drift(s, cid, 8, 8.5)
    points, _prior, earlier = stored_basis(s, cid, "H0001")
    assert _days(points) == [8, 9]
    assert len(earlier.points) == 4 and _days(earlier.points)[-1] == 7  # the newest one stays
