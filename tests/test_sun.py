"""Solar ephemeris against the published SPA example (Reda & Andreas 2004, table A4.1)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.errors import ConfigError
from helicalib.geometry.sun import angles_from_sun_vector, sun_position, sun_vector_from_angles, to_unix_seconds

SPA = dict(latitude_deg=39.742476, longitude_deg=-105.1786, altitude_m=1830.14, pressure_hpa=820.0, temperature_c=11.0)
SPA_TIME = "2003-10-17T12:30:30-07:00"


def test_spa_paper_example():
    pos = sun_position(SPA_TIME, delta_t_s=67.0, **SPA)
    assert float(pos.zenith_deg) == pytest.approx(50.11162, abs=1e-4)
    assert float(pos.azimuth_deg) == pytest.approx(194.34024, abs=1e-4)
    assert float(pos.elevation_deg) == pytest.approx(90 - 50.11162, abs=1e-4)


def test_vector_is_unit_and_matches_angles():
    times = pd.date_range("2026-03-20T00:00Z", periods=48, freq="30min")
    pos = sun_position(times, 40.07, 94.43, 1270.0)
    np.testing.assert_allclose(np.linalg.norm(pos.vector_enu, axis=-1), 1.0, atol=1e-12)
    # independent: east component = cos(el) sin(az) etc.
    el, az = np.radians(pos.elevation_deg), np.radians(pos.azimuth_deg)
    np.testing.assert_allclose(pos.vector_enu[:, 0], np.cos(el) * np.sin(az), atol=1e-12)
    np.testing.assert_allclose(pos.vector_enu[:, 2], np.sin(el), atol=1e-12)


def test_vectorised_over_times_and_sites_matches_scalar_calls():
    times = ["2026-06-21T04:00:00Z", "2026-06-21T09:00:00Z"]
    lats = np.array([[40.0], [-23.5]])
    pos = sun_position(times, lats, 94.4, 1000.0)
    assert pos.azimuth_deg.shape == (2, 2)
    for i, lat in enumerate(lats[:, 0]):
        for j, t in enumerate(times):
            one = sun_position(t, lat, 94.4, 1000.0)
            assert pos.azimuth_deg[i, j] == pytest.approx(float(one.azimuth_deg), abs=1e-9)
            assert pos.elevation_deg[i, j] == pytest.approx(float(one.elevation_deg), abs=1e-9)


def test_refraction_follows_pressure():
    # near the horizon, lower pressure gives less refraction (a lower apparent elevation)
    t = "2026-06-21T23:30:00Z"  # shortly after sunrise at 94°E
    high = sun_position(t, 40.07, 94.43, 0.0, pressure_hpa=1010.0).elevation_deg
    low = sun_position(t, 40.07, 94.43, 0.0, pressure_hpa=700.0).elevation_deg
    assert 0 < float(high) < 15
    assert float(high) > float(low)


def test_naive_time_is_refused():
    with pytest.raises(ConfigError, match="no timezone"):
        sun_position("2003-10-17T12:30:30", 39.7, -105.2)


def test_pandas_index_seconds_are_exact():
    idx = pd.DatetimeIndex(["2026-01-01T00:00:00.5Z"])
    assert to_unix_seconds(idx)[0] == pytest.approx(1767225600.5)


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 359.99), st.floats(-89.9, 89.9))
def test_angles_vector_round_trip(az, el):
    back_az, back_el = angles_from_sun_vector(sun_vector_from_angles(az, el))
    assert float(back_el) == pytest.approx(el, abs=1e-9)
    assert (float(back_az) - az + 180) % 360 - 180 == pytest.approx(0, abs=1e-7)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "helicalib", *args], capture_output=True, text=True, timeout=120)


def test_sun_cli_json():
    r = _cli("sun", "--lat", "39.742476", "--lon", "-105.1786", "--time", SPA_TIME, "--altitude-m", "1830.14",
             "--pressure-hpa", "820", "--temperature-c", "11", "--delta-t-s", "67", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["zenith_deg"] == pytest.approx(50.11162, abs=1e-4)
    assert out["azimuth_deg"] == pytest.approx(194.34024, abs=1e-4)
    assert len(out["vector_enu"]) == 3


def test_sun_cli_refuses_naive_time():
    r = _cli("sun", "--lat", "39.7", "--lon", "-105.2", "--time", "2003-10-17T12:30:30")
    assert r.returncode == 1
    assert "no timezone offset" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_sun_table_one_instant_matches_the_array_path_and_spa():
    """The table's one-instant path (and ``position``'s kept instants) give the array path's values
    to the bit, and both stay within the chunk interpolation's bound of SPA itself."""
    from helicalib.config import Site
    from helicalib.geometry.sun import SunTable, sun_at_site

    site = Site(name="t", latitude_deg=40.063, longitude_deg=94.426, altitude_m=1267.0)
    table = SunTable(site)
    rng = np.random.default_rng(3)
    times = 1_780_000_000.0 + np.concatenate([rng.uniform(0.0, 3 * 86400.0, 200), [0.0, 86400.0, 60.0]])
    batch = table.vector_enu(times)
    direct = np.asarray(sun_at_site(site, times).vector_enu)
    for k, t in enumerate(times):
        one = table.vector_enu(t)
        assert one.shape == (3,) and np.array_equal(one, batch[k])
        vec, az, el, rising = table.position(t)
        vec[:] = 0.0  # a caller's copy: the kept instant is not changed
        again = table.position(t)
        assert np.array_equal(again[0], batch[k]) and (again[1], again[2], again[3]) == (az, el, rising)
        later = table.vector_enu(t + 60.0)
        assert rising == bool(later[2] > batch[k][2])
    miss = np.arccos(np.clip(np.sum(batch * direct, axis=1), -1.0, 1.0))
    assert miss.max() < 5e-6  # rad: the chord error over a 60 s grid (~2.4e-6) and round-off
