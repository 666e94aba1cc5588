"""Frames of a known flux, degraded by the test (dark, non-linearity, non-uniformity, perspective,
distortion, noise), written to and read from real PNG files, are corrected back to the known map.

The forward model is written here from the physics (not from helicalib's corrections): the camera's
true non-linearity is an analytic knee curve; FLUX data are *measurements* of it (a sampled response
curve, a rendered dark frame, a rendered integrating-sphere frame), as a crew would take them.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from helicalib.config import Target
from helicalib.flux.corrections import correct_frame, flat_field_factors, mean_dark_grey, response_curve
from helicalib.flux.grid import board_grid
from helicalib.flux.measure import measure_flux
from helicalib.flux.synth import homography_uv_to_px, render_frame

FE_TRUE = 250.0          # W/m² per grey level: the beam peak reaches the compressed part of the response
DARK = 6.0               # linear grey
SHAPE = (512, 640)       # (H, W) px
K = np.array([[2600.0, 0, 320.0], [0, 2600.0, 256.0], [0, 0, 1]])
CAMERA_ENU = np.array([14.0, 75.0, 2.0])
TARGET = Target(id="T1", center_enu_m=(9.0, 8.0, 95.0), normal_enu=(0.0, 1.0, 0.0), size_m=(12.0, 12.0),
                marks={"vertices_m": [[-5.5, 5.5], [5.5, 5.5], [5.5, -5.5], [-5.5, -5.5]], "arm_m": 1.4,
                       "thickness_m": 0.35})
MARKS = {"vertices_m": TARGET.marks.vertices_m, "arm_m": TARGET.marks.arm_m, "thickness_m": TARGET.marks.thickness_m}

E0_WM2, SIGMA_M, C_UV = 40_000.0, 1.0, (0.5, -0.3)


def knee(x):
    """The camera's true response: linear up to 120, then compressing toward 255 (full well)."""
    x = np.asarray(x, dtype=float)
    return np.where(x <= 120.0, x, 120.0 + 135.0 * (1.0 - np.exp(-(x - 120.0) / 135.0)))


def beam(u, v):
    return E0_WM2 * np.exp(-((u - C_UV[0]) ** 2 + (v - C_UV[1]) ** 2) / (2 * SIGMA_M**2))


def gain_map(amplitude=0.04):
    """Pixel response: a ripple, a left-right slope and lens vignetting (-20 % in the corners)."""
    yy, xx = np.indices(SHAPE, dtype=float)
    r2 = ((xx - SHAPE[1] / 2) ** 2 + (yy - SHAPE[0] / 2) ** 2) / ((SHAPE[1] / 2) ** 2 + (SHAPE[0] / 2) ** 2)
    g = (1.0 + amplitude * np.sin(xx / 37.0) * np.cos(yy / 23.0) + amplitude / 2 * (xx / SHAPE[1] - 0.5)) * (1 - 0.2 * r2)
    return g / g.mean()


def roundtrip_png(tmp_path, name, img):
    path = tmp_path / name
    assert cv2.imwrite(str(path), img)
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint8 and back.shape == SHAPE
    return back


def scene(tmp_path, *, distortion=None, noise=0.8, gain_amp=0.04, flux=beam, ambient_after=40.0, k=K, look_at=None):
    """Render before/after frames plus the calibration frames; return everything measure_flux needs."""
    rng = np.random.default_rng(7)
    h = homography_uv_to_px(TARGET.center_enu_m, TARGET.frame_enu, CAMERA_ENU, k, look_at)
    gain = gain_map(gain_amp)
    common = dict(fe_wm2_per_grey=FE_TRUE, dark_grey=DARK, gain=gain, response=knee, noise_grey=noise,
                  marks=MARKS, camera_matrix=k, distortion=distortion, rng=rng)
    before = render_frame(SHAPE, h, TARGET.size_m, None, ambient_grey=40.0, **common)
    after = render_frame(SHAPE, h, TARGET.size_m, flux, ambient_grey=ambient_after, **common)
    before, after = roundtrip_png(tmp_path, "before.png", before), roundtrip_png(tmp_path, "after.png", after)
    # calibration measurements: capped lens, integrating sphere, response curve at 61 levels
    dark = np.clip(np.rint(knee(DARK + rng.normal(0, noise, SHAPE))), 0, 255).astype(np.uint8)
    sphere = np.mean([np.clip(np.rint(knee(DARK + 100.0 * gain + rng.normal(0, noise, SHAPE))), 0, 255)
                      for _ in range(8)], axis=0)  # 8 averaged frames, as one does with a sphere
    b = np.linspace(0.0, 300.0, 61)
    curve = response_curve(b, knee(b))
    dark_grey = mean_dark_grey(roundtrip_png(tmp_path, "dark.png", dark))
    flat = flat_field_factors(correct_frame(sphere, dark_grey=dark_grey, response=curve))
    h_px_to_uv = np.linalg.inv(h)
    return before, after, h_px_to_uv, dict(dark_grey=dark_grey, response=curve, flat_factors=flat)


def truth_on(grid):
    uu, vv = grid.mesh_m()
    return beam(uu, vv)


def errors(fm, truth):
    d = (fm.flux_wm2 - truth)[truth >= 0.05 * E0_WM2]  # the spot, where the corrections matter
    power_true = 2 * math.pi * SIGMA_M**2 * E0_WM2  # the whole beam lies > 5 sigma inside the board
    return {
        "rms_rel_peak": float(np.sqrt(np.nanmean(d**2)) / E0_WM2),
        "power_rel": fm.power_w / power_true - 1,
        "centre_m": math.hypot(fm.centre_uv_m[0] - C_UV[0], fm.centre_uv_m[1] - C_UV[1]),
    }


def test_all_corrections_recover_the_known_map(tmp_path):
    before, after, h, corr = scene(tmp_path)
    grid = board_grid(TARGET.size_m, 0.05)
    res = measure_flux(before, after, h, grid, FE_TRUE, **corr)
    e = errors(res.fluxmap, truth_on(grid))
    print(e)
    assert abs(e["power_rel"]) < 0.01
    assert e["rms_rel_peak"] < 0.02
    assert e["centre_m"] < 0.01
    assert abs(res.fluxmap.peak_wm2 / E0_WM2 - 1) < 0.03
    assert all(res.corrections[k]["applied"] for k in ("dark", "nonlinearity", "flat_field", "perspective"))
    assert not res.corrections["distortion"]["applied"]


@pytest.mark.parametrize("skip", ["response", "flat_factors"])
def test_leaving_a_correction_out_is_detectably_worse(tmp_path, skip):
    before, after, h, corr = scene(tmp_path)
    grid = board_grid(TARGET.size_m, 0.05)
    good = errors(measure_flux(before, after, h, grid, FE_TRUE, **corr).fluxmap, truth_on(grid))
    corr[skip] = None
    bad = errors(measure_flux(before, after, h, grid, FE_TRUE, **corr).fluxmap, truth_on(grid))
    print(skip, good, bad)
    assert bad["rms_rel_peak"] > 1.5 * good["rms_rel_peak"]


def test_lens_distortion_is_corrected(tmp_path):
    """A wide lens (f = 1200 px, k1 = -0.35) with the board off-centre, where distortion is strong."""
    dist = np.array([-0.35, 0.1, 0.0, 0.0, 0.0])
    wide = np.array([[1200.0, 0, 320.0], [0, 1200.0, 256.0], [0, 0, 1]])
    look_at = np.asarray(TARGET.center_enu_m) + np.array([-22.0, 0.0, -14.0])  # board toward the top right
    before, after, h, corr = scene(tmp_path, distortion=dist, k=wide, look_at=look_at)
    grid = board_grid(TARGET.size_m, 0.05)
    res = measure_flux(before, after, h, grid, FE_TRUE, camera_matrix=wide, distortion=dist, **corr)
    e = errors(res.fluxmap, truth_on(grid))
    assert res.corrections["distortion"]["applied"]
    assert abs(e["power_rel"]) < 0.01 and e["rms_rel_peak"] < 0.02 and e["centre_m"] < 0.01
    ignored = errors(measure_flux(before, after, h, grid, FE_TRUE, **corr).fluxmap, truth_on(grid))
    assert ignored["centre_m"] > 5 * e["centre_m"]


def test_non_lambertian_factor_divides_out(tmp_path):
    """A board that looks 8 % darker at the beam's incidence: the table restores the flux."""
    lb = 0.92
    before, after, h, corr = scene(tmp_path, flux=lambda u, v: lb * beam(u, v))
    grid = board_grid(TARGET.size_m, 0.05)
    table = (np.array([0.0, 20.0, 40.0]), np.array([1.0, 0.96, lb]))
    res = measure_flux(before, after, h, grid, FE_TRUE, incidence_deg=40.0, incidence_table=table, **corr)
    assert abs(errors(res.fluxmap, truth_on(grid))["power_rel"]) < 0.01
    assert res.corrections["non_lambertian"]["incidence_relative"] == pytest.approx(lb)
    with pytest.raises(Exception, match="incidence"):
        measure_flux(before, after, h, grid, FE_TRUE, incidence_table=table, **corr)
