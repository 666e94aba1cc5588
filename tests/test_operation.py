"""Year-round operation (``simulate --operate``, ``helicalib operate``): the check ranking rule, and
drift injected in the simulator found by checks, the calibration reopened and kept across a restart.

The simulation runs in-process on the virtual clock with the fast sensor (the simulator's true spot
and the fitted measurement-error model), a real SQLite file and the real runner."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helicalib.campaign.operation import rules as op
from helicalib.app.simulated import SimulationOptions, simulate_campaign
from helicalib.config import load_field_config
from helicalib.sim.scenario import parse_scenario

DAY = 86400.0


# ------------------------------------------------------------------ the rule
def test_gain_is_the_model_variance_plus_the_expected_drift_since_the_last_check():
    lam = op.DRIFT_RATE_PER_YEAR / 365.0
    gains = op.check_gains(np.array([0.3, np.nan, 0.0]), np.array([2.0, 10.0, 0.0]))
    assert gains == pytest.approx([0.09 + op.DRIFT_MRAD**2 * lam * 2.0, op.DRIFT_MRAD**2 * lam * 10.0, 0.0])
    # the threshold is the drift term of the longest a sure model goes unchecked
    assert op.min_gain_mrad2() == pytest.approx(op.DRIFT_MRAD**2 * lam * op.MAX_DAYS_UNCHECKED)


def test_the_largest_gain_goes_first_and_nothing_below_the_threshold():
    now = 100 * DAY
    ids = ["A", "B", "C"]
    last = [now - 2 * DAY, now - 2 * DAY, now - 2 * DAY]
    # B's model is the least sure where the sun is now
    assert op.choose_check(ids, [0.05, 0.4, 0.2], last, now) == "B"
    # sure models checked two days ago: not yet worth a check
    assert op.choose_check(ids, [0.01, 0.01, 0.01], last, now) is None
    # ... but after MAX_DAYS_UNCHECKED the drift term alone reaches the threshold: the longest unchecked first
    last = [now - 1 * DAY, now - (op.MAX_DAYS_UNCHECKED + 1) * DAY, now - (op.MAX_DAYS_UNCHECKED + 2) * DAY]
    assert op.choose_check(ids, [0.0, 0.0, 0.0], last, now) == "C"
    # never checked at all: due
    assert op.choose_check(["A"], [math.nan], [-math.inf], now) == "A"


def test_at_most_one_check_a_solar_day_and_the_rota_baseline():
    now = 100 * DAY
    recent = now - op.MIN_CHECK_INTERVAL_S / 2
    assert op.choose_check(["A"], [5.0], [recent], now) is None  # very unsure, but checked this morning
    ids = ["A", "B", "C"]
    last = [now - 3 * DAY, now - 20 * DAY, now - 15 * DAY]
    assert op.choose_check(ids, [9.0, 0.0, 0.0], last, now, mode="rota", rota_days=14) == "B"
    assert op.choose_check(ids, [9.0, 0.0, 0.0], last, now, mode="rota", rota_days=30) is None
    with pytest.raises(ValueError, match="rota"):
        op.choose_check(ids, [0, 0, 0], last, now, mode="sometimes")


def test_checks_leaning_the_same_way_add_up():
    from helicalib.campaign.operation.drift import trend_p_value

    # three checks, each 2 sigma off the same way: alone p = exp(-2) = 0.14 each, together exp(-6)
    assert trend_p_value([[2.0, 0.0]] * 3) == pytest.approx(math.exp(-0.5 * 3 * 4.0))
    assert trend_p_value([[2.0, 0.0]] * 3) < op.TREND_ALPHA * 3
    # the same sizes in turns cancel: no trend
    assert trend_p_value([[2.0, 0.0], [-2.0, 0.0], [0.0, 0.0]]) == pytest.approx(1.0)


def test_days_to_fix():
    assert op.days_to_fix(0.0, 1.5 * DAY) == pytest.approx(1.5)
    assert op.days_to_fix(0.0, None) == math.inf


# ------------------------------------------------------------------ drift in a simulated field
IDS = ["H0001", "H0011", "H0021", "H0031"]


@pytest.fixture(scope="module")
def drifted_run(tmp_path_factory, demo_field_path):
    """Four heliostats calibrated from the default start, every one settling by 4-5 mrad in the
    middle of day 3, then operation until the end of day 6."""
    cfg = load_field_config(demo_field_path)
    out = tmp_path_factory.mktemp("operate")
    scenario = parse_scenario({"seed": 4, "drift": {"share": 1.0, "kinds": {"settle": 1.0},
                                                    "settle_mrad": [4.0, 5.0], "after_days": 2.4,
                                                    "within_days": 0.2}})
    result = simulate_campaign(cfg, out, SimulationOptions(6.0, seed=4, scenario=scenario, heliostat_ids=IDS,
                                                           fidelity="fast", operation="ranked"))
    return cfg, result


def test_injected_drift_is_confirmed_by_checks_and_the_calibration_reopened(drifted_run):
    cfg, result = drifted_run
    s = result.summary
    assert s["drifted"] == len(IDS)
    assert s["true_sky_rms_undrifted_mrad"] is None  # every heliostat drifted: none left to say it over
    # every drift is seen, none invented
    assert s["drift_detected"] == len(IDS), s["drift_days_to_fix"]
    assert s["drift_false_alarms"] == 0
    runner = result.runner
    truth = {e["heliostat_id"]: e["start_s"] for e in s["drift_events"]}
    for d in runner.ops.drifts:
        hid = d["heliostat_id"]
        # suspected on a check after the drift began, confirmed by the next, far outside the band
        assert truth[hid] <= d["since_s"] < d["confirmed_s"]
        assert d["evidence"]["p_value"] < op.CONFIRM_ALPHA
        # the book (acceptance, drift tests) holds the points since the first suspicious check only;
        # the fits also carry those from before it, in an epoch of their own (book.EPOCHS_AFTER_DRIFT)
        assert all(p.capture_time_s >= d["since_s"] for p in runner.state.book.points(hid))
        b = runner.state.book.h[hid]
        assert d["points_dropped"] == 0 and d["points_before_kept"] == len(b.earlier.points) > 0
        assert all(p.capture_time_s < d["since_s"] for p in b.earlier.points)
        assert set(b.earlier.epoch.tolist()) == {1}  # one drift each: one earlier epoch
        assert len(b.fit.residual_mrad) == len(b.points) + len(b.earlier.points)
        assert b.fit.epoch_offsets is not None and b.fit.epoch_offsets.shape[0] == 2
        assert runner.ops.prior_mean(hid) is None  # centred on the nominal: the earlier points carry the rest
    assert s["checks"] > 0
    # operation's fits model a settling pedestal (a tilt rate); with the earlier epochs in the fits
    # the rate stays after a drift (their months pin it)
    assert runner.ops.tilt_rate
    for hid in IDS:
        b = runner.state.book.h[hid]
        assert b.drifted and runner.ops.tilt_rate_of(hid)
        assert b.fit.tilt_rate_mrad_per_day is not None
    assert 0.0 < s["board_time_share_after_commissioning"] < 0.5
    assert s["monthly_plant_tracking_rms_mrad"] and all(m > 0 for m in s["monthly_plant_tracking_rms_mrad"])


def test_the_tilt_rate_comes_back_once_a_drifted_heliostat_is_still():
    day = 86400.0
    still = op.STILL_DAYS_AFTER_DRIFT * day
    assert not op.fits_tilt_rate(False, False)                  # a campaign: no rate
    assert op.fits_tilt_rate(True, False)                       # operation: a rate
    assert not op.fits_tilt_rate(True, True, 100 * day + still - 1.0, 100 * day)  # days after a drift: none
    assert op.fits_tilt_rate(True, True, 100 * day + still, 100 * day)            # still for long enough
    assert op.fits_tilt_rate(True, True, 100 * day + 1.0, 100 * day, epochs=True)  # the earlier epochs pin it


def test_a_drifted_heliostat_is_accepted_again_on_points_after_the_drift(drifted_run):
    _cfg, result = drifted_run
    s = result.summary
    fixed = [x for x in s["drift_days_to_fix"] if x is not None]
    assert len(fixed) == len(IDS), s["drift_days_to_fix"]  # every settling accepted again before the end
    # within the 3.6 days the run has left after the drifts (2.4-2.6 days in)
    assert s["drift_median_days_to_fix"] is not None and s["drift_median_days_to_fix"] <= 3.6
    for d in result.runner.ops.drifts:
        if d.get("fixed_s") is not None:
            assert result.runner.state.book.accepted(d["heliostat_id"])


def test_a_restarted_runner_keeps_the_reopened_calibration(drifted_run):
    from helicalib.campaign.loop import CampaignRunner
    from helicalib.sim.clock import VirtualClock
    from helicalib.sim.plant import SimulatedPlant
    from helicalib.store.sqlite import Store

    cfg, result = drifted_run
    first = result.runner
    store = Store.open(result.database, "images")
    try:
        cid = store.campaigns()[-1].id
        t = first.devices.clock.now_s()
        sim = SimulatedPlant(cfg, parse_scenario({"seed": 4}), start_s=t)
        again = CampaignRunner(cfg, sim, {}, VirtualClock(t), store, cid, heliostat_ids=IDS, operation="ranked")
        for d in first.ops.drifts:
            hid = d["heliostat_id"]
            kept = again.state.book.points(hid)
            assert kept and all(p.capture_time_s >= d["since_s"] for p in kept)
            assert len(kept) == len(first.state.book.points(hid))
            # and the points from before the drift, with their epochs
            assert [p.id for p in again.state.book.h[hid].earlier.points] == [p.id for p in first.state.book.h[hid].earlier.points]
            np.testing.assert_array_equal(again.state.book.h[hid].earlier.epoch, first.state.book.h[hid].earlier.epoch)
            assert again.ops.prior_mean(hid) is None and d["prior_params"] is not None
            np.testing.assert_allclose(again.state.models[hid].params, first.state.models[hid].params, atol=1e-9)
            assert again.state.book.accepted(hid) == first.state.book.accepted(hid)
    finally:
        store.close()


# ------------------------------------------------------------------ bounded memory
def _point(visit, t, az_deg, el_deg):
    from types import SimpleNamespace

    a, e = np.radians(az_deg), np.radians(el_deg)
    return SimpleNamespace(visit_id=visit, capture_time_s=t,
                           sun_enu=(np.sin(a) * np.cos(e), np.cos(a) * np.cos(e), np.sin(e)))


def test_thinning_drops_the_visits_nearest_in_sun_position_and_keeps_the_newest():
    from helicalib.campaign.book import thin_visits

    distinct = [(90, 10), (120, 40), (180, 70), (240, 40), (270, 10)]
    points = [_point(i, 100.0 * i, az, el) for i, (az, el) in enumerate(distinct)]
    # three more visits, each 0.1° from one already held; two placements in one of them
    points += [_point(5, 600.0, 120.1, 40.0), _point(6, 700.0, 180.0, 70.1), _point(6, 701.0, 180.0, 70.1),
               _point(7, 800.0, 270.0, 10.1)]
    kept = thin_visits(points, 6)
    visits = sorted({p.visit_id for p in kept})
    assert len(visits) == 6
    assert 7 in visits  # the newest stays though it duplicates visit 4
    # of each near pair the older one went first: visit 1 (with 5) and then 2 (with 6)
    assert visits == [0, 3, 4, 5, 6, 7]
    assert len([p for p in kept if p.visit_id == 6]) == 2  # a visit goes whole or not at all
    assert thin_visits(points, 10) == points


def test_nightly_frame_retention_keeps_the_disk_bounded(tmp_path, demo_field_path):
    """Rendered frames over three plant days, pruned every night to the newest observation's frames
    per heliostat and every rejected one's: the files on disk are exactly those still referenced, and
    no more than that rule allows, while the database keeps every observation."""
    import sqlite3

    cfg = load_field_config(demo_field_path)
    ids = ["H0001", "H0040"]
    result = simulate_campaign(cfg, tmp_path, SimulationOptions(3.0, seed=2, heliostat_ids=ids, fidelity="render",
                                                                operation="ranked", keep_frames=1,
                                                                monthly_tracking=False))
    con = sqlite3.connect(result.database)
    rows = con.execute("SELECT heliostat_id, valid, capture_time_s, before_frame_path, after_frame_paths_json "
                       "FROM observations ORDER BY capture_time_s").fetchall()
    notes = [r[0] for r in con.execute("SELECT reason FROM events WHERE kind = 'note'")]
    con.close()
    assert any(n.startswith("frame retention:") for n in notes), notes
    import json

    referenced = set()
    with_frames = {h: [] for h in ids}
    for hid, valid, t, before, afters in rows:
        paths = [p for p in [before, *json.loads(afters or "[]")] if p]
        referenced.update(paths)
        if paths and valid:
            with_frames[hid].append(t)
    on_disk = {str(p.relative_to(tmp_path / "images")) for p in (tmp_path / "images").rglob("*.png")}
    assert on_disk == referenced  # nothing left behind, nothing missing
    last_night = max(rows, key=lambda r: r[2])[2] - 86400.0
    for hid in ids:
        # valid observations with frames: the newest one at the last pruning, and those recorded since
        assert len([t for t in with_frames[hid] if t < last_night]) <= 1, hid
    cleared = [r for r in rows if not r[3] and not json.loads(r[4] or "[]")]
    assert cleared  # the database kept the observations whose frames went, their paths cleared


def test_the_report_fits_an_operated_campaign_as_operation_does(drifted_run, demo_field_path):
    """The report's year-round prediction refits each heliostat from the database: for a campaign that
    went into operation it fits as operation does (a tilt rate), so it predicts what the runner's own
    fits predicted (the summary's median, from those fits)."""
    from helicalib.report.data import load_campaign
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.report.prediction import stored_fits, year_predictions
    from helicalib.store.history import was_operated
    from helicalib.store.sqlite import Store

    _cfg, result = drifted_run
    data = load_campaign(result.database, field_config=demo_field_path)
    store = Store.open(result.database, "images", readonly=True)
    try:
        assert was_operated(store, data.campaign.id)
    finally:
        store.close()
    # the report's fits are the runner's models (fitted from the same stored points, as operation
    # fits: a tilt rate, the points from before a confirmed drift in an epoch of their own). Both
    # solvers start from the run's newest fit: along the fits' flat directions (covariance condition
    # ~1e9) they stop a few 1e-6 of a parameter's σ apart (from the nominal heliostat the fast solver
    # stopped up to 4e-4 σ away on the epoch fits); a refit with the other tilt-rate rule lands 4e-3
    # to 3e-2 σ away.
    ids = sorted(IDS)
    fits = stored_fits(data, ids, HeliostatModel.from_config(data.cfg, ids))
    assert set(fits) == set(IDS)
    for hid, (params, fit) in fits.items():
        assert (fit.tilt_rate_mrad_per_day is not None) == result.runner.ops.tilt_rate_of(hid), hid
        assert np.all(np.abs(params - result.runner.state.models[hid].params[0]) <= 1e-4 * fit.sigma), hid
    yp = year_predictions(data)
    assert set(yp["heliostats"]) == set(IDS)
    median = float(np.median([p["expected_rms_mrad"] for p in yp["heliostats"].values()]))
    assert median == pytest.approx(result.summary["predicted_year_rms_median_mrad"], abs=0.005)


def test_a_check_averages_more_after_frames_than_a_campaign_visit(tmp_path, demo_field_path):
    """Rendered frames over three plant days of one heliostat, none pruned: every valid measurement
    of a check keeps ``operation.CHECK_AFTER_FRAMES`` after frames, every campaign visit's keeps the
    config's ``calibration.after_frames``; the stored ``check`` events name the check visits."""
    import json
    import sqlite3

    from helicalib.campaign.operation import rules as op_rules

    cfg = load_field_config(demo_field_path)
    assert cfg.calibration.after_frames < op_rules.CHECK_AFTER_FRAMES  # otherwise the test shows nothing
    result = simulate_campaign(cfg, tmp_path, SimulationOptions(3.0, seed=2, heliostat_ids=["H0001"], fidelity="render",
                                                                operation="ranked", monthly_tracking=False))
    con = sqlite3.connect(result.database)
    checks = {vid: n for vid, n in con.execute(
        "SELECT json_extract(data_json, '$.visit_id'), json_extract(data_json, '$.after_frames') FROM events "
        "WHERE kind = 'check'")}
    visits = {vid for (vid,) in con.execute("SELECT id FROM visits")}
    rows = con.execute("SELECT visit_id, after_frame_paths_json FROM observations WHERE valid = 1 AND iteration >= 0"
                       ).fetchall()
    con.close()
    assert checks, "no check in three days"
    assert set(checks) <= visits and set(checks.values()) == {op_rules.CHECK_AFTER_FRAMES}
    frames = {vid in checks: set() for vid, _ in rows}
    for vid, afters in rows:
        frames[vid in checks].add(len(json.loads(afters)))
    assert frames[True] == {op_rules.CHECK_AFTER_FRAMES}
    assert frames[False] == {cfg.calibration.after_frames}


def test_the_visit_cap_is_replayed_alike_by_the_runner_the_report_and_check(tmp_path, monkeypatch, demo_field_path):
    """With the visit cap at 8, and 6 after a drift (the heliostats make 27-34 valid visits; below about
    8 thinning takes the points acceptance needs, and unaccepted heliostats get no drift test), the
    drifted run's books are thinned before and after the drift: the
    points the store gives back for each heliostat's newest fit (``stored_basis``: what a
    resumed runner, the report's refit and ``helicalib check``'s drift test stand on) are the live
    book's, the report's refit is the runner's model, and each stored fit's point count is found again."""
    from helicalib.campaign import book
    from helicalib.campaign.basis import stored_basis
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.report.data import load_campaign
    from helicalib.report.prediction import stored_fits
    from helicalib.store.sqlite import Store

    monkeypatch.setattr(book, "MAX_VISIT_POINTS", 8)
    monkeypatch.setattr(book, "MAX_VISIT_POINTS_AFTER_DRIFT", 6)
    cfg = load_field_config(demo_field_path)
    scenario = parse_scenario({"seed": 4, "drift": {"share": 1.0, "kinds": {"settle": 1.0},
                                                    "settle_mrad": [4.0, 5.0], "after_days": 2.4,
                                                    "within_days": 0.2}})
    result = simulate_campaign(cfg, tmp_path, SimulationOptions(6.0, seed=4, scenario=scenario, heliostat_ids=IDS,
                                                                fidelity="fast", operation="ranked",
                                                                monthly_tracking=False))
    runner = result.runner
    assert len(runner.ops.drifts) == len(IDS), "drifts not confirmed: the test shows little of the epochs"
    store = Store.open(result.database, "images", readonly=True)
    try:
        cid = runner.campaign_id
        thinned = 0
        for hid in IDS:
            live = runner.state.book.points(hid)
            assert runner.state.book.h[hid].drifted
            assert len({p.visit_id for p in live}) <= 6
            located = [o for o in store.observations(campaign_id=cid, heliostat_id=hid) if book.located(o)]
            thinned += len({o.visit_id for o in located}) > len({p.visit_id for p in live})
            points, centre, earlier = stored_basis(store, cid, hid)
            assert [p.id for p in points] == [p.id for p in live], hid
            live_earlier = runner.state.book.h[hid].earlier
            assert [p.id for p in earlier.points] == [p.id for p in live_earlier.points], hid
            np.testing.assert_array_equal(earlier.epoch, live_earlier.epoch)
            assert len({p.visit_id for p in earlier.points}) <= 8 - 6  # the cap less the cap after a drift
            prior = runner.ops.prior_mean(hid)
            assert (centre is None) == (prior is None) and (prior is None or np.allclose(centre, prior)), hid
            latest = store.latest_fit(hid, campaign_id=cid)
            assert book.fit_size(*stored_basis(store, cid, hid, latest.time_s)[::2]) == latest.n_points, hid
        assert thinned == len(IDS)  # every heliostat had more visits than the cap
    finally:
        store.close()
    data = load_campaign(result.database, field_config=demo_field_path)
    fits = stored_fits(data, sorted(IDS), HeliostatModel.from_config(data.cfg, sorted(IDS)))
    for hid, (params, fit) in fits.items():
        assert np.all(np.abs(params - runner.state.models[hid].params[0]) <= 1e-4 * fit.sigma), hid
