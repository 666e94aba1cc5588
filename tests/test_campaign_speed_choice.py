"""The gaps planner's shortcuts at plant scale choose as the plain forms: the first of a
lexicographic order found key by key (no sort of a board's candidates), and the boards each
heliostat may borrow found with one array operation a board."""

from __future__ import annotations

import math

import numpy as np

from helicalib.campaign import choice
from helicalib.config import load_field_config
from helicalib.geometry import optics


def test_lexicographic_first_is_what_lexsort_puts_first_with_ties_and_nan():
    rng = np.random.default_rng(5)
    for trial in range(400):
        n = int(rng.integers(1, 60))
        tier = rng.integers(0, 3, n)
        closes = rng.choice([1.0, 2.0, math.inf, np.nan], n)
        borrowed = rng.integers(0, 2, n)
        not_preferred = rng.random(n) < 0.5
        err = -rng.choice([0.0, -0.0, 1.5, math.inf, 3.0], n)
        visits = rng.integers(0, 3, n)
        rank = rng.permutation(n)
        keys = (tier, closes, borrowed, not_preferred, err, visits, rank)
        sel = np.flatnonzero(rng.random(n) < 0.7)
        if not sel.size:
            continue
        expected = sel[np.lexsort(tuple(k[sel] for k in reversed(keys)))][0]
        assert choice._lexicographic_first(sel, keys) == expected, trial


def _reference_shared(cfg, hids, cams):
    """Each heliostat's boards one by one (the plain form)."""
    out = {t.id: {} for t in cfg.targets}
    cos_max = math.cos(math.radians(choice.MAX_SHARE_INCIDENCE_DEG))
    for hid in hids:
        h = cfg.heliostat(hid)
        home = np.asarray(cfg.target(h.target).center_enu_m, dtype=float)
        pos = np.asarray(h.position_enu_m, dtype=float)
        ok = []
        for t in cfg.targets:
            if t.id == h.target or t.id not in cams:
                continue
            centre = np.asarray(t.center_enu_m, dtype=float)
            if float(np.dot(optics.unit(pos - centre), np.asarray(t.normal_enu, dtype=float))) >= cos_max:
                ok.append((float(np.linalg.norm(centre - home)), t.id))
        for rank, (_d, tid) in enumerate(sorted(ok), start=1):
            out[tid][hid] = rank
    return out


def test_shared_targets_match_the_boards_found_one_heliostat_at_a_time(demo_data, write_field):
    base = demo_data["targets"][0]
    # five boards: T3 and T2 equally far from T1 (a tie the id breaks), T5 facing away from the field
    layout = {"T1": (9.0, [0.0, 0.81915, -0.57358]), "T2": (-9.0, [0.0, 0.81915, -0.57358]),
              "T3": (27.0, [0.0, 0.81915, -0.57358]), "T4": (-27.0, [0.34202, 0.76975, -0.53898]),
              "T5": (45.0, [0.0, -0.81915, -0.57358])}
    demo_data["targets"] = [dict(base, id=tid, center_enu_m=[x, 8.0, 95.0], normal_enu=n, standby_offset_m=[0.0, 15.0])
                            for tid, (x, n) in layout.items()]
    cam = demo_data["cameras"][0]
    demo_data["cameras"] = [dict(cam, id=f"C{tid}", target=tid, url=f"http://127.0.0.1:8081/{tid}.png",
                                 position_enu_m=[x, 75.0 if n[1] > 0 else -60.0, 2.0])
                            for tid, (x, n) in layout.items()]
    for k, h in enumerate(demo_data["heliostats"]):
        h["target"] = ("T1", "T2", "T3", "T4")[k % 4]
    cfg = load_field_config(write_field(demo_data))
    hids = [h.id for h in cfg.heliostats]
    for cams in ({"T1", "T2", "T3", "T4", "T5"}, {"T1", "T3"}):
        got = choice.shared_targets(cfg, hids, cams)
        assert got == _reference_shared(cfg, hids, cams)
        assert sum(len(v) for v in got.values()) > len(hids)  # boards are lent, some heliostats borrow several
    assert choice.shared_targets(cfg, [], {"T1"}) == {t.id: {} for t in cfg.targets}


def test_blank_needs_are_judged_again_when_the_days_or_the_evaluation_day_change(demo_field_path):
    from helicalib.app.simulated import default_start_s
    from helicalib.calibration import acceptance
    from helicalib.campaign.book import Book
    from helicalib.campaign.verdict import verdict

    cfg = load_field_config(demo_field_path)
    book = Book(cfg, [h.id for h in cfg.heliostats])
    hid, tb = cfg.heliostats[0].id, book.table
    judged = []

    def needs_at(now_s):
        days = book.days(now_s)

        def judge():
            judged.append(now_s)
            return verdict(cfg, book, hid, None, now_s)

        got = tb.blank_needs(days, now_s, judge)
        v = verdict(cfg, book, hid, None, now_s)
        assert got == (acceptance.needs(v, cfg.acceptance), bool(v.accepted))  # as judging it now
        return days

    t0 = default_start_s(cfg) + 12 * 3600.0  # local noon: the day's high span has begun
    days = needs_at(t0)
    needs_at(t0 + 600.0)
    needs_at(t0 + 3 * 3600.0)
    assert judged == [t0]  # the same days, the same evaluation day: judged once
    ref = acceptance.evaluation_day(days, t0)
    tomorrow = next(d.high_start_s for d in days if d.high_start_s is not None and d.high_start_s > ref.high_start_s)
    needs_at(tomorrow + 60.0)
    assert judged == [t0, tomorrow + 60.0]  # the next day's high span began: judged again
    book._days_span = (float("inf"), -float("inf"))  # the solar days are computed afresh (a new object)
    needs_at(tomorrow + 120.0)
    assert judged == [t0, tomorrow + 60.0, tomorrow + 120.0]
