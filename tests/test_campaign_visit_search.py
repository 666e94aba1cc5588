"""The visit's search after a clipped reading (``campaign.visit._next_search_aim``): the next aim puts
the spot at the board's centre from wherever the beam was aimed (a ring point, an earlier search aim).

An observation's offsets are from its aim point (``campaign.measure``), so a clipped spot seen
``seen`` metres from its aim tells a beam that misses its aim by about ``seen``.
"""

from __future__ import annotations

import numpy as np
import pytest

from helicalib.campaign.visit import _next_search_aim, _search_aims
from helicalib.config import load_field_config
from helicalib.store.records import Observation


@pytest.fixture(scope="module")
def target(demo_field_path):
    return load_field_config(demo_field_path).targets[0]


def _clipped(seen_uv, reason="clipped") -> Observation:
    return Observation(
        campaign_id=1, heliostat_id="H0001", target_id="T1", visit_id=1, iteration=1, capture_time_s=1.0e9,
        strokes_cmd_mm=(812.5, 640.25), strokes_read_mm=(812.4, 640.3), sun_enu=(0.0, 0.5, 0.866),
        sun_azimuth_deg=180.0, sun_elevation_deg=60.0, sun_rising=True, wind_ms=3.0, wind_direction_deg=270.0,
        dni_wm2=850.0, temperature_c=21.5, cleanliness=0.93, valid=False, reason=reason, message="",
        offset_u_m=None if seen_uv is None else float(seen_uv[0]),
        offset_v_m=None if seen_uv is None else float(seen_uv[1]),
        spot_x_px=None, spot_y_px=None, spot_area_px=None, threshold=None, jitter_px=None, spot_enu_m=None,
        error_mrad=None)


def _uv(target, enu):
    return target.enu_to_uvw(enu)[:2]


def test_from_the_centre_the_next_aim_is_opposite_to_the_spot(target):
    nxt = _next_search_aim(target, _clipped((3.0, -1.0)), target.uvw_to_enu(np.zeros(2)), [])
    assert np.allclose(_uv(target, nxt), [-3.0, 1.0], atol=1e-9)


def test_from_a_ring_point_the_next_aim_puts_the_spot_at_the_centre_not_back_at_the_ring_point(target):
    ring = np.array([0.35 * min(target.size_m), 0.0])
    nxt = _next_search_aim(target, _clipped((-1.6, 0.2)), target.uvw_to_enu(ring), [])
    uv = _uv(target, nxt)
    assert np.allclose(uv, [1.6, -0.2], atol=1e-9)
    # the spot lands at the new aim plus the beam's miss: the board's centre
    assert np.allclose(uv + np.array([-1.6, 0.2]), 0.0, atol=1e-9)


def test_the_next_aim_stays_on_the_inner_board(target):
    w = target.size_m[0]
    nxt = _next_search_aim(target, _clipped((-9.0, 0.0)), target.uvw_to_enu(np.array([1.0, 1.0])), [])
    assert np.allclose(_uv(target, nxt), [0.4 * w, 0.0], atol=1e-9)


def test_an_aim_that_would_not_move_or_a_spot_not_seen_takes_the_next_ring_point(target):
    ring = _search_aims(target, 6)
    here = np.array([-1.0, 0.5])
    nxt = _next_search_aim(target, _clipped((1.0, -0.5)), target.uvw_to_enu(here), list(ring))
    assert np.allclose(_uv(target, nxt), ring[0], atol=1e-9)  # -seen is where the beam already aims
    nxt = _next_search_aim(target, _clipped(None, "no_spot"), target.uvw_to_enu(here), list(ring))
    assert np.allclose(_uv(target, nxt), ring[0], atol=1e-9)
    assert _next_search_aim(target, _clipped(None, "no_spot"), target.uvw_to_enu(here), []) is None
