"""Cleanliness from the spot: attenuation model, cos incidence, intercept, and recovery of a known
cleanliness from rendered frames (our forward model and the simulated plant's board renderer)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from helicalib.flux.cleanliness import (
    atmospheric_attenuation,
    cos_incidence,
    estimate_cleanliness,
    expected_power_w,
    gaussian_intercept,
)
from helicalib.flux.grid import board_grid
from helicalib.flux.measure import auto_cell_m, measure_flux
from helicalib.flux.synth import homography_uv_to_px, render_frame


def test_clear_day_attenuation_values():
    # hand-evaluated Vittitoe & Biggs clear-day polynomial
    assert atmospheric_attenuation(0.0) == pytest.approx(0.99321)
    assert atmospheric_attenuation(500.0) == pytest.approx(0.99321 - 0.0588 + 0.004925)
    below, above = atmospheric_attenuation(np.array([999.999, 1000.001]))
    assert below == pytest.approx(above, abs=2e-5)  # the branches meet at 1 km (published coefficients are rounded)
    assert atmospheric_attenuation(2000.0) == pytest.approx(math.exp(-0.2212))
    assert atmospheric_attenuation(500.0, "hazy") == pytest.approx(0.98707 - 0.1374 + 0.008485)
    with pytest.raises(ValueError, match="1000 m"):
        atmospheric_attenuation(1500.0, "hazy")
    with pytest.raises(ValueError):
        atmospheric_attenuation(-1.0)


@given(st.floats(0, 3000), st.floats(0, 3000))
def test_attenuation_falls_with_range(a, b):
    lo, hi = sorted((a, b))
    assert 0 < atmospheric_attenuation(hi) <= atmospheric_attenuation(lo) <= 1


def test_cos_incidence_matches_the_bisector_normal():
    rng = np.random.default_rng(3)
    sun = rng.normal(size=(50, 3)) + [0, 0, 3]
    sun /= np.linalg.norm(sun, axis=1, keepdims=True)
    mirrors = rng.uniform(-100, 100, size=(50, 3)) * [1, 1, 0]
    aim = np.array([0.0, 0.0, 120.0])
    r = (aim - mirrors) / np.linalg.norm(aim - mirrors, axis=1, keepdims=True)
    n = (sun + r) / np.linalg.norm(sun + r, axis=1, keepdims=True)
    assert np.allclose(cos_incidence(sun, mirrors, aim), np.sum(sun * n, axis=1))


def test_gaussian_intercept_against_numerical_integration():
    sigma, half, off = 0.9, (2.0, 1.5), (0.7, -0.4)
    x = np.linspace(-8, 8, 1601)
    uu, vv = np.meshgrid(x, x)
    f = np.exp(-((uu - off[0]) ** 2 + (vv - off[1]) ** 2) / (2 * sigma**2)) / (2 * math.pi * sigma**2)
    on = (np.abs(uu) <= half[0]) & (np.abs(vv) <= half[1])
    numeric = float(f[on].sum() * (x[1] - x[0]) ** 2)
    assert gaussian_intercept(sigma, half, off) == pytest.approx(numeric, abs=2e-3)


def test_estimate_cleanliness_inverts_the_power_model_and_broadcasts():
    p_clean = expected_power_w(850.0, 20.25, 0.93, 0.88, 0.95, 0.98)
    assert p_clean == pytest.approx(850 * 20.25 * 0.93 * 0.88 * 0.95 * 0.98)
    c = estimate_cleanliness(np.array([0.5, 0.9]) * p_clean, 850.0, 20.25, 0.93, 0.88, 0.95, 0.98)
    assert np.allclose(c, [0.5, 0.9])
    assert math.isnan(estimate_cleanliness(1000.0, 0.0, 20.25, 0.93, 0.88, 0.95, 1.0))


def test_cleanliness_recovered_from_rendered_frames(tmp_path):
    """A soiled mirror (c = 0.72) whose Gaussian spot is partly off the board: measured power,
    with the intercept from the spot model, gives back c."""
    dni, area, rho, c_true, cos_i, slant = 870.0, 20.25, 0.93, 0.72, 0.91, 95.0
    tau = atmospheric_attenuation(slant)
    sigma, off, size = 1.3, (4.6, 0.5), (12.0, 12.0)
    p_beam = dni * area * rho * c_true * cos_i * tau  # all of it, on and off the board
    fe = 8.0  # W/m² per grey: the spot peaks about 120 grey above the ambient board
    peak = p_beam / (2 * math.pi * sigma**2)

    def flux(u, v):
        return peak * np.exp(-((u - off[0]) ** 2 + (v - off[1]) ** 2) / (2 * sigma**2))

    k = np.array([[2600.0, 0, 320.0], [0, 2600.0, 256.0], [0, 0, 1]])
    h = homography_uv_to_px((9.0, 8.0, 95.0), np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]]),
                            (14.0, 75.0, 2.0), k)
    kw = dict(fe_wm2_per_grey=fe, noise_grey=1.0)
    before = render_frame((512, 640), h, size, None, rng=np.random.default_rng(1), **kw)
    after = render_frame((512, 640), h, size, flux, rng=np.random.default_rng(2), **kw)
    for name, img in (("b.png", before), ("a.png", after)):
        cv2.imwrite(str(tmp_path / name), img)
    before = cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_GRAYSCALE)
    after = cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_GRAYSCALE)
    hp = np.linalg.inv(h)
    grid = board_grid(size, auto_cell_m(hp, before.shape))
    fm = measure_flux(before, after, hp, grid, fe).fluxmap
    intercept = gaussian_intercept(sigma, (6.0, 6.0), off)
    assert intercept < 0.9  # the test really exercises the intercept
    c = estimate_cleanliness(fm.power_w, dni, area, rho, cos_i, tau, intercept)
    print("rendered cleanliness", c, "true", c_true, "intercept", intercept)
    assert c == pytest.approx(c_true, abs=0.01)


def test_cleanliness_recovered_from_the_simulated_plant_camera(tmp_path, demo_field_path):
    """The simulated plant's own board renderer (helicalib.sim.camera): a beam of heliostat H0007 on
    T1 carrying DNI·A·cos·ρ·c watts, seen by camera C1; marks found by vision.find_marks; F_e from
    the renderer's gain (1 / (albedo · counts per W/m²)). The simulated plant has no atmospheric
    attenuation, so τ = 1 here."""
    sim_camera = pytest.importorskip("helicalib.sim.camera")
    from helicalib.config import load_field_config
    from helicalib.geometry.sun import sun_vector_from_angles
    from helicalib.sim.scenario import CameraSpec, Optics
    from helicalib.vision.marks import find_marks

    cfg = load_field_config(demo_field_path)
    target, camera = cfg.target("T1"), cfg.cameras_for("T1")[0]
    h = cfg.heliostat("H0007")
    spec, optics = CameraSpec(), Optics()
    renderer = sim_camera.BoardRenderer(camera, target, spec, optics, seed=5)
    sun = np.asarray(sun_vector_from_angles(np.radians(160.0), np.radians(45.0)), dtype=float)
    origin = np.asarray(h.position_enu_m)
    d = np.asarray(target.center_enu_m) + target.frame_enu[0] * 0.8 - origin  # aimed 0.8 m off centre
    d /= np.linalg.norm(d)
    n = (sun + d) / np.linalg.norm(sun + d)
    mirror = np.asarray(cfg.drive_of("H0007").mirror_size_m)
    dni, c_true = 860.0, 0.77
    spots = renderer.spots_from_beams(origin[None], d[None], sun, n[None], mirror[None], dni, np.array([c_true]))
    assert len(spots[1]) == 1
    before, after = renderer.render(None, dni, True), renderer.render(spots, dni, True)
    for name, img in (("b.png", before), ("a.png", after)):
        cv2.imwrite(str(tmp_path / name), img)
    before = cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_GRAYSCALE)
    after = cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_GRAYSCALE)
    marks = find_marks(before, target, camera)
    assert marks.found, marks.reason
    fe = 1.0 / (spec.board_albedo * spec.gain_counts_per_wm2)
    grid = board_grid(target.size_m, auto_cell_m(marks.homography, before.shape))
    fm = measure_flux(before, after, marks.homography, grid, fe).fluxmap
    assert int(np.count_nonzero(after >= 255)) == 0
    cos_i = cos_incidence(sun, origin, origin + d)
    c = estimate_cleanliness(fm.power_w, dni, float(np.prod(mirror)), optics.reflectivity, cos_i, 1.0, 1.0)
    print("sim plant cleanliness", c, "true", c_true, "centre", fm.centre_uv_m)
    assert c == pytest.approx(c_true, abs=0.02)
    assert fm.centre_uv_m[0] == pytest.approx(0.8, abs=0.05)
