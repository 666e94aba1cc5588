"""The paper's own equations (Ren et al. 2014): the B/E chain (1)–(10) and the boresight gauge (11).

:func:`reflection_residual` evaluates the paper's chain literally for a trial height ``y_b > 0``:
(1) the point on the parabola, (2) the normal's crossing ``G`` of the Z axis, (4) the tangent
from B to the tube through its crossing ``M`` of the axis (the root of the quadratic is chosen by
the figure: ``M`` below the focus for B, above it for E), (5)–(8) or (9)–(10) the tangent point
``A``, and (3) the law of reflection as equal angles ``PBG`` and ``ABG``. It is zero at the paper's
B (or E). Two misprints of the published text are corrected and documented in ``docs/trough.md``:
in (3) ``BG = (-y_b, z_g - z_b)`` so the ``y`` products carry a minus sign, and in (11) the
square root is ``sqrt(|CP_c|**2 - r**2)``.

:func:`boresight_distance_mm` solves (11): the distance ``OP_c`` of the centre camera for which the
lines from its principal point through the gauge's colour boundaries (half-width ``d/2``) graze
the tube. The paper's approximation ``|P_c M| ≈ |OP_c|`` is exact when the gauge lies in the vertex
plane (``gauge_z_mm = 0``); another gauge height can be given.
"""

from __future__ import annotations

import numpy as np

from helicalib.errors import GeometryError


def reflection_residual(y_b_mm, camera_yz_mm, focal_length_mm: float, tube_radius_mm: float, edge: str = "B"):
    """Residual of the paper's eq. (3) for trial reflection heights, through eqs (1)–(10).

    Parameters
    ----------
    y_b_mm : array_like, shape (...)
        Trial heights ``y_b > r`` [mm] (the paper's derivation is for the upper half).
    camera_yz_mm : array_like, shape (2,)
        Principal point ``P = (y_p, z_p)`` [mm].
    focal_length_mm, tube_radius_mm : float
        ``f`` and ``r`` [mm].
    edge : {"B", "E"}
        Lower edge (tangent point ``A`` by eqs 7–8) or upper edge (eqs 9–10).

    Returns
    -------
    ndarray, shape (...)
        ``cos∠PBG - cos∠ABG`` [-]; zero where the reflected ray of ``PB`` grazes the tube.
    """
    f, r = float(focal_length_mm), float(tube_radius_mm)
    yb = np.asarray(y_b_mm, dtype=float)
    yp, zp = (float(v) for v in camera_yz_mm)
    zb = yb**2 / (4.0 * f)  # (1)
    zg = np.sqrt(yb**2 + (zb - f) ** 2) + f  # (2)
    # (4): sqrt(yb^2 + m^2) / yb = ±(k - m) / r with k = f - zb, squared: a m^2 + b m + c = 0
    k = f - zb
    root = yb * r * np.sqrt(k**2 + yb**2 - r**2)
    denom = yb**2 - r**2
    m_minus, m_plus = (yb**2 * k - root) / denom, (yb**2 * k + root) / denom
    if edge == "B":  # M between D and F: k - m > 0
        m = np.where(k - m_minus > 0, m_minus, m_plus)
    elif edge == "E":  # M beyond F: m - k > 0
        m = np.where(m_plus - k > 0, m_plus, m_minus)
    else:
        raise ValueError("edge must be 'B' or 'E'")
    bm = np.sqrt(m**2 + yb**2)
    sin_a, cos_a = m / bm, yb / bm  # (5), (6)
    if edge == "B":
        ya, za = -r * sin_a, f - r * cos_a  # (7), (8)
    else:
        ya, za = r * sin_a, f + r * cos_a  # (9), (10)
    bg_y, bg_z = -yb, zg - zb
    bp_y, bp_z = yp - yb, zp - zb
    ba_y, ba_z = ya - yb, za - zb
    bg = np.hypot(bg_y, bg_z)
    lhs = (bp_y * bg_y + bp_z * bg_z) / (np.hypot(bp_y, bp_z) * bg)  # (3), left
    rhs = (ba_y * bg_y + ba_z * bg_z) / (np.hypot(ba_y, ba_z) * bg)  # (3), right
    return lhs - rhs


def boresight_distance_mm(gauge_width_mm: float, focal_length_mm: float, tube_radius_mm: float,
                          gauge_z_mm: float = 0.0) -> float:
    """Distance ``OP_c`` of the centre camera from the vertex by the "three points in a line" rule (11).

    Parameters
    ----------
    gauge_width_mm : float
        ``d``: distance between the gauge's two colour boundaries ``H`` and ``L`` [mm].
    focal_length_mm, tube_radius_mm : float
        ``f`` and ``r`` [mm].
    gauge_z_mm : float
        Height of the gauge's boundary points on the Z axis [mm]; 0 in the paper (vertex plane).

    Returns
    -------
    float
        ``z`` of the centre camera's principal point on the optical axis [mm].

    Raises
    ------
    GeometryError
        If ``d <= 2 r`` (no camera position can see both boundaries grazing the tube).
    """
    f, r, d = float(focal_length_mm), float(tube_radius_mm), float(gauge_width_mm)
    k = d / (2.0 * r)
    if k <= 1.0:
        raise GeometryError(f"gauge width {d:g} mm must exceed the tube diameter {2 * r:g} mm")
    h = f - float(gauge_z_mm)
    # (d/2r)^2 (c^2 - r^2) = (c + h)^2 with c = |CP_c|  ->  (k^2-1) c^2 - 2 h c - (k^2 r^2 + h^2) = 0
    a, b, c0 = k * k - 1.0, -2.0 * h, -(k * k * r * r + h * h)
    cp = (-b + np.sqrt(b * b - 4.0 * a * c0)) / (2.0 * a)
    return float(f + cp)


def boresight_gauge_width_mm(camera_distance_mm: float, focal_length_mm: float, tube_radius_mm: float,
                             gauge_z_mm: float = 0.0) -> float:
    """The gauge width ``d`` that puts the centre camera at ``camera_distance_mm`` (inverse of (11)).

    Parameters
    ----------
    camera_distance_mm : float
        ``OP_c`` [mm]; must exceed ``f + r``.
    focal_length_mm, tube_radius_mm, gauge_z_mm : float
        As in :func:`boresight_distance_mm` [mm].

    Returns
    -------
    float
        ``d`` [mm].
    """
    f, r = float(focal_length_mm), float(tube_radius_mm)
    cp = float(camera_distance_mm) - f
    if cp <= r:
        raise GeometryError(f"camera distance {camera_distance_mm:g} mm must exceed f + r = {f + r:g} mm")
    return float(2.0 * r * (camera_distance_mm - gauge_z_mm) / np.sqrt(cp * cp - r * r))
