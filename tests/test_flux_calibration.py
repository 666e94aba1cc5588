"""F_e by two radiometers (paper eq. 2), by the camera on the sun, G_av, and ε_sys."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from helicalib.flux.calibration import (
    fe_camera_on_sun,
    fe_two_radiometer,
    mean_grey_in_circle,
    single_radiometer_error,
    sun_grey_sum,
    system_error,
)
from helicalib.flux.corrections import flat_field_factors, nonuniformity_error, relative_response, response_curve
from helicalib.flux.grid import board_grid


def test_two_radiometer_worked_example_gives_the_papers_fe():
    """Radiometer a reads 462.4 W/m² with b at 100 W/m²; with a removed b reads 95 W/m² (the sun
    dimmed 5 %) and G_av = 190. The flux at the focus during the frame was 462.4·0.95 = 439.28 W/m²,
    so F_e = 439.28 / 190 = 2.312, the value the paper reports (section 4)."""
    assert fe_two_radiometer(462.4, 100.0, 95.0, 190.0) == pytest.approx(2.312, abs=1e-12)
    # a single radiometer would have given 462.4 / 190 = 2.4337, 5.26 % high
    assert single_radiometer_error(100.0, 95.0) == pytest.approx(0.05)
    assert 462.4 / 190.0 / 2.312 - 1 == pytest.approx(1 / 0.95 - 1)


@given(st.floats(1, 1e6), st.floats(1, 1e6), st.floats(0.5, 2.0), st.floats(1, 255))
def test_two_radiometer_tracks_the_sunlight_change(ea, eb, ratio, gav):
    """Scaling sunlight by r between the two readings scales F_e by r; equal b readings give Ea/Gav."""
    assert fe_two_radiometer(ea, eb, eb, gav) == pytest.approx(ea / gav, rel=1e-12)
    assert fe_two_radiometer(ea, eb, eb * ratio, gav) == pytest.approx(ratio * ea / gav, rel=1e-12)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_two_radiometer_refuses_non_positive(bad):
    with pytest.raises(ValueError, match="gav_grey"):
        fe_two_radiometer(1.0, 1.0, 1.0, bad)


def test_gav_is_the_mean_over_the_radiometer_area():
    grid = board_grid((2.0, 2.0), 0.002)
    uu, vv = grid.mesh_m()
    g = 100.0 + 10.0 * uu + 50.0 * vv  # linear field: the disc mean is the value at the centre
    assert mean_grey_in_circle(g, grid, (0.3, -0.2), math.pi * 0.05**2) == pytest.approx(100 + 3 - 10, abs=0.01)
    # a paraboloid: mean over a disc of radius R of r² is R²/2
    g2 = (uu - 0.1) ** 2 + (vv + 0.4) ** 2
    assert mean_grey_in_circle(g2, grid, (0.1, -0.4), math.pi * 0.2**2) == pytest.approx(0.2**2 / 2, rel=0.01)


def test_camera_on_the_sun_recovers_fe():
    """Independent forward model: a camera with c grey per unit radiance sees the sun disc
    (radius 4.65 mrad, limb-darkened) through an ND filter and a Lambertian board under flux E."""
    fx = fy = 20000.0  # px; the sun is 93 px in radius
    c = 2.0e-4  # grey per W/(m² sr)
    dni, tau, rho = 900.0, 1e-3, 0.9
    r_sun = 4.65e-3 * fx
    yy, xx = np.indices((301, 301), dtype=float)
    r = np.hypot(xx - 150.3, yy - 149.6) / r_sun
    mu = np.sqrt(np.clip(1 - r**2, 0, 1))
    shape = np.where(r < 1, 1 - 0.6 * (1 - mu), 0.0)  # limb darkening
    # normalise the radiance so that its integral over the disc is DNI
    omega_px = 1.0 / (fx * fy)
    radiance = dni * shape / (shape.sum() * omega_px)
    sun = c * tau * radiance
    e_board = 50_000.0
    g_board = c * rho * e_board / math.pi
    fe = fe_camera_on_sun(sun_grey_sum(sun), omega_px, dni, tau, rho)
    assert fe == pytest.approx(e_board / g_board, rel=1e-9)


def test_system_error_is_root_sum_square():
    # the paper's survey ranges at their upper ends: dark 1 %, NL 4 %, NU 0.6 %, LB 8 %
    eps = system_error({"dark": 0.01, "nonlinearity": 0.04, "nonuniformity": 0.006, "non_lambertian": 0.08})
    assert eps == pytest.approx(math.sqrt(0.0001 + 0.0016 + 0.000036 + 0.0064))
    assert eps == pytest.approx(0.0902, abs=1e-4)  # sqrt(0.008136)
    assert system_error({}) == 0.0
    with pytest.raises(ValueError, match="dark"):
        system_error({"dark": -0.1})


def test_flat_field_factors_and_nonuniformity_error():
    flat = np.array([[90.0, 110.0], [100.0, 100.0]])
    a = flat_field_factors(flat)
    assert np.allclose(a, [[100 / 90, 100 / 110], [1.0, 1.0]])  # G_mean / G_i (eq. 6)
    assert np.allclose(flat * a, 100.0)
    assert nonuniformity_error(flat) == pytest.approx(math.sqrt((100 + 100 + 0 + 0) / 4) / 100)  # eq. 5


def test_response_curve_linearises_a_known_nonlinearity():
    b = np.linspace(0, 10, 41)
    grey = 5.0 + 20.0 * b - 0.6 * np.clip(b - 5, 0, None) ** 2  # linear to b = 5, then saturating
    curve = response_curve(b, grey, linear_up_to_grey=105.0)
    assert curve.k0_grey == pytest.approx(5.0) and curve.k1_grey_per_input == pytest.approx(20.0)
    assert np.allclose(curve.linearise(grey), 5.0 + 20.0 * b)  # exact at the measured points
    assert curve.linearise(np.array(50.0)) == pytest.approx(50.0)  # identity in the linear part
    with pytest.raises(ValueError, match="increasing"):
        response_curve([0, 1, 1], [0, 1, 2])


def test_relative_response_interpolates_eq7_table():
    assert relative_response(30.0, [0, 20, 40], [1.0, 0.96, 0.92]) == pytest.approx(0.94)
    assert relative_response(-30.0, [0, 20, 40], [1.0, 0.96, 0.92]) == pytest.approx(0.94)
    assert relative_response(70.0, [0, 20, 40], [1.0, 0.96, 0.92]) == pytest.approx(0.92)
