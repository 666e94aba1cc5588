"""Theory of the trough overlay: B/E against the paper's own equations and direct 3-D reflection, eq. 11."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.errors import GeometryError
from helicalib.trough.camera import PinholeCamera
from helicalib.trough.config import Collector
from helicalib.trough.geometry import edge_x_extent_mm, tube_edges
from helicalib.trough.overlay import edges_in_image
from helicalib.trough.paper import boresight_distance_mm, boresight_gauge_width_mm, reflection_residual

F_MM, R_MM = 1710.0, 35.0  # the paper's unit
PAPER = dict(focal_length_mm=F_MM, aperture_mm=5774.0, length_mm=12000.0, tube_radius_mm=R_MM, rows=4, columns=7,
             row_edges_mm=[[1640, 2887], [50, 1612], [-1612, -50], [-2887, -1640]], column_gap_mm=20)


def _reflect_3d(camera_mm, point_mm, f, tilt_rad=0.0, pivot_yz=(0.0, 0.0)):
    """Independent 3-D reflection: numerical gradient of the (rotated) surface, vector law of reflection."""
    p = np.asarray(point_mm, float)
    c, s = np.cos(tilt_rad), np.sin(tilt_rad)
    rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # about +X
    piv = np.array([0.0, *pivot_yz])

    def surface(q):  # implicit surface of the rotated parabola: evaluate in the facet's own frame
        loc = rot.T @ (q - piv) + piv
        return loc[2] - loc[1] ** 2 / (4 * f)

    h = 1e-4
    grad = np.array([(surface(p + h * e) - surface(p - h * e)) / (2 * h) for e in np.eye(3)])
    n = grad / np.linalg.norm(grad)
    d = (p - camera_mm) / np.linalg.norm(p - camera_mm)
    return d - 2 * np.dot(d, n) * n


def _distance_to_focal_line(point_mm, direction):
    """Shortest distance between the 3-D line (point, direction) and the focal line (0, f) along X."""
    axis = np.array([1.0, 0.0, 0.0])
    cross = np.cross(direction, axis)
    return abs(np.dot(np.array([0.0, 0.0, F_MM]) - point_mm, cross)) / np.linalg.norm(cross)


@settings(max_examples=40, deadline=None)
@given(yp=st.floats(300, 2600), zp=st.floats(6000, 20000))
def test_edges_satisfy_the_papers_equations_1_to_10(yp, zp):
    e = tube_edges((yp, zp), F_MM, R_MM, [200.0], [2887.0])
    if not e.found[0] or e.lower_clipped[0] or e.upper_clipped[0]:
        return
    # B by eqs (1)-(8) and (3); E by eqs (9)-(10)
    assert abs(reflection_residual(e.lower_y_local_mm[0], (yp, zp), F_MM, R_MM, "B")) < 1e-9
    assert abs(reflection_residual(e.upper_y_local_mm[0], (yp, zp), F_MM, R_MM, "E")) < 1e-9
    # and not the other way round: the paper's two roots of (4) are distinct edges
    assert abs(reflection_residual(e.lower_y_local_mm[0], (yp, zp), F_MM, R_MM, "E")) > 1e-6


@settings(max_examples=40, deadline=None)
@given(xp=st.floats(-3000, 3000), yp=st.floats(-2600, 2600), zp=st.floats(6000, 15000),
       x=st.floats(-5000, 5000), tilt=st.floats(-8, 8))
def test_edges_graze_the_tube_in_3d(xp, yp, zp, x, tilt):
    """Any camera X and any point along the edge line: the 3-D reflected ray is tangent to the tube."""
    y0, y1 = (200.0, 2800.0) if yp > 0 else (-2800.0, -200.0)
    yc = 0.5 * (y0 + y1)
    pivot = (yc, yc * yc / (4 * F_MM))
    e = tube_edges((yp, zp), F_MM, R_MM, [y0], [y1], tilt_mrad=tilt, pivot_yz_mm=[pivot])
    if not e.found[0]:
        return
    for yz, clipped in ((e.lower_yz_mm[0], e.lower_clipped[0]), (e.upper_yz_mm[0], e.upper_clipped[0])):
        if clipped:
            continue
        q = np.array([x, *yz])
        out = _reflect_3d(np.array([xp, yp, zp]), q, F_MM, tilt * 1e-3, pivot)
        assert _distance_to_focal_line(q, out) == pytest.approx(R_MM, abs=1e-4)


def test_edge_extent_ends_where_the_ray_meets_the_tube_end():
    cam = np.array([1500.0, 831.0, 10000.0])
    e = tube_edges(cam[1:], F_MM, R_MM, [50.0], [1612.0])
    x_lo, x_hi = edge_x_extent_mm(cam[0], e.lower_ratio, -6000.0, 6000.0, [-1e9], [1e9])
    for x_end, tube_end in ((x_lo[0], -6000.0), (x_hi[0], 6000.0)):
        q = np.array([x_end, *e.lower_yz_mm[0]])
        out = _reflect_3d(cam, q, F_MM)
        # follow the ray to its closest approach to the focal line (in YZ) and read X there
        t = np.dot(np.array([0.0, F_MM]) - q[1:], out[1:]) / np.dot(out[1:], out[1:])
        assert q[0] + t * out[0] == pytest.approx(tube_end, abs=1e-6)


def test_paper_unit_figure_6_geometry():
    """Ren et al. fig. 6(a): undeformed, the tube is one straight band across the facets of the row the camera faces."""
    col = Collector(**PAPER)
    lay = col.facets()
    cam = PinholeCamera(np.array([0.0, 831.0, 10000.0]), 8.0 / 4.4e-3, (799.5, 599.5), (1600, 1200))
    ov = edges_in_image(col, lay, cam)
    # only the inner upper row (R2) — the row the 831 mm camera is centred on — shows the tube
    assert set(lay.row[ov.visible]) == {2}
    # the same B and E in every facet of the row: a straight horizontal band continuous across facets
    vis = np.flatnonzero(ov.visible)
    for seg in (ov.lower_uv_px, ov.upper_uv_px):
        v = seg[vis, :, 1]
        assert np.ptp(v) < 1e-6
    # at least the four facets the paper checked lie within the 1/1.8" + 8 mm field of view
    assert len(vis) >= 4
    # B below E in the photo, both strictly inside the facet strip
    assert np.all(ov.lower_uv_px[vis, 0, 1] > ov.upper_uv_px[vis, 0, 1])
    assert np.all(ov.lower_uv_px[vis, 0, 1] < ov.strip_bottom_uv_px[vis, 0, 1])
    assert np.all(ov.upper_uv_px[vis, 0, 1] > ov.strip_top_uv_px[vis, 0, 1])
    # the outer-row camera (2263 mm) sees the tube in R1 only; the cameras below mirror the ones above
    for y_cam, row in ((2263.0, 1), (-831.0, 3), (-2263.0, 4)):
        cam_k = PinholeCamera(np.array([0.0, y_cam, 10000.0]), 8.0 / 4.4e-3, (799.5, 599.5), (1600, 1200))
        ov_k = edges_in_image(col, lay, cam_k)
        assert set(lay.row[ov_k.visible]) == {row}
    low = edges_in_image(col, lay, PinholeCamera(np.array([0.0, -831.0, 10000.0]), 1818.0, (799.5, 599.5), (1600, 1200)))
    i_up, i_dn = lay.ids.index("R2C4"), lay.ids.index("R3C4")
    assert low.upper_yz_mm[i_dn, 0] == pytest.approx(-ov.lower_yz_mm[i_up, 0], abs=1e-9)


def test_tilt_moves_both_edges_the_same_way():
    e = tube_edges((831.0, 10000.0), F_MM, R_MM, [50.0] * 3, [1612.0] * 3, tilt_mrad=[-1.0, 0.0, 1.0])
    assert np.all(np.diff(e.lower_y_local_mm) > 5.0) and np.all(np.diff(e.upper_y_local_mm) > 5.0)


def test_no_tube_in_a_strip_the_camera_does_not_face():
    e = tube_edges((831.0, 10000.0), F_MM, R_MM, [-2887.0, 1640.0], [-1640.0, 2887.0])
    assert not e.found.any() and np.isnan(e.lower_y_local_mm).all()


@pytest.mark.parametrize("distance_mm, gauge_z_mm", [(10000.0, 0.0), (6000.0, 0.0), (10000.0, 40.0)])
def test_boresight_gauge_three_points_in_a_line(distance_mm, gauge_z_mm):
    d = boresight_gauge_width_mm(distance_mm, F_MM, R_MM, gauge_z_mm)
    # independent: the line from P_c through the boundary H = (d/2, gauge_z) is tangent to the tube
    p, hpt, c = np.array([0.0, distance_mm]), np.array([d / 2, gauge_z_mm]), np.array([0.0, F_MM])
    u = (hpt - p) / np.linalg.norm(hpt - p)
    assert abs(u[0] * (c - p)[1] - u[1] * (c - p)[0]) == pytest.approx(R_MM, rel=1e-12)
    assert boresight_distance_mm(d, F_MM, R_MM, gauge_z_mm) == pytest.approx(distance_mm, rel=1e-12)


def test_boresight_paper_stand_off_and_limits():
    # the paper's 10 m stand-off: eq. (11) with |P_c A| = sqrt(|CP_c|^2 - r^2) — d/2 = r (f + CP)/sqrt(CP^2 - r^2)
    cp = 10000.0 - F_MM
    assert boresight_gauge_width_mm(10000.0, F_MM, R_MM) == pytest.approx(2 * R_MM * (F_MM + cp) / np.sqrt(cp**2 - R_MM**2))
    with pytest.raises(GeometryError):
        boresight_distance_mm(2 * R_MM, F_MM, R_MM)
    with pytest.raises(GeometryError):
        boresight_gauge_width_mm(F_MM + 10.0, F_MM, R_MM)


@settings(max_examples=30, deadline=None)
@given(rx=st.floats(-3, 3), ry=st.floats(-3, 3), rz=st.floats(-3, 3),
       x=st.floats(-3000, 3000), y=st.floats(-2500, 2500), z=st.floats(0, 1500))
def test_camera_projection_and_rays_round_trip(rx, ry, rz, x, y, z):
    cam = PinholeCamera(np.array([100.0, 831.0, 10000.0]), 1818.0, (799.5, 599.5), (1600, 1200), (rx, ry, rz))
    q = np.array([x, y, z])
    uv, depth = cam.project(q)
    assert depth > 0
    ray = cam.rays(uv[0], uv[1])
    assert np.allclose(cam.position_mm + ray * np.linalg.norm(q - cam.position_mm), q, atol=1e-6)


def test_camera_nominal_attitude():
    cam = PinholeCamera(np.array([0.0, 831.0, 10000.0]), 1000.0, (320.0, 240.0), (640, 480))
    uv, _ = cam.project(np.array([[1000.0, 831.0, 0.0], [0.0, 1831.0, 0.0]]))
    assert uv[0] == pytest.approx([420.0, 240.0])  # +X to the right
    assert uv[1] == pytest.approx([320.0, 140.0])  # +Y up
