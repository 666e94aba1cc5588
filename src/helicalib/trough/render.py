"""Ray-traced synthetic photos of a trough collector with known facet tilts.

Independent of :mod:`helicalib.trough.geometry`: every sub-pixel sample's camera ray is followed
in 3-D — blocked by the tube, or intersected with its (tilted) facet, reflected, and tested against
the finite tube cylinder. Used by the tests and the ``helicalib trough render`` command so users
can try the overlay without a collector.

Grey levels: the tube (seen directly or in a facet) is dark, the sky reflected by a facet bright,
and gaps, frame and surroundings a middle grey. Each pixel is the mean of ``supersample**2``
samples (box filter), so edges fall between grey levels with sub-pixel precision.
"""

from __future__ import annotations

import numpy as np

from helicalib.trough.camera import PinholeCamera

TUBE_GREY = 25.0
SKY_GREY = 215.0
BACKGROUND_GREY = 110.0


def _parabola_hit(origin, direction, f):
    """Smallest positive ``t`` with ``origin + t direction`` on ``z = y^2/(4f)`` (NaN if none), shape (...)."""
    oy, oz = origin[..., 1], origin[..., 2]
    dy, dz = direction[..., 1], direction[..., 2]
    a = dy * dy / (4.0 * f)
    b = 2.0 * oy * dy / (4.0 * f) - dz
    c = oy * oy / (4.0 * f) - oz
    disc = b * b - 4.0 * a * c
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    small = np.abs(a) < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        q = -0.5 * (b + np.copysign(sq, b))  # stable roots q/a and c/q
        t1 = np.where(small, -c / b, q / a)
        t2 = np.where(small, np.nan, c / q)
    t1 = np.where(t1 > 1e-6, t1, np.inf)
    t2 = np.where(t2 > 1e-6, t2, np.inf)
    t = np.fmin(t1, t2)
    return np.where(np.isfinite(t), t, np.nan)


def _tube_hit(origin, direction, f, r, x_min, x_max):
    """Whether rays meet the tube cylinder (axis (y, z) = (0, f), ends x_min..x_max) ahead, shape (...)."""
    py, pz = origin[..., 1], origin[..., 2] - f
    dy, dz = direction[..., 1], direction[..., 2]
    a = dy * dy + dz * dz
    b = 2.0 * (py * dy + pz * dz)
    c = py * py + pz * pz - r * r
    disc = b * b - 4.0 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-b - np.sqrt(disc)) / (2.0 * a)
    x = origin[..., 0] + t * direction[..., 0]
    with np.errstate(invalid="ignore"):
        return (disc > 0) & (t > 1e-6) & (x >= x_min) & (x <= x_max)


def _rotate_x(vec, angle_rad):
    """Rotate (..., 3) vectors about +X by per-ray angles (...) [rad]."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.stack([vec[..., 0], c * vec[..., 1] - s * vec[..., 2], s * vec[..., 1] + c * vec[..., 2]], axis=-1)


def trace(camera: PinholeCamera, u_px, v_px, focal_length_mm: float, tube_radius_mm: float,
          tube_x_range_mm: tuple[float, float], facet_y_mm, facet_x_mm, tilt_mrad) -> np.ndarray:
    """Grey level seen along the rays through image positions.

    Parameters
    ----------
    camera : PinholeCamera
    u_px, v_px : ndarray, shape (...)
        Image positions [px].
    focal_length_mm, tube_radius_mm : float
        ``f`` and ``r`` [mm].
    tube_x_range_mm : (float, float)
        Tube ends along X [mm].
    facet_y_mm : ndarray, shape (R, 2)
        Row bounds ``[y_min, y_max]`` in facet coordinates [mm].
    facet_x_mm : ndarray, shape (C, 2)
        Column bounds ``[x_min, x_max]`` [mm].
    tilt_mrad : ndarray, shape (R, C)
        Facet tilts about +X through each facet's strip centre on the parabola [mrad].

    Returns
    -------
    ndarray, shape (...)
        Grey levels (0–255 scale).
    """
    f, r = float(focal_length_mm), float(tube_radius_mm)
    rows_y = np.asarray(facet_y_mm, dtype=float)
    cols_x = np.asarray(facet_x_mm, dtype=float)
    tilt = np.asarray(tilt_mrad, dtype=float) * 1e-3
    d = camera.rays(u_px, v_px)
    p = np.broadcast_to(np.asarray(camera.position_mm, dtype=float), d.shape)
    out = np.full(d.shape[:-1], BACKGROUND_GREY)

    # which facet: from the nominal surface (tilts are small); refined on the tilted facet below
    t0 = _parabola_hit(p, d, f)
    h0 = p + t0[..., None] * d
    row = np.full(out.shape, -1)
    col = np.full(out.shape, -1)
    for i, (lo, hi) in enumerate(rows_y):
        row[(h0[..., 1] >= lo) & (h0[..., 1] <= hi)] = i
    for j, (lo, hi) in enumerate(cols_x):
        col[(h0[..., 0] >= lo) & (h0[..., 0] <= hi)] = j
    on = (row >= 0) & (col >= 0) & np.isfinite(t0)
    if np.any(on):
        ri, ci = row[on], col[on]
        ang = tilt[ri, ci]
        yc = rows_y[ri].mean(axis=1)
        pivot = np.stack([np.zeros_like(yc), yc, yc * yc / (4.0 * f)], axis=-1)
        o_loc = _rotate_x(p[on] - pivot, -ang) + pivot
        d_loc = _rotate_x(d[on], -ang)
        t = _parabola_hit(o_loc, d_loc, f)
        h = o_loc + t[..., None] * d_loc
        inside = (np.isfinite(t) & (h[:, 1] >= rows_y[ri, 0]) & (h[:, 1] <= rows_y[ri, 1])
                  & (h[:, 0] >= cols_x[ci, 0]) & (h[:, 0] <= cols_x[ci, 1]))
        n = np.stack([np.zeros_like(t), -h[:, 1] / (2.0 * f), np.ones_like(t)], axis=-1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        refl = d_loc - 2.0 * np.sum(d_loc * n, axis=-1, keepdims=True) * n
        h_glob = _rotate_x(h - pivot, ang) + pivot
        r_glob = _rotate_x(refl, ang)
        hits_tube = _tube_hit(h_glob, r_glob, f, r, *tube_x_range_mm)
        shade = np.where(inside, np.where(hits_tube, TUBE_GREY, SKY_GREY), BACKGROUND_GREY)
        out[on] = shade
    direct = _tube_hit(p, d, f, r, *tube_x_range_mm)
    # the tube stands in front of the mirror (z = f > every mirror point of the module)
    out[direct] = TUBE_GREY
    return out


def render(camera: PinholeCamera, focal_length_mm: float, tube_radius_mm: float, tube_x_range_mm,
           facet_y_mm, facet_x_mm, tilt_mrad, supersample: int | tuple[int, int] = 4, rows_px: tuple[int, int] | None = None,
           noise_grey: float = 0.0, seed: int = 0, chunk_rows: int = 64) -> np.ndarray:
    """Render the camera's photo of the collector (8-bit grey).

    Parameters
    ----------
    camera : PinholeCamera
    focal_length_mm, tube_radius_mm, tube_x_range_mm, facet_y_mm, facet_x_mm, tilt_mrad
        As in :func:`trace`.
    supersample : int or (int, int)
        Samples per pixel along each image axis, or ``(along u, along v)`` (box filter).
    rows_px : (int, int), optional
        Render only image rows ``[first, last)``; other rows are background grey.
    noise_grey : float
        Standard deviation of added Gaussian noise [grey levels].
    seed : int
        Noise seed.
    chunk_rows : int
        Rows traced at once (memory bound).

    Returns
    -------
    ndarray of uint8, shape (height, width)
    """
    w, h = camera.image_size_px
    first, last = rows_px if rows_px is not None else (0, h)
    img = np.full((h, w), BACKGROUND_GREY)
    su, sv = (supersample, supersample) if np.isscalar(supersample) else supersample
    su, sv = int(su), int(sv)
    off_u = (np.arange(su) + 0.5) / su - 0.5
    off_v = (np.arange(sv) + 0.5) / sv - 0.5
    us = (np.arange(w)[:, None] + off_u[None, :]).ravel()
    for start in range(first, last, chunk_rows):
        stop = min(start + chunk_rows, last)
        vs = (np.arange(start, stop)[:, None] + off_v[None, :]).ravel()
        vv, uu = np.meshgrid(vs, us, indexing="ij")
        grey = trace(camera, uu, vv, focal_length_mm, tube_radius_mm, tube_x_range_mm, facet_y_mm, facet_x_mm, tilt_mrad)
        img[start:stop] = grey.reshape(stop - start, sv, w, su).mean(axis=(1, 3))
    if noise_grey > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise_grey, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def render_collector(collector, camera: PinholeCamera, tilt_mrad_by_facet: dict[str, float] | None = None,
                     **options) -> np.ndarray:
    """Render a :class:`~helicalib.trough.config.Collector` with tilts given per facet id (e.g. ``{"R2C3": 1.5}``).

    ``options`` go to :func:`render` (``supersample``, ``rows_px``, ``noise_grey``, ``seed``).
    Unknown facet ids raise ``KeyError`` naming them.
    """
    layout = collector.facets()
    tilt = np.zeros((collector.rows, collector.columns))
    for fid, value in (tilt_mrad_by_facet or {}).items():
        if fid not in layout.ids:
            raise KeyError(f"unknown facet '{fid}' (R1C1 … R{collector.rows}C{collector.columns})")
        i = layout.ids.index(fid)
        tilt[layout.row[i] - 1, layout.column[i] - 1] = float(value)
    cols = np.stack([layout.x_min_mm[: collector.columns], layout.x_max_mm[: collector.columns]], axis=1)
    return render(camera, collector.focal_length_mm, collector.tube_radius_mm, collector.tube_x_range_mm,
                  collector.row_bounds_mm(), cols, tilt, **options)
