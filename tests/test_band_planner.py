"""In the 5–15° band the planner takes the heliostats closest to acceptance first.

Pure: candidates with their gaps in, assignments out (:func:`helicalib.campaign.planner.plan`).
"""

from __future__ import annotations

from types import SimpleNamespace

from helicalib.calibration.acceptance import Gap
from helicalib.campaign import planner

NOW = 1000.0
GATING = SimpleNamespace(cleanliness_min=0.5, cleanliness_preferred=0.9)


def _gap(kind: str, start: float, end: float, window: int | None = None) -> Gap:
    return Gap(kind, window, start, end, f"{kind} {window}")


SETTING_OPEN = _gap("setting", NOW - 10, NOW + 3000)
RISING_TOMORROW = _gap("rising", NOW + 40000, NOW + 43000)
WINDOW_TOMORROW = _gap("window", NOW + 50000, NOW + 57000, 0)


def _cand(hid: str, gaps, err: float | None, borrowed: int = 0) -> planner.Candidate:
    return planner.Candidate(hid, "T1", gaps=tuple(gaps), predicted_error_mrad=err, borrowed=borrowed)


def test_the_band_point_that_completes_a_heliostat_goes_first():
    far = _cand("H1", [SETTING_OPEN, RISING_TOMORROW, WINDOW_TOMORROW], None)  # new: infinite predicted error
    near = _cand("H2", [SETTING_OPEN], 0.5)
    out = planner.plan([far, near], NOW, GATING)
    assert [(a.heliostat_id, a.tier) for a in out] == [("H2", planner.TIER_LOW_BAND)]
    # one need more: the other goes first again (then the larger predicted error decides)
    out = planner.plan([_cand("H1", [SETTING_OPEN, WINDOW_TOMORROW], 3.0),
                        _cand("H2", [SETTING_OPEN, RISING_TOMORROW], 1.0)], NOW, GATING)
    assert out[0].heliostat_id == "H1"


def test_outside_the_band_the_needs_do_not_order():
    window_open = _gap("window", NOW - 10, NOW + 3000, 1)
    many = _cand("H1", [window_open, RISING_TOMORROW, WINDOW_TOMORROW], 4.0)
    few = _cand("H2", [window_open], 1.0)
    assert planner.plan([many, few], NOW, GATING)[0].heliostat_id == "H1"  # the larger predicted error
    assert planner.band_needs(planner.TIER_WINDOW, 3) == 0 and planner.band_needs(planner.TIER_LOW_BAND, 3) == 3


def test_a_guest_still_follows_the_boards_own_heliostats_of_its_band():
    own = _cand("H1", [SETTING_OPEN, RISING_TOMORROW, WINDOW_TOMORROW], 2.0)
    guest = _cand("H9", [SETTING_OPEN], 2.0, borrowed=1)
    assert planner.plan([guest, own], NOW, GATING)[0].heliostat_id == "H1"
    key = planner.rank(own, NOW, GATING)
    assert key[:4] == (planner.TIER_LOW_BAND, SETTING_OPEN.next_end_s, 0, 3)
