"""Target-camera renderer of the simulated plant and ``SimCamera`` (``devices.protocols.Camera``).

A frame is rendered in two steps. The board is rastered in its own plane (target frame u, v):
a static albedo image (white board, four black L marks or nine black dots, ``sim.boards``) lit by the ambient light (tied to DNI)
plus the spot of every heliostat whose *true* beam meets the board. Each spot is the mirror's
footprint (mirror size × incidence, stretched by the board's obliquity) blurred by a Gaussian of
the sun shape and twice the slope error, carrying ``DNI · area · cos(incidence) · reflectivity ·
cleanliness`` watts; the footprint and blur are separable, so all spots are one matrix product.
The lit raster is then warped into the image through the board→pixel homography of a pinhole
camera at ``position_enu_m`` looking at the board centre, noise is added (a pre-drawn noise tile
at a random offset), and values saturate at 8 bits.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import ndtr

from helicalib.devices.protocols import Frame
from helicalib.geometry import optics
from helicalib.sim.boards import dark_mask
from helicalib.sim.scenario import CameraSpec, Optics

UP = np.array([0.0, 0.0, 1.0])
FLUX_FLOOR_WM2 = 1e-5
"""Spot irradiance below this [W/m²] is not rastered (2e-6 counts at the default gain: below the
float32 resolution of the lit board)."""


def simulated_fe(scenario) -> float:
    """Fe [W/m² per grey] of the simulated cameras of ``scenario``: what a FLUX.yaml would hold.

    The renderer turns irradiance E on the white board into ``grey = board_albedo · gain · E``
    (plus ambient light and noise, which the after − before difference removes), so
    ``Fe = 1 / (board_albedo · gain_counts_per_wm2)``. Only the white board obeys it: the L marks
    (``mark_albedo``) and a dot board's dots (``dot_albedo``) are darker.
    """
    spec = scenario.camera
    return 1.0 / (float(spec.board_albedo) * float(spec.gain_counts_per_wm2))


def simulated_flux(cfg, scenario) -> dict[str, tuple[float, None]]:
    """Each board's (Fe, atmosphere) for the campaign's camera sensors
    (:func:`helicalib.campaign.sensor.camera_sensors`): the scenario's Fe, and None for the
    atmosphere because the simulated plant renders no attenuation between mirror and board."""
    fe = simulated_fe(scenario)
    return {t.id: (fe, None) for t in cfg.targets}


def camera_pose(position_enu: np.ndarray, look_at_enu: np.ndarray) -> np.ndarray:
    """World→camera rotation (3, 3), OpenCV axes (x right, y down, z forward), level (no roll)."""
    f = optics.unit(np.asarray(look_at_enu, float) - np.asarray(position_enu, float))
    x = np.cross(f, UP)
    x = x / np.linalg.norm(x)
    y = np.cross(f, x)
    return np.stack([x, y, f])


def default_camera_position(target) -> np.ndarray:
    """Default camera position: 80 m out along the board normal, 2 m above the ground [m, ENU]."""
    c = np.asarray(target.center_enu_m, float)
    w = np.asarray(target.normal_enu, float)
    p = c + 80.0 * w
    p[2] = 2.0
    return p


def board_homography(camera_cfg, target) -> tuple[np.ndarray, tuple[int, int]]:
    """Homography (3, 3) from board coordinates (u, v, 1) [m] to pixels, and (width, height) [px]."""
    width, height = camera_cfg.resolution_px
    pos = np.asarray(camera_cfg.position_enu_m, float) if camera_cfg.position_enu_m is not None \
        else default_camera_position(target)
    centre = np.asarray(target.center_enu_m, float)
    r = camera_pose(pos, centre)
    k = camera_cfg.camera_matrix
    if k is None:
        dist = float(np.linalg.norm(centre - pos))
        f = 0.7 * width * dist / max(target.size_m)
        k = np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
    frame = target.frame_enu
    m = np.column_stack([r @ frame[0], r @ frame[1], r @ (centre - pos)])
    return k @ m, (int(width), int(height))


def spot_geometry(target, optics_spec, origin_enu, direction_enu, sun_enu, normal_enu, mirror_size_m, dni_wm2,
                  cleanliness):
    """Where N beams light a board, as the renderer draws them.

    Returns ``(uv_m (N, 2), power_w (N,), width_m (N, 2), sigma_m (N, 2), near (N,) bool)``: the
    beam's point on the board plane (u, v from the centre), the power it carries, the mirror's
    footprint (mirror size × √cos incidence, stretched by the board's obliquity) and the Gaussian
    blur of the sun shape and twice the slope error; ``near`` is False for beams that miss the
    board from the front by more than their footprint and 4 σ.
    """
    uv, hit, valid = optics.intersect_target(origin_enu, direction_enu, target)
    w = target.frame_enu[2]
    cos_b = -(direction_enu @ w)
    dist = np.linalg.norm(hit - origin_enu, axis=-1)
    cos_inc = np.clip(normal_enu @ np.asarray(sun_enu, float), 0.0, 1.0)
    sigma_beam = 1e-3 * math.hypot(optics_spec.sun_sigma_mrad, 2.0 * optics_spec.slope_error_mrad)
    stretch = 1.0 / np.sqrt(np.clip(cos_b, 0.05, 1.0))
    width = mirror_size_m * np.sqrt(cos_inc)[:, None] * stretch[:, None]
    sigma = (sigma_beam * dist * stretch)[:, None] * np.ones((1, 2))
    half = np.asarray(target.size_m) / 2.0
    with np.errstate(invalid="ignore"):
        reach = half[None, :] + width / 2 + 4 * sigma
        near = valid & (cos_b > 0) & (cos_inc > 0) & np.all(np.abs(uv) < reach, axis=-1)
    area = mirror_size_m[:, 0] * mirror_size_m[:, 1]
    power = dni_wm2 * area * cos_inc * optics_spec.reflectivity * np.asarray(cleanliness)
    return uv, power, np.maximum(width, 1e-3), sigma, near & (power > 0)


def stopped_before(target, others, origin_enu, direction_enu) -> np.ndarray:
    """True for the beams (N, 3) that meet one of the boards ``others`` (within the board) before they
    reach ``target``'s plane: a board is opaque, so such a beam lights that board and not this one.
    (A beam aimed at a board near a neighbour that the field sees overlapping it used to be drawn on
    both.)"""
    _, hit, valid = optics.intersect_target(origin_enu, direction_enu, target)
    reach = np.where(valid, np.linalg.norm(hit - origin_enu, axis=-1), np.inf)
    out = np.zeros(len(origin_enu), dtype=bool)
    for other in others:
        uv, hit_o, valid_o = optics.intersect_target(origin_enu, direction_enu, other)
        with np.errstate(invalid="ignore"):
            inside = valid_o & np.all(np.abs(uv) <= np.asarray(other.size_m) / 2.0, axis=-1)
            out |= inside & (np.linalg.norm(hit_o - origin_enu, axis=-1) < reach)
    return out


class BoardRenderer:
    """Renders frames of one camera (its pose, intrinsics and target board), cached static parts."""

    def __init__(self, camera_cfg, target, spec: CameraSpec, optics_spec: Optics, seed: int = 0):
        self.camera = camera_cfg
        self.target = target
        self.spec = spec
        self.optics = optics_spec
        self.h_board, self.size_px = board_homography(camera_cfg, target)
        w_m, h_m = target.size_m
        # raster resolution: about 1.5 raster pixels per image pixel at the board centre
        centre_px = self.h_board @ np.array([0.0, 0.0, 1.0])
        step_px = self.h_board @ np.array([1.0, 0.0, 1.0])
        px_per_m = float(np.linalg.norm(step_px[:2] / step_px[2] - centre_px[:2] / centre_px[2]))
        self.ppm = float(np.clip(1.5 * px_per_m, spec.board_px_per_m, 150.0))
        self.nu, self.nv = int(math.ceil(w_m * self.ppm)), int(math.ceil(h_m * self.ppm))
        self.u_m = -w_m / 2 + (np.arange(self.nu) + 0.5) * (w_m / self.nu)
        self.v_m = h_m / 2 - (np.arange(self.nv) + 0.5) * (h_m / self.nv)
        raster_to_board = np.array([[w_m / self.nu, 0.0, -w_m / 2], [0.0, -h_m / self.nv, h_m / 2], [0.0, 0.0, 1.0]])
        # raster pixel (x, y) covers [x, x+1): its centre is (x+0.5); OpenCV maps pixel centres
        shift = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])
        self.h_raster = self.h_board @ raster_to_board @ shift
        uu, vv = np.meshgrid(self.u_m, self.v_m)
        dark = spec.dot_albedo if target.marks is not None and target.marks.kind == "dots" else spec.mark_albedo
        self.albedo = np.where(dark_mask(target, uu, vv), dark, spec.board_albedo).astype(np.float32)
        rng = np.random.default_rng(seed)
        w, h = self.size_px
        self._noise = rng.standard_normal((h + 64, w + 64)).astype(np.float32) * np.float32(spec.noise_counts)
        self._rng = rng

    def spot_flux_wm2(self, uv_m: np.ndarray, power_w: np.ndarray, width_m: np.ndarray,
                      sigma_m: np.ndarray) -> np.ndarray:
        """Irradiance raster (nv, nu) [W/m²] of K spots: box (K, 2) ⊗ Gaussian σ (K, 2), total power (K,)."""
        out = np.zeros((self.nv, self.nu), dtype=np.float32)
        win = self.spot_flux_window(uv_m, power_w, width_m, sigma_m)
        if win is not None:
            rows, cols, flux = win
            out[rows, cols] = flux
        return out

    def spot_flux_window(self, uv_m, power_w, width_m, sigma_m):
        """``(rows, cols, flux)``: the raster window (two slices) outside which the K spots add less
        than ``FLUX_FLOOR_WM2`` anywhere, and the irradiance (float32) inside it; None if no spot."""
        if len(power_w) == 0:
            return None

        def profile(grid, centre, width, sigma):  # (K, n), integrates to 1 over the axis
            g = grid[None, :] - centre[:, None]
            half = width[:, None] / 2.0
            s = sigma[:, None]
            return (ndtr((g + half) / s) - ndtr((g - half) / s)) / width[:, None]

        pu = profile(self.u_m, uv_m[:, 0], width_m[:, 0], sigma_m[:, 0])
        pv = profile(self.v_m, uv_m[:, 1], width_m[:, 1], sigma_m[:, 1])
        # a spot's term P_k · pv_k(v) · pu_k(u) is at most P_k · max(pv_k) · pu_k(u) (and alike): drop
        # the Gaussian tails whose terms stay below FLUX_FLOOR_WM2 / K everywhere (their products
        # would underflow to subnormal numbers, which the CPU handles tens of times slower)
        k = len(power_w)
        scale_u = (power_w * pv.max(axis=1))[:, None]
        scale_v = (power_w * pu.max(axis=1))[:, None]
        pu = np.where(pu * scale_u >= FLUX_FLOOR_WM2 / k, pu, 0.0)
        pv = np.where(pv * scale_v >= FLUX_FLOOR_WM2 / k, pv, 0.0)
        # upper bounds of the flux along each column / row
        col = np.sum(pu * scale_u, axis=0)
        row = np.sum(pv * scale_v, axis=0)
        c = np.flatnonzero(col >= FLUX_FLOOR_WM2)
        r = np.flatnonzero(row >= FLUX_FLOOR_WM2)
        if c.size == 0 or r.size == 0:
            return None
        rows, cols = slice(int(r[0]), int(r[-1]) + 1), slice(int(c[0]), int(c[-1]) + 1)
        shape = (rows.stop - rows.start, cols.stop - cols.start)
        if k == 1:  # the usual case: one outer product (the same values as the matrix product)
            flux = np.empty(shape, dtype=np.float32)
            np.multiply.outer(pv[0, rows] * power_w[0], pu[0, cols], out=flux, casting="same_kind")
            return rows, cols, flux
        acc = np.zeros(shape, dtype=np.float32)
        for j in range(k):  # each spot over its own extent only, summed in float32 (the raster's type)
            cu, rv = np.flatnonzero(pu[j, cols]), np.flatnonzero(pv[j, rows])
            if cu.size and rv.size:
                rs, cs = slice(rv[0], rv[-1] + 1), slice(cu[0], cu[-1] + 1)
                a = (pv[j, rows][rs] * power_w[j]).astype(np.float32)
                acc[rs, cs] += np.multiply.outer(a, pu[j, cols][cs].astype(np.float32))
        return rows, cols, acc

    def spots_from_beams(self, origin_enu, direction_enu, sun_enu, normal_enu, mirror_size_m, dni_wm2,
                         cleanliness, others=()):
        """Board-frame spot parameters of the beams (N, 3) that meet this board from the front, less
        those that another board of ``others`` (the plant's other targets) stops first."""
        uv, power, width, sigma, k = spot_geometry(self.target, self.optics, origin_enu, direction_enu, sun_enu,
                                                   normal_enu, mirror_size_m, dni_wm2, cleanliness)
        if others and k.any():
            idx = np.nonzero(k)[0]
            k[idx[stopped_before(self.target, others, origin_enu[idx], direction_enu[idx])]] = False
        return uv[k], power[k], width[k], sigma[k]

    def render(self, spots, dni_wm2: float, daylight: bool, exposure: float = 1.0) -> np.ndarray:
        """The frame (height, width) uint8 for spots ``(uv, power, width, sigma)`` and the ambient light.

        ``exposure``: the exposure relative to the nominal one (``CameraSpec.exposure_ms``). Light
        (board, spots, background) scales with it; the noise is the sensor's at the nominal exposure
        times :func:`noise_scale` (read noise fixed, shot noise growing with the collected light);
        values clip at 255. At 1 the frame is the nominal one, bit for bit."""
        s = self.spec
        ambient = np.float32((s.ambient_fraction * dni_wm2 + s.ambient_offset_wm2) if daylight else 0.0)
        # the board lit by the ambient light, then the spots only inside their window (the flux
        # elsewhere is below FLUX_FLOOR_WM2, far under the 8-bit resolution)
        radiance = self.albedo * ambient
        win = self.spot_flux_window(*spots) if spots is not None else None
        if win is not None:
            rows, cols, flux = win
            flux += ambient
            flux *= self.albedo[rows, cols]
            radiance[rows, cols] = flux
        radiance *= np.float32(s.gain_counts_per_wm2 * exposure)
        background = s.background_counts * (dni_wm2 / 1000.0 + 0.2) * exposure if daylight else 0.0
        w, h = self.size_px
        img = cv2.warpPerspective(radiance, self.h_raster, (w, h), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=float(background))
        ox, oy = self._rng.integers(0, 64, size=2)
        if exposure == 1.0:
            img += self._noise[oy:oy + h, ox:ox + w]
        else:
            img += self._noise[oy:oy + h, ox:ox + w] * np.float32(noise_scale(exposure, s.read_noise_share))
        np.clip(img, 0.0, 255.0, out=img)
        return (img + 0.5).astype(np.uint8)


def noise_scale(exposure: float, read_share: float) -> float:
    """The sensor noise's standard deviation at ``exposure`` (relative to the nominal one) over
    its nominal value: read noise (variance share ``read_share``) stays, shot noise grows with the
    light collected (variance ∝ exposure). Modelled per frame, not per pixel, so that the nominal
    frame keeps its uniform noise."""
    return math.sqrt(read_share + (1.0 - read_share) * exposure)


_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV ≥ 4.10
    _PNG_PARAMS += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
"""Lossless and fast both ways. Measured on a 1280×1024 sim frame (OpenCV 5.0, CPU time): level 1
alone 22 ms to encode, 10 ms to decode, 598 KiB; level 1 + RLE + no row filter 11 ms, 6 ms, 521 KiB."""


def encode_png(image: np.ndarray) -> bytes:
    """8-bit grayscale PNG (fast, lossless)."""
    ok, buf = cv2.imencode(".png", image, _PNG_PARAMS)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


class SimCamera:
    """A camera of the in-process :class:`~helicalib.sim.plant.SimulatedPlant` (``Camera`` protocol).

    ``grab()`` renders the board at the plant's current time and returns PNG bytes with the
    capture time in plant time. ``render()`` gives the uint8 array without encoding.

    ``fe_wm2_per_grey`` is :func:`simulated_fe` of the plant's scenario (the campaign gets it
    through :func:`simulated_flux`, not from the camera); it holds at the nominal exposure
    (``CameraSpec.exposure_ms``), grey levels scale with ``exposure_ms`` / nominal.

    Exposure (PLANT_INTERFACE 1.1): ``exposure_control`` is the scenario's ``camera.exposure``.
    A camera with it keeps its setting ``exposure_ms`` (the nominal exposure at first), which
    :meth:`set_exposure` or ``grab(exposure_ms=...)`` changes (clamped to
    ``camera.exposure_range_ms``), and its frames carry it (``Frame.exposure_ms``). A camera without
    it ignores every asked exposure, stays at the nominal one and its frames carry None.
    """

    def __init__(self, plant, camera_id: str):
        self.plant = plant
        cams = {c.id: c for c in plant.cfg.cameras}
        if camera_id not in cams:
            raise KeyError(f"no camera {camera_id!r} (defined: {', '.join(cams)})")
        self.config = cams[camera_id]
        self.target = plant.cfg.target(self.config.target)
        sc = plant.scenario
        seed = (sc.seed * 1000 + list(cams).index(camera_id)) & 0xFFFFFFFF
        self.renderer = BoardRenderer(self.config, self.target, sc.camera, sc.optics, seed=seed)
        self.others = tuple(t for t in plant.cfg.targets if t.id != self.target.id)  # boards that may stop a beam
        self.source = self.config.url
        self.fe_wm2_per_grey = simulated_fe(sc)
        self.nominal_exposure_ms = float(sc.camera.exposure_ms)
        self.exposure_range_ms = (float(sc.camera.exposure_range_ms[0]), float(sc.camera.exposure_range_ms[1]))
        self.exposure_control = bool(sc.camera.exposure)
        self.exposure_ms = self.nominal_exposure_ms

    def set_exposure(self, exposure_ms: float) -> float | None:
        """Set the exposure [ms], clamped to ``exposure_range_ms``; returns the exposure applied, or
        None (nothing changed) for a camera without exposure control. Raises ValueError for an
        exposure that is not a positive finite number."""
        value = float(exposure_ms)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"exposure_ms must be a positive number, got {exposure_ms!r}")
        if not self.exposure_control:
            return None
        self.exposure_ms = min(max(value, self.exposure_range_ms[0]), self.exposure_range_ms[1])
        return self.exposure_ms

    def render(self) -> tuple[np.ndarray, float]:
        """(frame (height, width) uint8, capture time [UTC s, plant time]) at the current exposure."""
        p = self.plant
        t = p.t_s
        sun, elevation = p.sun(t)
        weather = p.weather()
        beams = p.true_beams(t)
        spots = self.renderer.spots_from_beams(
            beams.origin_enu, beams.direction_enu, sun, beams.normal_enu, p.nominal.drives.mirror_size_m,
            weather.dni_wm2, p.soiling.cleanliness(t), others=self.others)
        exposure = self.exposure_ms / self.nominal_exposure_ms
        return self.renderer.render(spots, weather.dni_wm2, elevation > 0.0, exposure), t

    def grab(self, exposure_ms: float | None = None) -> Frame:
        """A frame at ``exposure_ms`` (set first; ignored without exposure control), else at the
        current setting."""
        if exposure_ms is not None:
            self.set_exposure(exposure_ms)
        image, t = self.render()
        return Frame(data=encode_png(image), capture_time_s=float(t), source=self.source,
                     exposure_ms=self.exposure_ms if self.exposure_control else None)
