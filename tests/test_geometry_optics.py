"""Optics: reflection, aim normal with mirror offset, target intersection, T/GRLM formula (1)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.config import Target
from helicalib.geometry import optics


def test_reflect_simple_case():
    # sun straight up, mirror at 45° facing north-up: the beam goes due north
    r = optics.reflect(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 1.0]) / math.sqrt(2))
    np.testing.assert_allclose(r, [0.0, 1.0, 0.0], atol=1e-15)


@settings(max_examples=100, deadline=None)
@given(st.floats(0, 360), st.floats(5, 89), st.floats(0, 360), st.floats(5, 89))
def test_reflect_law_of_reflection(az_s, el_s, az_n, el_n):
    s = np.array([math.sin(math.radians(az_s)) * math.cos(math.radians(el_s)),
                  math.cos(math.radians(az_s)) * math.cos(math.radians(el_s)), math.sin(math.radians(el_s))])
    n = np.array([math.sin(math.radians(az_n)) * math.cos(math.radians(el_n)),
                  math.cos(math.radians(az_n)) * math.cos(math.radians(el_n)), math.sin(math.radians(el_n))])
    r = optics.reflect(s, n)
    assert abs(np.linalg.norm(r) - 1) < 1e-12
    assert abs(r @ n - s @ n) < 1e-12  # equal angles with the normal
    assert abs(np.cross(s, n) @ r) < 1e-12  # s, n, r coplanar


@settings(max_examples=100, deadline=None)
@given(st.floats(-150, 150), st.floats(30, 200), st.floats(0, 360), st.floats(5, 89), st.floats(0, 0.6))
def test_aim_normal_beam_hits_aim_from_mirror_centre(e, nn, az, el, offset):
    p = np.array([e, nn, 4.0])
    t = np.array([0.0, 8.0, 95.0])
    s = np.array([math.sin(math.radians(az)) * math.cos(math.radians(el)),
                  math.cos(math.radians(az)) * math.cos(math.radians(el)), math.sin(math.radians(el))])
    n = optics.aim_normal(p, s, t, offset)
    m = optics.mirror_centre(p, n, offset)
    r = optics.reflect(s, n)
    miss_mrad = 1000 * optics.angle_between_rad(r, t - m)
    assert miss_mrad < 1e-7


def test_mirror_offset_matters():
    p, t, s = np.array([0.0, 100.0, 4.0]), np.array([0.0, 8.0, 95.0]), np.array([0.0, -0.5, 0.866])
    n0 = optics.aim_normal(p, s, t, 0.0)
    n1 = optics.aim_normal(p, s, t, 0.3)
    assert 1000 * optics.angle_between_rad(n0, n1) > 0.1


def _target(normal=(0.0, 1.0, 0.0)):
    return Target(id="T", center_enu_m=(0.0, 8.0, 95.0), normal_enu=normal, size_m=(12.0, 12.0))


def test_intersect_target_frame_and_validity():
    t = _target()
    # the frame: u = unit(z × w) = (-1, 0, 0) for a north-facing board (right as seen from the field), v up
    origin = np.array([[3.0, 100.0, 97.0], [0.0, 100.0, 95.0], [0.0, 100.0, 95.0]])
    direction = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    uv, hit, valid = optics.intersect_target(origin, direction, t)
    assert valid.tolist() == [True, False, False]  # hits; parallel; points away
    np.testing.assert_allclose(uv[0], [-3.0, 2.0])
    np.testing.assert_allclose(hit[0], [3.0, 8.0, 97.0])
    assert np.all(np.isnan(uv[1:]))


def test_tglm_formula_1_worked_example():
    # T/GRLM 02-2014 formula (1): η = sqrt((xi−x0)²/μ² + (yi−y0)²/μ²) / L × 1000.
    # Target centre at pixel (640, 512), spot centre at (670, 552), μ = 10 px/m, L = 1000 m:
    # sqrt(30² + 40²) / 10 = 5 m, 5 / 1000 × 1000 = 5 mrad.
    x0, y0, xi, yi, mu, L = 640, 512, 670, 552, 10.0, 1000.0
    eta = math.sqrt((xi - x0) ** 2 / mu**2 + (yi - y0) ** 2 / mu**2) / L * 1000
    assert eta == 5.0
    pivot = np.array([0.0, 1008.0, 95.0])  # L = 1000 m north of the aim point, level with it
    aim = np.array([0.0, 8.0, 95.0])
    spot = aim + np.array([-(xi - x0) / mu, 0.0, (yi - y0) / mu])  # u points west on a north-facing board
    assert optics.tracking_error_mrad(spot, aim, pivot) == eta
    exact = optics.tracking_error_exact_mrad(spot, aim, pivot)
    np.testing.assert_allclose(exact, 1000 * math.atan(5.0 / 1000.0), rtol=1e-12)  # spot ⊥ line of sight
