"""The campaign's bookkeeping: the spot's measured cleanliness gates a mirror when the plant gives none."""

from __future__ import annotations

import math

from helicalib.campaign.book import Book
from helicalib.campaign.choice import choose_next
from helicalib.app.simulated import default_start_s
from helicalib.config import load_field_config
from helicalib.store.records import Observation


def _obs(hid: str, t: float, cleanliness_measured: float) -> Observation:
    return Observation(campaign_id=1, heliostat_id=hid, target_id="T2", visit_id=1, iteration=0, capture_time_s=t,
                       strokes_cmd_mm=(900.0, 800.0), strokes_read_mm=None, sun_enu=(0.0, -0.5, 0.866),
                       sun_azimuth_deg=180.0, sun_elevation_deg=60.0, valid=False, reason="no_spot",
                       cleanliness_measured=cleanliness_measured)


def test_measured_cleanliness_gates_when_the_plant_gives_none(demo_field_path):
    cfg = load_field_config(demo_field_path)
    now = default_start_s(cfg) + 9 * 3600  # mid-morning: acceptance gaps are open
    book = Book(cfg, ["H0001", "H0002"])
    # H0001 measured too dirty (below cleanliness_min 0.55), H0002 clean enough; the newest measure counts
    book.add(_obs("H0001", now - 7200, 0.9))
    book.add(_obs("H0001", now - 3600, 0.40))
    book.add(_obs("H0002", now - 3600, 0.80))
    nan = {"H0001": math.nan, "H0002": math.nan}
    assert book.h["H0001"].measured_cleanliness == 0.40
    assert choose_next(cfg, book, ["H0001", "H0002"], now, nan) == "H0002"
    assert choose_next(cfg, book, ["H0001"], now, nan) is None
    # a plant reading, when there is one, comes first
    assert choose_next(cfg, book, ["H0001"], now, {"H0001": 0.9}) == "H0001"
