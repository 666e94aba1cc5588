"""Gating and planning policy: the paper's limits at their edges, and who goes next."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from helicalib.calibration.acceptance import Gap
from helicalib.campaign.gating import gate_field, gate_mirrors
from helicalib.campaign.planner import (
    REFINE_MIN_SPREAD_MRAD, TIER_EXTRA, TIER_LOW_BAND, TIER_OPEN, TIER_RECHECK, TIER_REFINE, TIER_WINDOW, Candidate,
    plan, round_robin, round_robin_shared,
)
from helicalib.config import Gating

G = Gating(wind_max_ms=10, wind_preferred_ms=5, stow_wind_ms=15, dni_min_wm2=300, dni_preferred_wm2=800,
           cleanliness_min=0.55, cleanliness_preferred=0.7)
NOW = 1_000_000.0


# ----------------------------------------------------------------------------- gating
@pytest.mark.parametrize("wind, calibrate, stow, good", [
    (5.0, True, False, True), (5.01, True, False, False), (10.0, True, False, False),
    (10.01, False, False, False), (15.0, False, False, False), (15.01, False, True, False),
])
def test_wind_edges(wind, calibrate, stow, good):
    g = gate_field(wind, 900.0, G)
    assert (g.calibrate, g.stow, g.wind_good) == (calibrate, stow, good)


@pytest.mark.parametrize("dni, calibrate, good", [(300.0, False, False), (300.1, True, False),
                                                   (800.0, True, False), (800.1, True, True)])
def test_dni_edges(dni, calibrate, good):
    g = gate_field(2.0, dni, G)
    assert (g.calibrate, g.dni_good) == (calibrate, good)
    assert g.good is good  # the wind (2 m/s) is good, so the DNI decides


def test_reasons_name_readings_and_limits():
    assert gate_field(16.2, 900, G).reason == "wind 16.2 m/s > 15 m/s: stow the whole field"
    assert gate_field(11.0, 250, G).reason == "wind 11.0 m/s > 10 m/s; DNI 250 W/m² ≤ 300 W/m²: no calibration"
    r = gate_field(7.0, 850, G).reason
    assert r.startswith("calibration allowed") and "above the preferred 5" in r and "DNI 850 W/m² (good)" in r


def test_stow_hysteresis_resumes_only_when_calm():
    assert gate_field(12.0, 900, G, stowed=True).stow  # below the stow limit but not calm
    assert gate_field(10.0, 900, G, stowed=True).stow is False
    assert gate_field(10.0, 900, G, stowed=True).calibrate
    assert gate_field(math.nan, 900, G, stowed=True).stow


def test_missing_readings_block_but_never_stow():
    g = gate_field(math.nan, 900, G)
    assert not g.calibrate and not g.stow and "no wind reading" in g.reason
    g = gate_field(3.0, math.nan, G)
    assert not g.calibrate and "no DNI reading" in g.reason


def test_mirror_gate_edges():
    m = gate_mirrors([0.55, 0.5501, 0.7, 0.7001, np.nan], G)
    assert m.allowed.tolist() == [False, True, True, True, False]
    assert m.good.tolist() == [False, False, False, True, False]
    assert "too soiled" in m.reason(0, 0.55, G) and m.reason(3, 0.7001, G) == "cleanliness 0.70 (good)"


@given(st.floats(0, 40), st.floats(0, 1200))
def test_preferred_limits_never_block(wind, dni):
    g = gate_field(wind, dni, G)
    assert g.calibrate == (wind <= G.wind_max_ms and dni > G.dni_min_wm2)
    assert g.stow == (wind > G.stow_wind_ms)
    assert not (g.stow and g.calibrate)


# ----------------------------------------------------------------------------- planner
def gap(kind, start, end, window=None):
    return Gap(kind, window, start, end, f"{kind} {window}")


def test_low_band_before_window_before_error():
    cands = [
        Candidate("H1", "T1", predicted_error_mrad=20.0, gaps=(gap("points", NOW - 10, NOW + 9000),)),
        Candidate("H2", "T1", predicted_error_mrad=1.0, gaps=(gap("window", NOW - 10, NOW + 3000, 2),)),
        Candidate("H3", "T1", predicted_error_mrad=0.5, gaps=(gap("rising", NOW - 10, NOW + 1800),)),
    ]
    (a,) = plan(cands, NOW, G)
    assert (a.heliostat_id, a.tier) == ("H3", TIER_LOW_BAND) and a.reason.startswith("low band")
    (a,) = plan(cands[:2], NOW, G)
    assert (a.heliostat_id, a.tier) == ("H2", TIER_WINDOW)
    (a,) = plan(cands[:1], NOW, G)
    assert a.tier == TIER_OPEN


def test_gaps_not_open_now_do_not_count():
    later = Candidate("H1", "T1", predicted_error_mrad=1.0, gaps=(gap("setting", NOW + 3600, NOW + 7200),))
    other = Candidate("H2", "T1", predicted_error_mrad=2.0, gaps=(gap("window", NOW, NOW + 100, 0),))
    (a,) = plan([later, other], NOW, G)
    assert a.heliostat_id == "H2"
    assert plan([later], NOW, G)[0].tier == TIER_EXTRA
    assert plan([later], NOW, G, skip_extra=True) == ()


def test_window_closing_soonest_then_cleanliness_then_largest_error():
    a = Candidate("HA", "T1", predicted_error_mrad=9.0, gaps=(gap("window", NOW, NOW + 5000, 1),))
    b = Candidate("HB", "T1", predicted_error_mrad=1.0, gaps=(gap("window", NOW, NOW + 2000, 0),))
    assert plan([a, b], NOW, G)[0].heliostat_id == "HB"
    c = Candidate("HC", "T1", predicted_error_mrad=9.0, cleanliness=0.65, gaps=(gap("points", NOW, NOW + 10),))
    d = Candidate("HD", "T1", predicted_error_mrad=2.0, cleanliness=0.95, gaps=(gap("points", NOW, NOW + 10),))
    assert plan([c, d], NOW, G)[0].heliostat_id == "HD"  # preferred cleanliness raises priority
    e = Candidate("HE", "T1", predicted_error_mrad=None, gaps=(gap("points", NOW, NOW + 10),))
    assert plan([d, e], NOW, G)[0].heliostat_id == "HE"  # no model yet = largest error


def test_one_heliostat_per_free_target_and_skips():
    cands = [
        Candidate("H1", "T1", predicted_error_mrad=5.0),
        Candidate("H2", "T1", predicted_error_mrad=3.0),
        Candidate("H3", "T2", predicted_error_mrad=1.0),
        Candidate("H4", "T2", predicted_error_mrad=9.0, cleanliness=0.55),      # gated
        Candidate("H5", "T3", accepted=True),
        Candidate("H6", "T4", predicted_error_mrad=9.0, cooldown_until_s=NOW + 1),
        Candidate("H7", "T5", predicted_error_mrad=9.0),
    ]
    out = plan(cands, NOW, G, busy_targets=["T5"])
    assert [(x.target_id, x.heliostat_id) for x in out] == [("T1", "H1"), ("T2", "H3")]
    out = plan(cands, NOW, G, busy_heliostats=["H1"], include_accepted=True)
    assert {(x.target_id, x.heliostat_id, x.tier) for x in out} == {
        ("T1", "H2", TIER_EXTRA), ("T2", "H3", TIER_EXTRA), ("T3", "H5", TIER_RECHECK), ("T5", "H7", TIER_EXTRA)}


def test_refine_is_asked_for_and_comes_after_every_gap():
    done_sure = Candidate("HA", "T1", accepted=True, predicted_error_mrad=0.5, spread_mrad=0.1)
    done_unsure = Candidate("HB", "T1", accepted=True, predicted_error_mrad=0.5, spread_mrad=0.9)
    done_less = Candidate("HC", "T1", accepted=True, predicted_error_mrad=3.0, spread_mrad=0.4)
    # not asked: accepted heliostats never take target time
    assert plan([done_sure, done_unsure, done_less], NOW, G) == ()
    (a,) = plan([done_sure, done_unsure, done_less], NOW, G, refine=True)
    assert (a.heliostat_id, a.tier) == ("HB", TIER_REFINE)  # the most uncertain model at this sun
    assert "0.90 mrad" in a.reason
    # a model certain enough here is left alone
    assert done_sure.spread_mrad < REFINE_MIN_SPREAD_MRAD
    assert plan([done_sure], NOW, G, refine=True) == ()
    # unaccepted heliostats go first: extra points (tier 3), ranked by their spread, then any open gap
    waiting_a = Candidate("HD", "T1", predicted_error_mrad=5.0, spread_mrad=0.2,
                          gaps=(gap("setting", NOW + 3600, NOW + 7200),))
    waiting_b = Candidate("HE", "T1", predicted_error_mrad=1.0, spread_mrad=0.6,
                          gaps=(gap("setting", NOW + 3600, NOW + 7200),))
    (a,) = plan([done_unsure, waiting_a, waiting_b], NOW, G, refine=True)
    assert (a.heliostat_id, a.tier) == ("HE", TIER_EXTRA)
    band = Candidate("HF", "T1", predicted_error_mrad=0.1, spread_mrad=0.01, gaps=(gap("rising", NOW, NOW + 600),))
    (a,) = plan([done_unsure, waiting_b, band], NOW, G, refine=True)
    assert (a.heliostat_id, a.tier) == ("HF", TIER_LOW_BAND)
    # a re-check (include_accepted) stays a re-check
    (a,) = plan([done_unsure], NOW, G, include_accepted=True, refine=True)
    assert a.tier == TIER_RECHECK


def test_a_borrowed_target_serves_its_own_heliostats_first_and_only_open_gaps():
    """A free board lent to heliostats of a busy one (``borrowed`` > 0): its own go first within
    the same tier and closing time, a guest's scarcer gap beats an own heliostat's lesser one, and
    a guest never takes it for points no gap asks for (extra, refine)."""
    band_end = NOW + 1800
    own = Candidate("H1", "T1", predicted_error_mrad=0.5, gaps=(gap("rising", NOW, band_end),))
    guest = Candidate("G1", "T1", predicted_error_mrad=9.0, gaps=(gap("rising", NOW, band_end),), borrowed=1)
    (a,) = plan([guest, own], NOW, G)
    assert a.heliostat_id == "H1"  # same tier and closing: own first, though the guest's error is larger
    assert plan([guest], NOW, G)[0].heliostat_id == "G1" and "borrowed" in plan([guest], NOW, G)[0].reason
    own_window = Candidate("H2", "T1", predicted_error_mrad=9.0, gaps=(gap("window", NOW, NOW + 600, 3),))
    assert plan([own_window, guest], NOW, G)[0].heliostat_id == "G1"  # a band gap outranks a window
    nearer = Candidate("G2", "T1", predicted_error_mrad=0.1, gaps=(gap("rising", NOW, band_end),), borrowed=1)
    farther = Candidate("G3", "T1", predicted_error_mrad=9.0, gaps=(gap("rising", NOW, band_end),), borrowed=2)
    assert plan([farther, nearer], NOW, G)[0].heliostat_id == "G2"  # the nearer home board's guests first
    # nothing open now: a guest stays home (tier 3 would be extra points), also under refine
    idle = Candidate("G4", "T1", predicted_error_mrad=1.0, gaps=(gap("setting", NOW + 3600, NOW + 7200),),
                     borrowed=1)
    assert plan([idle], NOW, G) == () and plan([idle], NOW, G, refine=True) == ()
    assert plan([replace(idle, borrowed=0)], NOW, G, refine=True)[0].tier == TIER_EXTRA
    done = Candidate("G5", "T1", accepted=True, predicted_error_mrad=0.5, spread_mrad=0.9, borrowed=1)
    assert plan([done], NOW, G, refine=True) == ()
    assert plan([done], NOW, G, include_accepted=True)[0].tier == TIER_RECHECK  # a re-check may borrow


def test_round_robin_goes_in_turn_and_wraps():
    cands = [Candidate(f"H{i}", "T1") for i in range(4)] + [Candidate("K0", "T2"), Candidate("K1", "T2", accepted=True)]
    out = round_robin(cands, NOW, G, cursor={})
    assert [(a.target_id, a.heliostat_id) for a in out] == [("T1", "H0"), ("T2", "K0")]
    assert round_robin(cands, NOW, G, cursor={"T1": "H1", "T2": "K0"})[0].heliostat_id == "H2"
    assert round_robin(cands, NOW, G, cursor={"T1": "H3"})[0].heliostat_id == "H0"
    # K1 is accepted, so T2 comes back to K0
    assert round_robin(cands, NOW, G, cursor={"T2": "K0"})[1].heliostat_id == "K0"
    assert round_robin(cands, NOW, G, cursor={"T1": "H0"}, busy_heliostats=["H1"])[0].heliostat_id == "H2"
    assert [a.target_id for a in round_robin(cands, NOW, G, cursor={}, busy_targets=["T1"])] == ["T2"]


def test_shared_round_robin_goes_in_one_field_wide_turn():
    """The baseline with shared boards: whichever board is free takes the next heliostat in one
    field-wide order, its own or a guest that can reach it, skipping accepted and busy ones."""
    cands = [Candidate("A", "T1"), Candidate("B", "T1", borrowed=1), Candidate("C", "T1", accepted=True),
             Candidate("D", "T1", borrowed=1)]
    take = lambda **kw: round_robin_shared(cands, NOW, G, target_id="T1", **kw)  # noqa: E731
    assert take(cursor=None).heliostat_id == "A"
    assert take(cursor="A").heliostat_id == "B"
    assert take(cursor="B").heliostat_id == "D"  # C is accepted
    assert take(cursor="D").heliostat_id == "A"  # wraps around
    assert take(cursor="A", usable=lambda h: h != "B").heliostat_id == "D"  # B cannot reach T1 now
    assert take(cursor="A", busy_heliostats=["B", "D", "A"]) is None
    assert take(cursor="A").reason.startswith("in turn")


def test_heliostats_without_a_point_share_one_verdict_and_one_set_of_gaps(demo_field_path):
    """choose_next evaluates a heliostat with no point once per decision for all of them: it
    relies on their verdicts and gaps being equal, whatever the heliostat (checked here at
    instants over two days, against each heliostat's own evaluation)."""
    from helicalib.calibration import acceptance as acc
    from helicalib.campaign.book import Book
    from helicalib.campaign.verdict import verdict
    from helicalib.app.simulated import default_start_s
    from helicalib.config import load_field_config

    cfg = load_field_config(demo_field_path)
    ids = [h.id for h in cfg.heliostats]
    book = Book(cfg, ids)
    t0 = default_start_s(cfg)
    for t in t0 + 3600.0 * np.arange(0.0, 48.0, 5.5):
        days = book.days(t)
        seen = {(repr(v := verdict(cfg, book, hid, None, t)), repr(acc.gaps(v, cfg.acceptance, days, t)))
                for hid in ids}
        assert len(seen) == 1


def test_next_sun_above_in_one_call_is_the_step_by_step_answer():
    """The night gate's next opening from one array call of the sun table equals the 144 look-ups."""
    from helicalib.campaign.choice import _next_sun_above
    from helicalib.config import Site
    from helicalib.geometry.sun import SunTable, to_unix_seconds

    table = SunTable(Site(name="t", latitude_deg=40.063, longitude_deg=94.426, altitude_m=1267.0))
    t0 = float(to_unix_seconds("2026-06-01T12:00:00Z"))  # evening, night and dawn at the site
    seen = set()
    for now in t0 + 617.0 * np.arange(0, 140):
        for level in (5.0, -2.0, 89.0):  # 89°: never within the day, the default answer
            want = _next_sun_above(table.position, now, level)
            got = _next_sun_above(table.position, now, level, table.position_elevations_deg)
            assert got == want
            seen.add(want - now)
    assert 86400.0 in seen and len(seen) > 10


def test_cooldown_doubles_after_invalid_visits_in_a_row_and_resets_on_a_valid_point():
    """30, 60, 120, 240, 240 minutes after invalid visits in a row; a fault neither counts nor resets;
    a valid point goes back to 20 minutes and a new run starts at 30."""
    from helicalib.campaign import book as books
    from helicalib.campaign.visit_types import VisitOutcome

    b = books.HeliostatBook()
    invalid = VisitOutcome(status="invalid", reason="clipped")
    waits = [books.cooldown_s(b, invalid) for _ in range(5)]
    assert waits == [1800.0, 3600.0, 7200.0, 14400.0, 14400.0]
    assert books.cooldown_s(b, VisitOutcome(status="fault", reason="camera_timeout")) == 14400.0
    assert b.failed_in_row == 5
    assert books.cooldown_s(b, VisitOutcome(status="converged", reason="ok", valid_points=1)) == books.COOLDOWN_VALID_S
    assert b.failed_in_row == 0
    assert books.cooldown_s(b, invalid) == 1800.0
    assert books.cooldown_s(b, VisitOutcome(status="refused", reason="range")) == 1800.0


def test_resume_restores_the_cool_down_the_visits_left():
    """Three invalid visits in a row, then one cut by a stow and one the kill left running (neither
    judged by the loop): the back-off stands at 3 and the wait at 2 h from the third one's end; a
    visit that faulted after a valid point resets it, as Book.visited did."""
    from types import SimpleNamespace as V

    from helicalib.campaign import book as books
    from helicalib.campaign.resume import restore_cooldown

    def visit(i, outcome, end):
        return V(id=i, outcome=outcome, started_s=end - 100.0, ended_s=end, iterations=0)

    b = books.HeliostatBook()
    visits = [visit(1, "invalid", 1000.0), visit(2, "invalid", 5000.0), visit(3, "invalid", 9000.0),
              visit(4, "aborted", 9500.0), visit(5, "running", 9900.0)]
    restore_cooldown(b, visits, [V(visit_id=4, valid=True)])
    assert b.failed_in_row == 3 and b.cooldown_until_s == 9000.0 + 7200.0
    b = books.HeliostatBook()
    restore_cooldown(b, [*visits[:3], visit(6, "fault", 12000.0)], [V(visit_id=6, valid=True)])
    assert b.failed_in_row == 0 and b.cooldown_until_s == 12000.0 + books.COOLDOWN_VALID_S
