"""``sim-field``: generate a field config (radial-staggered layout) whose strokes are feasible all year.

Heliostats stand in staggered rings on the pole side of the tower (north for a northern site,
south for a southern one) within ±75° of it. Ring spacing and in-ring spacing follow the mirror
diagonal; a new zone with a denser ring starts each time the in-ring gap doubles. Every candidate
is checked for the receiver and for its calibration board over a year of sun positions ≥ 5°
(:func:`feasible_all_year`, all candidates × all sun positions as arrays); candidates whose strokes
leave the range, or whose board would see them more than :data:`MAX_BOARD_INCIDENCE_DEG` off its
normal, are dropped and more rings are laid until ``n`` heliostats remain.

Boards are shared out evenly (:func:`assign_boards`): the heliostats, sorted by their angle from the
pole direction (west to east on the pole side), are cut into ``targets`` runs whose sizes differ by
at most one; run ``k`` uses board ``k`` (the boards stand west to east in the same order).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from helicalib.config import write_field_config
from helicalib.devices.regcheck import check_count
from helicalib.devices.regmap import default_register_map
from helicalib.geometry.drives import DriveArrays, angle_interval_rad, strokes_to_angles
from helicalib.geometry.optics import AIM_ITERATIONS
from helicalib.geometry.sun import year_sun_times

DRIVE_NAME = "tr20"
MIRROR_M = (4.5, 4.5)
BOARD_M = 12.0
"""The boards' side [m] for fields up to about 1500 heliostats; a field whose far heliostats' spots
need more gets larger boards (:func:`board_size_m`)."""
SUN_DISC_RAD = 9.3e-3
"""The sun's angular diameter [rad]: a flat mirror's spot is about ``distance · SUN_DISC_RAD`` plus the mirror."""
BOARD_OVER_SPOT = 1.6
"""Board side over the spot at the field's 90th-percentile distance to its board. On 12 m boards a
simulated 10⁴-heliostat campaign's first visits failed (the spot reaching the rim) for 0.5 % of the
heliostats whose board was over 1.65 spots wide, 6 % at 1.3–1.65, 18 % at 1.2–1.3 and 32–62 % under
1.2 (docs/benchmarks.md, "Scale")."""
PIVOT_HEIGHT_M = 4.3
STROKE_MARGIN_MM = 25.0
"""Room left at both ends of each stroke range for corrections and between the sampled sun positions."""
MAX_BOARD_INCIDENCE_DEG = 70.0
"""Largest angle between a board's normal and the direction to a heliostat it serves (the planner's
``campaign.choice.MAX_SHARE_INCIDENCE_DEG`` for a board it lends)."""
CHUNK_PAIRS = 1 << 16
"""Heliostat × sun-position pairs per block of :func:`feasible_all_year` (0.5 MB per array)."""
FIRST_PASS_EVERY = 8
""":func:`feasible_all_year` checks every 8th sun position first and the rest only where that passed."""
MAX_CANDIDATES_PER_HELIOSTAT = 50


def _drive(south_field: bool) -> dict:
    """The demo's tilt-roll drive; a south field tilts the other way (actuator 1 sign −1)."""
    return {
        "kind": "tilt-roll", "mirror_offset_m": 0.25, "mirror_size_m": list(MIRROR_M),
        "actuators": [
            {"arm_fixed_m": 1.6, "arm_moving_m": 1.1, "gamma0_deg": 60, "sign": -1 if south_field else 1,
             "length_at_zero_stroke_m": 0.80, "stroke_range_mm": [0, 1850]},
            {"arm_fixed_m": 1.2, "arm_moving_m": 0.9, "gamma0_deg": 90, "sign": 1,
             "length_at_zero_stroke_m": 0.50, "stroke_range_mm": [0, 1590]},
        ],
    }


def radial_staggered(count: int, r0_m: float, spacing_m: float, half_width_deg: float = 75.0,
                     pole_azimuth_deg: float = 0.0) -> np.ndarray:
    """At least ``count`` positions (k, 2) east/north [m] in staggered rings from radius ``r0_m``.

    Ring by ring, so a larger ``count`` returns the same positions followed by more rings."""
    out: list[np.ndarray] = []
    r = r0_m
    dr = 0.866 * spacing_m
    zone_r = r0_m
    ring = 0
    total = 0
    while total < count:
        daz = spacing_m / zone_r                       # angular gap fixed within a zone
        if r * daz > 2.0 * spacing_m:                  # gap doubled: new, denser zone
            zone_r = r
            daz = spacing_m / zone_r
        half = math.radians(half_width_deg)
        k = int(half // daz)
        az = (np.arange(-k, k + 1) + (0.5 if ring % 2 else 0.0)) * daz
        az = az[np.abs(az) <= half] + math.radians(pole_azimuth_deg)
        pts = np.stack([r * np.sin(az), r * np.cos(az)], axis=1)
        out.append(pts)
        total += len(pts)
        r += dr
        ring += 1
    return np.concatenate(out)


# ---------------------------------------------------------------------------- feasibility
def _drive_frame(drive) -> tuple[np.ndarray, float]:
    """Rows (a1, a2, n0) of a drive whose axes are orthonormal with n0 = σ·(a1 × a2), and σ = ±1.

    For such a drive n = σ sin θ2 a1 + cos θ2 (cos θ1 n0 − σ sin θ1 a2), so θ2 = asin(σ n·a1) and
    θ1 = atan2(−σ n·a2, n·n0) (the closed form of ``drives.normal_to_angles`` for these axes)."""
    a1, a2, n0 = (np.asarray(v, dtype=float) / np.linalg.norm(v) for v in drive.axes)
    sigma = float(np.dot(n0, np.cross(a1, a2)))
    if abs(np.dot(a1, a2)) > 1e-12 or abs(abs(sigma) - 1.0) > 1e-12:
        raise ValueError("feasible_all_year: the drive's axes must be orthogonal and n0 = ±(axis1 × axis2)")
    return np.stack([a1, a2, n0]), math.copysign(1.0, sigma)


def axis_angle_limits(drive, margin_mm: float = STROKE_MARGIN_MM) -> tuple[np.ndarray, np.ndarray]:
    """Axis-angle window of strokes at least ``margin_mm`` inside their ranges: ``(low (2,), high (2,))`` [rad].

    The stroke of each actuator is a monotonic function of its axis angle inside the linkage range
    ((0, π) triangle angle), so "stroke in [min + margin, max − margin]" is "angle in [low, high]".
    """
    arr = DriveArrays.from_drives([drive])
    s = np.stack([arr.stroke_min_mm[0] + margin_mm, arr.stroke_max_mm[0] - margin_mm])    # (2 ends, 2 actuators)
    th = strokes_to_angles(arr, s)
    if not np.all(np.isfinite(th)) or np.any(s[0] > s[1]):
        raise ValueError("feasible_all_year: a stroke range (less the margin) leaves the linkage's triangle")
    lo_l, hi_l = angle_interval_rad(arr)
    # the other solution of normal → angles has θ2' = π − θ2: never in a linkage range inside [−π/2, π/2]
    if lo_l[0, 1] < -math.pi / 2 - 1e-12 or hi_l[0, 1] > math.pi / 2 + 1e-12:
        raise ValueError("feasible_all_year: axis 2's linkage range must lie within ±90°")
    return th.min(axis=0), th.max(axis=0)


def feasible_all_year(pivots_enu: np.ndarray, aim_enu: np.ndarray, sun_enu: np.ndarray, drive,
                      margin_mm: float = STROKE_MARGIN_MM, progress=None) -> np.ndarray:
    """(N,) bool: both strokes at least ``margin_mm`` inside their ranges at every sun position.

    The strokes are those of ``HeliostatModel.strokes_for_aim`` (error-free heliostats, the aim normal
    with the mirror offset by the same fixed point, the same branch of the drive's inverse), computed
    for heliostats × sun positions as arrays and compared as axis angles (:func:`axis_angle_limits`).
    Every :data:`FIRST_PASS_EVERY`-th sun position is checked first for all heliostats; one that
    fails there is out, so only the others are checked at the remaining positions.

    Parameters
    ----------
    pivots_enu : (N, 3) pivots [m, ENU]
    aim_enu : (3,) or (N, 3) aim points [m, ENU]
    sun_enu : (T, 3) unit sun vectors, ENU
    drive : ``config.Drive`` shared by all N heliostats; axes orthonormal (both presets are)
    progress : ``progress(done)`` as heliostats are settled, ``done`` of N so far
    """
    pivots = np.asarray(pivots_enu, dtype=float).reshape(-1, 3)
    n = len(pivots)
    frame, sigma = _drive_frame(drive)
    limits = axis_angle_limits(drive, margin_mm)
    # work in the drive frame (a1, a2, n0): the fixed point is rotation-equivariant
    d = (np.broadcast_to(np.asarray(aim_enu, dtype=float), (n, 3)) - pivots) @ frame.T     # (N, 3) pivot → aim
    s = np.asarray(sun_enu, dtype=float).reshape(-1, 3)
    s = (s / np.linalg.norm(s, axis=1, keepdims=True)) @ frame.T                           # (T, 3)
    first = np.zeros(len(s), dtype=bool)
    first[::FIRST_PASS_EVERY] = True
    ok = _within_limits(d, s[first], sigma, float(drive.mirror_offset_m), limits)
    out = int(n - ok.sum())
    if progress is not None and out:
        progress(out)
    keep = np.flatnonzero(ok)
    step = None if progress is None else (lambda k: progress(out + k))
    ok[keep] = _within_limits(d[keep], s[~first], sigma, float(drive.mirror_offset_m), limits, step)
    return ok


def _within_limits(d: np.ndarray, s: np.ndarray, sigma: float, offset_m: float, limits, step=None) -> np.ndarray:
    """(N,) bool: the aim normal's axis angles inside ``limits`` for every sun; ``d`` (N, 3) pivot → aim
    [m] and ``s`` (T, 3) unit sun vectors, both in the drive frame (a1, a2, n0)."""
    lo, hi = limits
    ok = np.ones(len(d), dtype=bool)
    if len(s) == 0:
        return ok
    sx, sy, sz = (s[None, :, k] for k in range(3))                                       # (1, T)
    # θ1 = atan2(w_s, w_c) with (w_c, w_s) = (n·n0, −σ n·a2) lies in [lo, hi] (less than π long) when
    # w turns counter-clockwise from the direction at lo and clockwise from the one at hi
    c_lo, s_lo, c_hi, s_hi = math.cos(lo[0]), math.sin(lo[0]), math.cos(hi[0]), math.sin(hi[0])
    sin2_lo, sin2_hi = math.sin(lo[1]), math.sin(hi[1])                                  # θ2 = asin(σ n·a1)
    if not hi[0] - lo[0] < math.pi or not -math.pi / 2 <= lo[1] <= hi[1] <= math.pi / 2:
        raise ValueError("feasible_all_year: an axis-angle window longer than the closed form allows")
    rows = max(1, CHUNK_PAIRS // len(s))
    for a in range(0, len(d), rows):
        dx, dy, dz = (d[a:a + rows, k, None] for k in range(3))                          # (rows, 1)
        inv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
        nx, ny, nz = sx + dx * inv, sy + dy * inv, sz + dz * inv                            # (rows, T)
        for _ in range(AIM_ITERATIONS):
            scale = offset_m / np.sqrt(nx * nx + ny * ny + nz * nz)
            vx, vy, vz = dx - nx * scale, dy - ny * scale, dz - nz * scale                  # aim − mirror centre
            inv = 1.0 / np.sqrt(vx * vx + vy * vy + vz * vz)
            nx, ny, nz = sx + vx * inv, sy + vy * inv, sz + vz * inv
        sin2 = sigma * nx / np.sqrt(nx * nx + ny * ny + nz * nz)
        wc, ws = nz, -sigma * ny
        ok[a:a + rows] = (np.all((c_lo * ws - s_lo * wc >= 0.0) & (wc * s_hi - ws * c_hi >= 0.0), axis=1)
                          & (sin2.min(axis=1) >= sin2_lo) & (sin2.max(axis=1) <= sin2_hi))
        if step is not None:
            step(min(a + rows, len(d)))
    return ok


# ---------------------------------------------------------------------------- boards
def assign_boards(positions_m: np.ndarray, boards: int, south_field: bool = False) -> np.ndarray:
    """Board index (N,) for heliostats at ``positions_m`` (N, 2+) east/north [m]: sorted by their angle
    from the pole direction toward the east (ties: nearer first), cut into ``boards`` consecutive runs
    whose sizes differ by at most one; run k gets board k (boards stand west to east)."""
    p = np.asarray(positions_m, dtype=float)
    angle = np.arctan2(p[:, 0], (-1.0 if south_field else 1.0) * p[:, 1])
    order = np.lexsort((np.hypot(p[:, 0], p[:, 1]), angle))
    out = np.empty(len(p), dtype=int)
    for k, run in enumerate(np.array_split(order, boards)):
        out[run] = k
    return out


def board_incidence_deg(positions_enu: np.ndarray, center_enu, normal_enu) -> np.ndarray:
    """Angle (N,) [deg] between a board's normal and the direction from its centre to each position
    (N, 3) [m, ENU]; above 90° the board faces away."""
    v = np.asarray(positions_enu, dtype=float) - np.asarray(center_enu, dtype=float)
    nrm = np.asarray(normal_enu, dtype=float)
    c = (v @ nrm) / (np.linalg.norm(v, axis=1) * np.linalg.norm(nrm))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


# ---------------------------------------------------------------------------- the field
def _field_data(n: int, latitude_deg: float, longitude_deg: float, altitude_m: float, targets: int,
                name: str | None, board_m: float = BOARD_M) -> dict:
    """The config mapping (without heliostats): site, tower, boards (``board_m`` square) side by side,
    cameras, drive, plant. The L marks keep the 12 m board's proportions."""
    south = latitude_deg < 0
    sgn = -1.0 if south else 1.0
    tower_h = float(np.clip(40.0 + 2.5 * math.sqrt(n), 60.0, 250.0))
    board_h = round(0.6 * tower_h, 1)
    r0 = _first_ring_m(tower_h)
    side = float(board_m)
    scale = side / BOARD_M
    c = round(side / 2 - 0.5, 2)  # the marks' outer corners 0.5 m inside the rim
    target_list = []
    for k in range(targets):
        x = (k - (targets - 1) / 2) * (side + 4.0)
        target_list.append({
            "id": f"T{k + 1}", "center_enu_m": [round(x, 2), sgn * 8.0, board_h], "normal_enu": [0.0, sgn, 0.0],
            "size_m": [side, side], "standby_offset_m": [0.0, side + 3.0],  # above the board: clear of its neighbours
            "marks": {"vertices_m": [[-c, c], [c, c], [c, -c], [-c, -c]], "arm_m": round(1.4 * scale, 2),
                      "thickness_m": round(0.35 * scale, 2)},
        })
    site = {"name": name or f"Simulated field ({n} heliostats)", "latitude_deg": latitude_deg,
            "longitude_deg": longitude_deg, "altitude_m": altitude_m}
    return {
        "site": site, "tower": {"receiver_aim_enu_m": [0.0, 0.0, round(tower_h, 1)]},
        "targets": target_list,
        "cameras": [{"id": f"C{k + 1}", "target": t["id"], "url": f"http://127.0.0.1:8081/{t['id']}.png",
                     "position_enu_m": [t["center_enu_m"][0], sgn * (r0 * 0.8), 2.0], "resolution_px": [1280, 1024]}
                    for k, t in enumerate(target_list)],
        "drives": {DRIVE_NAME: _drive(south)},
        "plant": _plant(n),
        "calibration": {"loop_threshold_mrad": 3.5, "max_iterations": 5},
        "gating": {"wind_max_ms": 10.0, "wind_preferred_ms": 5.0, "stow_wind_ms": 15.0, "dni_min_wm2": 300,
                   "dni_preferred_wm2": 800, "cleanliness_min": 0.55, "cleanliness_preferred": 0.7},
        "acceptance": {"low_band_deg": [5, 15], "high_elevation_deg": 15, "high_window_h": 2, "min_points": 5,
                       "max_rms_mrad": 1.2},
        "tracking_test": {"threshold_mrad": 3.5, "wind_bins": [{"wind_ms": 4, "min_fraction": 0.99},
                                                               {"wind_ms": 8, "min_fraction": 0.62},
                                                               {"wind_ms": 11, "min_fraction": 0.33}],
                          "bin_half_width_ms": 1.0},
        "storage": {"database": "sqlite:///helicalib.db", "images_dir": "images"},
    }


def board_size_m(rows: list[dict], targets: list[dict]) -> float:
    """The board side [m] a laid field needs: :data:`BOARD_OVER_SPOT` times a flat mirror's spot
    (``distance · SUN_DISC_RAD`` plus the mirror's side) at the 90th-percentile distance of its
    heliostats to their boards, rounded up to 0.5 m; at least :data:`BOARD_M`."""
    centre = {t["id"]: np.asarray(t["center_enu_m"], dtype=float) for t in targets}
    pivots = np.array([[r["e_m"], r["n_m"], r["u_m"]] for r in rows], dtype=float)
    boards = np.array([centre[r["target"]] for r in rows])
    spot = float(np.percentile(np.linalg.norm(boards - pivots, axis=1), 90)) * SUN_DISC_RAD + MIRROR_M[0]
    return max(BOARD_M, math.ceil(2.0 * BOARD_OVER_SPOT * spot) / 2.0)


def _first_ring_m(tower_h_m: float) -> float:
    return max(0.6 * tower_h_m, 40.0)


class _Checks:
    """Counts the year's checks (one per heliostat and aim) for ``progress(done, total, candidates)``:
    ``total`` = the receiver checks of every candidate laid + the board checks (at least one per
    heliostat wanted, more when a dropped heliostat's place is checked for another board)."""

    def __init__(self, want: int, progress):
        self.want, self.progress = want, progress
        self.done = self.laid = self.board_planned = 0

    def run(self, fn, count: int, board: bool = False):
        """``fn(step)`` checks ``count`` heliostats, calling ``step(k)`` with k of them done so far."""
        if board:
            self.board_planned += count
        else:
            self.laid += count
        start = self.done

        def step(k: int) -> None:
            if start + k > self.done:
                self.done = start + k
                if self.progress is not None:
                    self.progress(self.done, self.laid + max(self.want, self.board_planned), self.laid)

        out = fn(step) if count else None
        step(count)
        return out


def generate_field(n: int, latitude_deg: float, longitude_deg: float, altitude_m: float = 0.0,
                   targets: int = 4, name: str | None = None, step_days: float = 7.0,
                   step_min: float = 30.0, progress=None) -> tuple[dict, list[dict]]:
    """Field config mapping (without ``heliostats_csv``) and heliostat rows of a feasible field.

    Rings are laid in order; every candidate is checked for the receiver, the first ``n`` that pass
    are shared out over the boards (:func:`assign_boards`) and checked for their board (strokes all
    year, incidence ≤ :data:`MAX_BOARD_INCIDENCE_DEG`); one that fails is dropped, the next candidate
    takes its place and the boards are shared out again, until all ``n`` pass. Rings are added when
    too few candidates remain. The boards are 12 m square unless the laid field's far heliostats need
    more (:func:`board_size_m`): then the boards are set that size and the heliostats shared out and
    checked for them again (at most :data:`BOARD_PASSES` layouts).

    ``progress(done, total, candidates)``, if given, is called as the year's checks go: ``done`` of
    ``total`` heliostat checks (one per heliostat and aim, each over the whole year's sun positions),
    ``candidates`` the positions laid so far. ``done`` only grows; ``total`` grows when more rings or
    more board checks are needed, and the last call has ``done == total``.
    """
    from helicalib.config import Drive, Site

    south = latitude_deg < 0
    pole = 180.0 if south else 0.0
    data = _field_data(n, latitude_deg, longitude_deg, altitude_m, targets, name)
    tower_h = data["tower"]["receiver_aim_enu_m"][2]
    spacing = 1.35 * math.hypot(*MIRROR_M)
    r0 = _first_ring_m(tower_h)
    drive = Drive(**data["drives"][DRIVE_NAME])
    _, sun = year_sun_times(Site(**data["site"]), 2026, step_days=step_days, step_min=step_min,
                            min_elevation_deg=5.0)
    receiver = np.asarray(data["tower"]["receiver_aim_enu_m"], dtype=float)
    want = int(n)
    checks = _Checks(want, progress)
    laid = {"cand": np.empty((0, 3)), "rec_ok": np.empty(0, dtype=bool)}  # the receiver's checks, kept across passes
    layout = 1
    while True:
        rows = _lay(want, data, laid, r0, spacing, pole, south, receiver, sun, drive, checks)
        side = board_size_m(rows, data["targets"])
        if side <= data["targets"][0]["size_m"][0] or layout >= BOARD_PASSES:
            return data, rows  # with the boards the rows were checked for
        # the far heliostats' spots need larger boards: the same positions, the boards set again
        data = _field_data(n, latitude_deg, longitude_deg, altitude_m, targets, name, board_m=side)
        layout += 1


BOARD_PASSES = 3
"""Layouts of :func:`generate_field` at most: a larger board is wider apart from its neighbours, so
the heliostats are shared out and checked for their boards again (the receiver's checks are kept).
The last layout is kept with the boards it was checked for, even if its far heliostats would want
larger ones."""


def _lay(want: int, data: dict, laid: dict, r0: float, spacing: float, pole: float, south: bool,
         receiver: np.ndarray, sun: np.ndarray, drive, checks: _Checks) -> list[dict]:
    """Rows of the first ``want`` positions that pass the receiver's and their board's checks for the
    boards of ``data``; lays more rings into ``laid`` (positions and receiver verdicts) as needed."""
    targets = len(data["targets"])
    cand, rec_ok = laid["cand"], laid["rec_ok"]
    board_ok = np.full((len(cand), targets), -1, dtype=np.int8)  # −1 not checked, 0 fails, 1 passes
    dropped = np.zeros(len(cand), dtype=bool)
    count = max(int(want * 1.15) + 10, len(cand))
    while True:
        if len(cand) < count:                                     # lay rings up to ``count`` candidates
            pts = radial_staggered(count, r0, spacing, pole_azimuth_deg=pole)[len(cand):]
            new = np.column_stack([pts, np.full(len(pts), PIVOT_HEIGHT_M)])
            ok = checks.run(lambda step, new=new: feasible_all_year(new, receiver, sun, drive, progress=step), len(new))
            cand, rec_ok = np.vstack([cand, new]), np.concatenate([rec_ok, ok])
            laid["cand"], laid["rec_ok"] = cand, rec_ok
            board_ok = np.vstack([board_ok, np.full((len(new), targets), -1, dtype=np.int8)])
            dropped = np.concatenate([dropped, np.zeros(len(new), dtype=bool)])
        avail = np.flatnonzero(rec_ok & ~dropped)
        if len(avail) < want:
            if len(cand) >= MAX_CANDIDATES_PER_HELIOSTAT * want + 1000:
                raise RuntimeError(f"only {len(avail)} of {want} candidate positions are feasible all year")
            rate = max(len(avail), 1) / len(cand)
            count = len(cand) + int(1.15 * (want - len(avail)) / rate) + 10
            continue
        sel = avail[:want]
        board = assign_boards(cand[sel], targets, south)
        for k in range(targets):
            idx = sel[(board == k) & (board_ok[sel, k] < 0)]
            if len(idx):
                board_ok[idx, k] = _board_check(cand[idx], data["targets"][k], sun, drive, checks)
        bad = board_ok[sel, board] == 0
        if not bad.any():
            break
        dropped[sel[bad]] = True
    return [{"id": f"H{j + 1:05d}", "e_m": round(float(cand[g, 0]), 2), "n_m": round(float(cand[g, 1]), 2),
             "u_m": PIVOT_HEIGHT_M, "drive": DRIVE_NAME, "target": data["targets"][board[j]]["id"]}
            for j, g in enumerate(sel)]


def _board_check(pivots: np.ndarray, target: dict, sun: np.ndarray, drive, checks: _Checks) -> np.ndarray:
    """(k,) 1 where ``target`` sees the pivots (k, 3) within the incidence limit, at least 1 m from its
    centre, and their strokes reach it all year; else 0."""
    centre = np.asarray(target["center_enu_m"], dtype=float)
    seen = ((board_incidence_deg(pivots, centre, target["normal_enu"]) <= MAX_BOARD_INCIDENCE_DEG)
            & (np.linalg.norm(pivots - centre, axis=1) >= 1.0))
    ok = np.zeros(len(pivots), dtype=np.int8)
    idx = np.flatnonzero(seen)
    checks.run(lambda step: None, len(pivots) - len(idx), board=True)      # settled without the year's sweep
    if len(idx):
        ok[idx] = checks.run(lambda step: feasible_all_year(pivots[idx], centre, sun, drive, progress=step),
                             len(idx), board=True)
    return ok


def write_field(data: dict, rows: list[dict], out_path: str | Path):
    """Write ``FIELD.yaml`` + ``FIELD.csv`` beside it; returns the loaded (validated) config."""
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    csv_path = out.with_suffix(".csv")
    with csv_path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["id", "e_m", "n_m", "u_m", "drive", "target"])
        w.writeheader()
        w.writerows(rows)
    return write_field_config({**data, "heliostats_csv": csv_path.name}, out)


def _plant(n: int) -> dict:
    """The field's SCS on loopback: PLANT_INTERFACE.md's register map, or its layout repeated on
    several Modbus unit ids (``plant-interface-1-units``) for a field that map cannot address."""
    plant = {"scs": {"host": "127.0.0.1", "port": 5020, "unit": 1, "timeout_s": 2.0}, "clock": "plant"}
    if check_count(default_register_map(), n):
        plant["register_map"] = "plant-interface-1-units"
    return plant
