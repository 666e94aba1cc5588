"""Drive kinematics and push-rod linkage: paired inverses as hypothesis round trips, and preset meanings."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.config import PRESETS
from helicalib.geometry.drives import (
    DriveArrays,
    angle_interval_rad,
    angles_to_normal,
    angles_to_strokes,
    normal_to_angles,
    rotate,
    strokes_in_range,
    strokes_to_angles,
)


def make_drives(n, a1, a2, n0, ra=1.6, rb=1.1, gamma0_deg=(60.0, 90.0), sign=(1.0, 1.0), l0=(0.8, 0.5),
                smin=(0.0, 0.0), smax=(1850.0, 1590.0)):
    def rows(v, w):
        return np.broadcast_to(np.asarray(v, dtype=float), (n, w)).copy()

    return DriveArrays(
        axis1_enu=rows(a1, 3), axis2_enu=rows(a2, 3), normal0_enu=rows(n0, 3),
        arm_fixed_m=rows(ra, 2), arm_moving_m=rows(rb, 2), gamma0_rad=np.radians(rows(gamma0_deg, 2)),
        sign=rows(sign, 2), length_at_zero_m=rows(l0, 2), stroke_min_mm=rows(smin, 2), stroke_max_mm=rows(smax, 2),
        mirror_offset_m=np.full(n, 0.25), mirror_size_m=rows((4.5, 4.5), 2),
    )


def unit_vectors():
    return st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: 0.3 < math.sqrt(sum(x * x for x in v))).map(
        lambda v: tuple(np.asarray(v) / np.linalg.norm(v)))


linkage = st.fixed_dictionaries({
    "ra": st.floats(0.3, 2.5), "rb": st.floats(0.3, 2.5), "gamma0_deg": st.floats(5, 175),
    "sign": st.sampled_from([1.0, -1.0]), "l0": st.floats(0.05, 1.0),
})


@settings(max_examples=200, deadline=None)
@given(linkage, st.floats(0.02, 0.98), st.floats(0.02, 0.98))
def test_angles_strokes_angles_round_trip(k, f1, f2):
    d = make_drives(1, (1, 0, 0), (0, 1, 0), (0, 0, 1), ra=k["ra"], rb=k["rb"], gamma0_deg=k["gamma0_deg"],
                    sign=k["sign"], l0=k["l0"])
    low, high = angle_interval_rad(d)
    angles = low + np.array([[f1, f2]]) * (high - low)
    strokes = angles_to_strokes(d, angles)
    assert np.all(np.isfinite(strokes))
    np.testing.assert_allclose(strokes_to_angles(d, strokes), angles, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(linkage, st.floats(0.01, 0.99), st.floats(0.01, 0.99))
def test_strokes_angles_strokes_round_trip(k, f1, f2):
    ra, rb = k["ra"], k["rb"]
    d = make_drives(1, (1, 0, 0), (0, 1, 0), (0, 0, 1), ra=ra, rb=rb, gamma0_deg=k["gamma0_deg"], sign=k["sign"],
                    l0=k["l0"])
    lmin, lmax = abs(ra - rb), ra + rb  # the triangle exists strictly between these lengths
    lengths = lmin + np.array([[f1, f2]]) * (lmax - lmin)
    strokes = 1000.0 * (lengths - k["l0"])
    angles = strokes_to_angles(d, strokes)
    assert np.all(np.isfinite(angles))
    np.testing.assert_allclose(angles_to_strokes(d, angles), strokes, atol=1e-6)


def test_linkage_law_of_cosines_independent():
    # γ0 = 90°, θ = 0: right triangle, ℓ = hypot(ra, rb); θ = +30° with sign −1 → γ = 60°: ℓ² = ra²+rb²−ra·rb
    d = make_drives(1, (1, 0, 0), (0, 1, 0), (0, 0, 1), ra=1.2, rb=0.9, gamma0_deg=(90, 90), sign=(1, -1), l0=(0.5, 0.5))
    s = angles_to_strokes(d, np.array([[0.0, math.radians(30)]]))
    assert s[0, 0] == np.float64(1000 * (math.hypot(1.2, 0.9) - 0.5))
    np.testing.assert_allclose(s[0, 1], 1000 * (math.sqrt(1.44 + 0.81 - 1.08) - 0.5), rtol=1e-12)


def test_impossible_values_are_nan_not_clipped():
    d = make_drives(1, (1, 0, 0), (0, 1, 0), (0, 0, 1), ra=1.2, rb=0.9, gamma0_deg=(90, 90), l0=(0.5, 0.5))
    # γ = 90° + 100° > 180°: no triangle angle
    assert np.all(np.isnan(angles_to_strokes(d, np.radians([[100.0, -95.0]]))))
    # lengths beyond ra + rb = 2.1 m or below |ra − rb| = 0.3 m
    assert np.all(np.isnan(strokes_to_angles(d, np.array([[1700.0, -250.0]]))))
    ok = strokes_in_range(d, np.array([[-1.0, 1590.0], [np.nan, 10.0]]))
    assert ok.tolist() == [[False, True], [False, True]]


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(sorted(PRESETS)), st.floats(0.03, 0.97), st.floats(0.03, 0.97),
       st.floats(10, 170), st.floats(10, 170))
def test_angles_normal_angles_round_trip_presets(kind, f1, f2, g1, g2):
    a1, a2, n0 = PRESETS[kind]
    d = make_drives(1, a1, a2, n0, gamma0_deg=(g1, g2))
    low, high = angle_interval_rad(d)
    angles = low + np.array([[f1, f2]]) * (high - low)
    normal = angles_to_normal(d, angles)
    back, reachable = normal_to_angles(d, normal)
    assert reachable.all()
    np.testing.assert_allclose(angles_to_normal(d, back), normal, atol=1e-9)  # the same normal, always
    if abs(float(normal[0] @ np.asarray(a1, float))) < 1.0 - 1e-9:
        # the same angles, except where the normal lies along axis 1: there (gimbal lock, e.g. an
        # azimuth-elevation mirror facing straight down) every first angle gives that normal
        np.testing.assert_allclose(back, angles, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(unit_vectors(), unit_vectors(), unit_vectors(), st.floats(-3, 3), st.floats(-3, 3))
def test_normal_angles_normal_round_trip_custom_axes(a1, a2, n0, t1, t2):
    a1, a2, n0 = map(np.asarray, (a1, a2, n0))
    if abs(a1 @ a2) > 0.95 or abs(a2 @ n0) > 0.95:  # degenerate drives (parallel axes)
        return
    if abs(a1 @ n0) > 0.95:  # near gimbal lock: test_round_trip_at_gimbal_lock_is_inside_the_contract
        return
    d = make_drives(1, a1, a2, n0, gamma0_deg=(90, 90))
    normal = angles_to_normal(d, np.array([[t1, t2]]))
    back, _ = normal_to_angles(d, normal)
    assert np.all(np.isfinite(back))  # the normal came from the drive, so a solution exists
    # where the two cones touch (the edge of the reachable set) the closed form loses half the digits
    # (sqrt of a rounding error): 1e-8 rad = 1e-5 mrad, still 1000× inside the 0.01 mrad contract
    np.testing.assert_allclose(angles_to_normal(d, back), normal, atol=1e-8)


def test_azimuth_elevation_preset_means_normal_azimuth_and_elevation():
    d = make_drives(3, *PRESETS["azimuth-elevation"], gamma0_deg=(5, 90))
    az = np.radians([30.0, 135.0, 170.0])
    el = np.radians([10.0, 45.0, 80.0])
    n = angles_to_normal(d, np.stack([az, el], axis=-1))
    expect = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=-1)  # from north, clockwise
    np.testing.assert_allclose(n, expect, atol=1e-12)


def test_tilt_roll_preset_directions():
    d = make_drives(2, *PRESETS["tilt-roll"])
    n = angles_to_normal(d, np.radians([[20.0, 0.0], [0.0, 20.0]]))
    s, c = math.sin(math.radians(20)), math.cos(math.radians(20))
    np.testing.assert_allclose(n, [[0, -s, c], [s, 0, c]], atol=1e-12)  # θ1 toward −y, θ2 toward +x


def test_unreachable_normal_is_flagged():
    # azimuth-elevation, azimuth linkage γ0 = 90° (θ1 in (-90°, 90°)), elevation γ0 = 100° (θ2 in (-100°, 80°)):
    # the zenith (elevation 90°) is out of reach on both branches, elevation 65° at azimuth 45° is fine
    d = make_drives(2, *PRESETS["azimuth-elevation"], gamma0_deg=(90, 100))
    n = np.array([[0.0, 0.0, 1.0], [0.3, 0.3, 0.9]])
    angles, reachable = normal_to_angles(d, n / np.linalg.norm(n, axis=1, keepdims=True))
    assert reachable.tolist() == [False, True]
    np.testing.assert_allclose(np.degrees(angles[1]), [45.0, np.degrees(np.arcsin(0.9 / np.sqrt(0.99)))], atol=1e-9)
    # a non-orthogonal drive cannot reach normals outside its two cones: a2·n0 fixes the circle
    dn = make_drives(1, (0, 0, 1), (1, 0, 0), rotate(np.array([0.0, 0, 1]), np.array(0.0), np.array([0.8, 0.6, 0.0])))
    ang, ok = normal_to_angles(dn, np.array([[0.0, 0.0, 1.0]]))
    assert not ok[0] and np.all(np.isnan(ang))


def test_from_drives_reads_config_drive():
    from helicalib.config import Drive

    drv = Drive(kind="tilt-roll", mirror_offset_m=0.3, mirror_size_m=(7.5, 7.5), actuators=(
        {"arm_fixed_m": 1.6, "arm_moving_m": 1.1, "gamma0_deg": 90, "sign": 1, "length_at_zero_stroke_m": 0.85,
         "stroke_range_mm": (0, 1750)},
        {"arm_fixed_m": 1.2, "arm_moving_m": 0.9, "gamma0_deg": 60, "sign": -1, "length_at_zero_stroke_m": 0.62,
         "stroke_range_mm": (10, 1400)}))
    d = DriveArrays.from_drives([drv, drv])
    assert len(d) == 2
    np.testing.assert_allclose(d.gamma0_rad[0], np.radians([90, 60]))
    assert d.sign[1].tolist() == [1.0, -1.0]
    assert d.stroke_min_mm[0].tolist() == [0.0, 10.0] and d.stroke_max_mm[0].tolist() == [1750.0, 1400.0]
    np.testing.assert_array_equal(d.axis1_enu[0], [1.0, 0.0, 0.0])


@given(st.lists(st.floats(-1e3, 1e3), min_size=6, max_size=6), st.integers(1, 5))
def test_cross3_is_numpys_cross_with_broadcasting(xs, n):
    from helicalib.geometry.drives import cross3

    a = np.array(xs[:3])
    b = np.tile(np.array(xs[3:]), (n, 1)) + np.arange(n)[:, None]
    np.testing.assert_allclose(cross3(a, b), np.cross(a, b), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(cross3(b, a), np.cross(b, a), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(cross3(a, a[::-1]), np.cross(a, a[::-1]), rtol=1e-12, atol=1e-9)


def test_round_trip_at_gimbal_lock_is_inside_the_contract():
    """A zero-pose normal along axis 1 (gimbal lock: turning axis 1 does not move it) is where the
    closed form is worst: half the digits (√ε) are lost. Still far inside the 0.01 mrad contract.
    (hypothesis found a1 = n0 = (0.707, 0.031, 0.707), a2 = up: 2.4e-8 rad off.)"""
    a1 = np.array([0.7067619618147913, 0.03122592934428998, 0.7067619618147913])
    for n0 in (a1, -a1, a1 + np.array([0.0, 1e-6, 0.0])):
        d = make_drives(1, a1, np.array([0.0, 0.0, 1.0]), n0 / np.linalg.norm(n0), gamma0_deg=(90, 90))
        for t in ([0.0, 0.0], [0.3, -0.2], [-1.0, 2.0]):
            normal = angles_to_normal(d, np.array([t]))
            back, _ = normal_to_angles(d, normal)
            err_mrad = 1000.0 * np.max(np.abs(angles_to_normal(d, back) - normal))
            assert err_mrad < 1e-3  # contract: 0.01 mrad


def test_cross3_and_normal_to_angles_row_by_row_equal_the_batch():
    """``cross3`` equals ``np.cross`` under broadcasting; ``normal_to_angles`` on many rows gives
    each row's single-row answer to the bit (both solutions are scored on their own axis, never mixed
    across rows), including unreachable normals and both-solution picks."""
    from helicalib.geometry.drives import cross3

    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(7, 1, 3)), rng.normal(size=(4, 3))
    np.testing.assert_allclose(cross3(a, b), np.cross(a, b), rtol=0, atol=1e-15)
    assert cross3(a[0, 0], b[0]).shape == (3,)
    a1, a2, n0 = PRESETS["tilt-roll"]
    d = make_drives(60, a1, a2, n0, gamma0_deg=(70.0, 110.0))
    normals = rng.normal(size=(60, 3))
    normals[:45, 2] = np.abs(normals[:45, 2]) + 0.3  # mostly reachable; the last 15 point anywhere
    angles, reachable = normal_to_angles(d, normals)
    assert 0 < reachable.sum() < 60
    for k in range(60):
        one, ok = normal_to_angles(d.take([k]), normals[k:k + 1])
        np.testing.assert_array_equal(one[0], angles[k])
        assert bool(ok[0]) == bool(reachable[k])
