"""Geodesy for imported plant data: WGS84 → plant ENU, Gauss-Krüger offsets → plant ENU.

Exact formulas, no linearisation (pyproj is not a dependency):

* geodetic (lat, lon, h) → ECEF on an ellipsoid: ``N = a / sqrt(1 - e² sin² φ)``,
  ``X = (N + h) cos φ cos λ``, ``Y = (N + h) cos φ sin λ``, ``Z = (N (1 - e²) + h) sin φ``;
* ECEF → local ENU at a reference point: the rotation with rows
  ``e = (-sin λ0, cos λ0, 0)``, ``n = (-sin φ0 cos λ0, -sin φ0 sin λ0, cos φ0)``,
  ``u = (cos φ0 cos λ0, cos φ0 sin λ0, sin φ0)`` applied to ``X - X0``;
* Gauss-Krüger (DHDN, 3° zone 2, Bessel 1841, central meridian 6° E, false easting 2 500 000 m,
  scale 1) → geodetic: the inverse transverse-Mercator series (Snyder 1987, eqs. 8-18 … 8-25).
  Plant-relative ENU of two GK points is then taken on the Bessel ellipsoid: the datum shift to
  WGS84 is common to both points and changes a 100 m baseline by well under a millimetre.
"""

from __future__ import annotations

import math

import numpy as np

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
BESSEL_A = 6377397.155
BESSEL_F = 1.0 / 299.1528128

# PAINT's Gauss-Krüger base of the Jülich field (paint.util.paint_mappings GK_RIGHT_BASE / GK_HEIGHT_BASE)
JUELICH_GK_RIGHT_BASE_M = 2527317.095
JUELICH_GK_HEIGHT_BASE_M = 5642086.619


def geodetic_to_ecef(lat_deg, lon_deg, h_m, a: float = WGS84_A, f: float = WGS84_F) -> np.ndarray:
    """Geodetic coordinates (degrees, metres) → Earth-centred Earth-fixed XYZ (..., 3) [m]."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    h = np.asarray(h_m, dtype=float)
    e2 = f * (2.0 - f)
    n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    x = (n + h) * np.cos(lat) * np.cos(lon)
    y = (n + h) * np.cos(lat) * np.sin(lon)
    z = (n * (1.0 - e2) + h) * np.sin(lat)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_enu_matrix(lat0_deg: float, lon0_deg: float) -> np.ndarray:
    """Rows e, n, u of the local frame at (lat0, lon0), expressed in ECEF, shape (3, 3)."""
    p, l = math.radians(lat0_deg), math.radians(lon0_deg)
    return np.array(
        [
            [-math.sin(l), math.cos(l), 0.0],
            [-math.sin(p) * math.cos(l), -math.sin(p) * math.sin(l), math.cos(p)],
            [math.cos(p) * math.cos(l), math.cos(p) * math.sin(l), math.sin(p)],
        ]
    )


def geodetic_to_enu(points_llh, reference_llh, a: float = WGS84_A, f: float = WGS84_F) -> np.ndarray:
    """Points [lat°, lon°, h m] (..., 3) → ENU metres (..., 3) about ``reference_llh`` (same ellipsoid)."""
    pts = np.asarray(points_llh, dtype=float)
    ref = np.asarray(reference_llh, dtype=float)
    xyz = geodetic_to_ecef(pts[..., 0], pts[..., 1], pts[..., 2], a, f)
    xyz0 = geodetic_to_ecef(ref[0], ref[1], ref[2], a, f)
    return (xyz - xyz0) @ ecef_to_enu_matrix(ref[0], ref[1]).T


def wgs84_to_enu(points_llh, reference_llh) -> np.ndarray:
    """WGS84 [lat°, lon°, alt m] (..., 3) → plant ENU metres (..., 3) about ``reference_llh``."""
    return geodetic_to_enu(points_llh, reference_llh, WGS84_A, WGS84_F)


def gauss_krueger_to_geodetic(right_m: float, height_m: float, zone: int | None = None) -> tuple[float, float]:
    """Gauss-Krüger (DHDN / Bessel, 3° zones) Rechtswert, Hochwert → (lat°, lon°) on Bessel 1841.

    The zone is the leading digit of the Rechtswert unless given (zone 2: central meridian 6° E).
    """
    if zone is None:
        zone = int(right_m // 1_000_000)
    lon0 = math.radians(3.0 * zone)
    x = right_m - (zone * 1_000_000 + 500_000.0)
    y = height_m
    a, f = BESSEL_A, BESSEL_F
    e2 = f * (2.0 - f)
    ep2 = e2 / (1.0 - e2)
    k0 = 1.0
    m = y / k0
    mu = m / (a * (1.0 - e2 / 4.0 - 3.0 * e2**2 / 64.0 - 5.0 * e2**3 / 256.0))
    e1 = (1.0 - math.sqrt(1.0 - e2)) / (1.0 + math.sqrt(1.0 - e2))
    phi1 = (
        mu
        + (3.0 * e1 / 2.0 - 27.0 * e1**3 / 32.0) * math.sin(2 * mu)
        + (21.0 * e1**2 / 16.0 - 55.0 * e1**4 / 32.0) * math.sin(4 * mu)
        + (151.0 * e1**3 / 96.0) * math.sin(6 * mu)
        + (1097.0 * e1**4 / 512.0) * math.sin(8 * mu)
    )
    c1 = ep2 * math.cos(phi1) ** 2
    t1 = math.tan(phi1) ** 2
    n1 = a / math.sqrt(1.0 - e2 * math.sin(phi1) ** 2)
    r1 = a * (1.0 - e2) / (1.0 - e2 * math.sin(phi1) ** 2) ** 1.5
    d = x / (n1 * k0)
    lat = phi1 - (n1 * math.tan(phi1) / r1) * (
        d**2 / 2.0
        - (5.0 + 3.0 * t1 + 10.0 * c1 - 4.0 * c1**2 - 9.0 * ep2) * d**4 / 24.0
        + (61.0 + 90.0 * t1 + 298.0 * c1 + 45.0 * t1**2 - 252.0 * ep2 - 3.0 * c1**2) * d**6 / 720.0
    )
    lon = lon0 + (
        d
        - (1.0 + 2.0 * t1 + c1) * d**3 / 6.0
        + (5.0 - 2.0 * c1 + 28.0 * t1 - 3.0 * c1**2 + 8.0 * ep2 + 24.0 * t1**2) * d**5 / 120.0
    ) / math.cos(phi1)
    return math.degrees(lat), math.degrees(lon)


def gauss_krueger_offset_to_enu(
    east_offset_m: float,
    north_offset_m: float,
    altitude_m: float,
    reference_altitude_m: float,
    right_base_m: float = JUELICH_GK_RIGHT_BASE_M,
    height_base_m: float = JUELICH_GK_HEIGHT_BASE_M,
) -> np.ndarray:
    """A point given as Gauss-Krüger offsets from a GK base (HeliOS ``x``, ``y``, ``z``) → plant ENU [m].

    The plant origin is the GK base itself at ``reference_altitude_m`` (as PAINT defines the Jülich
    plant origin). GK grid north differs from true north by the meridian convergence (≈ 0.30° at
    Jülich), which is why a HeliOS offset (-57.2, 25.0) lands at ENU (-57.07, 25.30).
    """
    lat0, lon0 = gauss_krueger_to_geodetic(right_base_m, height_base_m)
    lat, lon = gauss_krueger_to_geodetic(right_base_m + east_offset_m, height_base_m + north_offset_m)
    return geodetic_to_enu([lat, lon, altitude_m], [lat0, lon0, reference_altitude_m], BESSEL_A, BESSEL_F)
