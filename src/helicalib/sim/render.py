"""A small synthetic target-board renderer for tests and benchmarks (not a physical simulator).

It draws what a target camera sees: the white board in perspective from a camera pose, the four
black L marks or nine black dots (``marks`` of the field config), uneven ambient lighting, a darker background around
the board, zero or more heliostat spots (Gaussian or flat-topped elliptical, in board metres, so
their true centre is known exactly), sensor noise and 8-bit saturation. Every pixel is evaluated
analytically at ``supersample²`` points (anti-aliased edges), so ground truth does not depend
on a texture resolution.

Brightness model (grey levels)::

    g = albedo(u, v) · (ambient · light(u, v) + Σ spot_k(u, v)) + noise,   clipped to 0..255

with albedo 1 on the white board, ``mark_albedo`` on the marks, and ``background`` off the board.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from helicalib.config import DotMarks, Target
from helicalib.sim.boards import dark_mask


@dataclass(frozen=True)
class CameraPose:
    """A pinhole camera: intrinsics ``K`` (3, 3) and world→camera rotation ``R`` (3, 3), centre ``C`` (3,) ENU [m].

    Camera axes follow OpenCV: x right, y down, z forward.
    """

    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    resolution_px: tuple[int, int]  # (width, height)
    distortion: tuple[float, ...] | None = None

    def board_to_image(self, target: Target) -> np.ndarray:
        """Homography (3, 3): board (u, v, 1) [m] → ideal (undistorted) image pixels."""
        frame = target.frame_enu
        r1 = self.R @ frame[0]
        r2 = self.R @ frame[1]
        t = self.R @ (np.asarray(target.center_enu_m) - self.C)
        H = self.K @ np.column_stack([r1, r2, t])
        return H / H[2, 2]


def look_at_pose(camera_enu_m, target: Target, fx: float, resolution_px=(1280, 1024), *, fy: float | None = None,
                 cx: float | None = None, cy: float | None = None, aim_uv_m=(0.0, 0.0), roll_deg: float = 0.0,
                 distortion: Sequence[float] | None = None) -> CameraPose:
    """A camera at ``camera_enu_m`` [m] looking at the board point ``aim_uv_m`` with the board's u to the image right.

    ``roll_deg`` turns the image about the optical axis (clockwise on the image).
    """
    w, h = resolution_px
    K = np.array([[fx, 0.0, (w - 1) / 2 if cx is None else cx],
                  [0.0, fx if fy is None else fy, (h - 1) / 2 if cy is None else cy],
                  [0.0, 0.0, 1.0]])
    C = np.asarray(camera_enu_m, dtype=float)
    aim = target.uvw_to_enu(np.asarray(aim_uv_m, dtype=float))
    z = aim - C
    z /= np.linalg.norm(z)
    u = target.frame_enu[0]
    x = u - (u @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    a = np.deg2rad(roll_deg)
    xr, yr = np.cos(a) * x + np.sin(a) * y, -np.sin(a) * x + np.cos(a) * y
    R = np.stack([xr, yr, z])
    return CameraPose(K=K, R=R, C=C, resolution_px=(int(w), int(h)),
                      distortion=None if distortion is None else tuple(float(d) for d in distortion))


def pose_from_camera(camera, target: Target) -> CameraPose:
    """The pose of a configured camera (``position_enu_m`` and ``intrinsics`` required), aimed at the board centre."""
    k = camera.intrinsics
    return look_at_pose(camera.position_enu_m, target, k.fx, camera.resolution_px, fy=k.fy, cx=k.cx, cy=k.cy,
                        distortion=camera.distortion)


@dataclass(frozen=True)
class Spot:
    """A heliostat spot on the board.

    ``shape`` "gaussian": ``peak · exp(-½ (a²/σa² + b²/σb²))`` with ``size_m = (σa, σb)``;
    "flat": a flat-topped ellipse of semi-axes ``size_m`` with a linear soft edge of relative width
    ``edge``. (a, b) are the board offsets turned by ``angle_deg``. ``peak`` is in grey levels on the
    white board.
    """

    center_m: tuple[float, float]
    size_m: tuple[float, float]
    peak: float = 120.0
    shape: str = "gaussian"
    angle_deg: float = 0.0
    edge: float = 0.25

    def irradiance(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        a = np.deg2rad(self.angle_deg)
        du, dv = u - self.center_m[0], v - self.center_m[1]
        p = (np.cos(a) * du + np.sin(a) * dv) / self.size_m[0]
        q = (-np.sin(a) * du + np.cos(a) * dv) / self.size_m[1]
        r2 = p * p + q * q
        if self.shape == "gaussian":
            return self.peak * np.exp(-0.5 * r2)
        if self.shape == "flat":
            r = np.sqrt(r2)
            return self.peak * np.clip((1.0 + self.edge / 2 - r) / self.edge, 0.0, 1.0)
        raise ValueError(f"unknown spot shape {self.shape!r}")


DOT_ALBEDO = 0.65
"""The dots' default albedo relative to the white board: light grey (the 2019 article names the dots'
sizes and layout, not their colour). A spot's light on a dot is restored at 1/albedo times the
frame's noise, so black dots (0.06, as T/GRLM's L marks) measure spots 2.4-7.5 times worse than a
mark board, and light-grey ones 0.39-1.05 times as far off, on frames exposed for the board and for
the spot: docs/vision.md, "Light-grey dots"."""


@dataclass(frozen=True)
class Lighting:
    """Scene light: ``ambient`` grey level of the white board at its centre, a linear gradient
    ``gradient`` (fraction per board half-width along u and v), ``background`` grey level off the
    board, ``mark_albedo`` of T/GRLM's black L marks, ``dot_albedo`` of a dot board's dots
    (:data:`DOT_ALBEDO`), ``noise_sigma`` grey levels of sensor noise. Albedos are relative to
    the white board (1)."""

    ambient: float = 150.0
    gradient: tuple[float, float] = (0.15, -0.10)
    background: float = 60.0
    mark_albedo: float = 0.06
    noise_sigma: float = 1.5
    dot_albedo: float = DOT_ALBEDO

    def albedo_of(self, target: Target) -> float:
        """The albedo of ``target``'s marks: its dots on a dot board, else the L marks'."""
        return self.dot_albedo if target.marks is not None and target.marks.kind == "dots" else self.mark_albedo


def _image_to_board(pose: CameraPose, target: Target, xs: np.ndarray, ys: np.ndarray):
    if pose.distortion is not None and any(abs(d) > 0 for d in pose.distortion):
        import cv2

        pts = np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(np.float64).reshape(-1, 1, 2)
        und = cv2.undistortPoints(pts, pose.K, np.asarray(pose.distortion), P=pose.K).reshape(-1, 2)
        xs, ys = und[:, 0].reshape(xs.shape), und[:, 1].reshape(ys.shape)
    Hi = np.linalg.inv(pose.board_to_image(target))
    w = Hi[2, 0] * xs + Hi[2, 1] * ys + Hi[2, 2]
    u = (Hi[0, 0] * xs + Hi[0, 1] * ys + Hi[0, 2]) / w
    v = (Hi[1, 0] * xs + Hi[1, 1] * ys + Hi[1, 2]) / w
    return u, v, w


def _board_bbox(pose: CameraPose, target: Target) -> tuple[int, int, int, int]:
    """Pixel box (x0, y0, x1, y1) holding the board, with a margin; the whole frame if unsure."""
    width, height = pose.resolution_px
    hw, hh = target.size_m[0] / 2, target.size_m[1] / 2
    edge = np.linspace(-1.0, 1.0, 9)
    uv = np.concatenate([np.column_stack([edge * hw, np.full(9, s * hh)]) for s in (-1, 1)]
                        + [np.column_stack([np.full(9, s * hw), edge * hh]) for s in (-1, 1)])
    frame = target.frame_enu
    P = np.asarray(target.center_enu_m) + uv[:, :1] * frame[0] + uv[:, 1:2] * frame[1]
    if np.any((P - pose.C) @ pose.R[2] <= 0):
        return 0, 0, width, height
    px = project_board_points(pose, target, uv)
    margin = 4 + 0.02 * max(width, height)
    x0, y0 = np.floor(px.min(axis=0) - margin).astype(int)
    x1, y1 = np.ceil(px.max(axis=0) + margin).astype(int)
    return max(0, x0), max(0, y0), min(width, x1), min(height, y1)


def render_frame(target: Target, pose: CameraPose, spots: Sequence[Spot] = (), lighting: Lighting = Lighting(), *,
                 rng: np.random.Generator | int | None = 0, supersample: int = 2) -> np.ndarray:
    """Render one 8-bit frame, uint8 (H, W) with H, W from ``pose.resolution_px``."""
    rng = np.random.default_rng(rng)
    width, height = pose.resolution_px
    hw, hh = target.size_m[0] / 2, target.size_m[1] / 2
    ys_full = np.arange(height, dtype=np.float64)[:, None]
    img = np.broadcast_to(lighting.background * (1.0 + 0.1 * ys_full / height), (height, width)).copy()
    x0, y0, x1, y1 = _board_bbox(pose, target)
    if x1 > x0 and y1 > y0:
        acc = np.zeros((y1 - y0, x1 - x0), dtype=np.float64)
        ys0, xs0 = np.mgrid[y0:y1, x0:x1].astype(np.float64)
        offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
        for oy in offsets:
            for ox in offsets:
                u, v, w = _image_to_board(pose, target, xs0 + ox, ys0 + oy)
                on_board = (np.abs(u) <= hw) & (np.abs(v) <= hh) & (w > 0)
                light = lighting.ambient * (1.0 + lighting.gradient[0] * u / hw + lighting.gradient[1] * v / hh)
                for s in spots:
                    light = light + s.irradiance(u, v)
                albedo = np.where(dark_mask(target, u, v), lighting.albedo_of(target), 1.0)
                acc += np.where(on_board, albedo * light, lighting.background * (1.0 + 0.1 * (ys0 / height)))
        img[y0:y1, x0:x1] = acc / supersample**2
    if lighting.noise_sigma > 0:
        img = img + rng.normal(0.0, lighting.noise_sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def project_board_points(pose: CameraPose, target: Target, uv_m: np.ndarray) -> np.ndarray:
    """Board points (N, 2) [m] → image pixels (N, 2) of this pose (distortion applied)."""
    import cv2

    uv = np.atleast_2d(np.asarray(uv_m, dtype=float))
    frame = target.frame_enu
    P = np.asarray(target.center_enu_m) + uv[:, :1] * frame[0] + uv[:, 1:2] * frame[1]
    rvec, _ = cv2.Rodrigues(pose.R)
    tvec = -pose.R @ pose.C
    dist = np.zeros(5) if pose.distortion is None else np.asarray(pose.distortion, dtype=float)
    px, _ = cv2.projectPoints(P.reshape(-1, 1, 3), rvec, tvec, pose.K, dist)
    return px.reshape(-1, 2)


def demo_target() -> Target:
    """The 12 m board of ``field_config/demo_north.yaml`` (T1), built in memory."""
    return Target(id="T1", center_enu_m=(9.0, 8.0, 95.0), normal_enu=(0.0, 1.0, 0.0), size_m=(12.0, 12.0),
                  standby_offset_m=(-15.0, 0.0),
                  marks={"vertices_m": [[-5.5, 5.5], [5.5, 5.5], [5.5, -5.5], [-5.5, -5.5]],
                         "arm_m": 1.4, "thickness_m": 0.35})


def demo_dot_target() -> Target:
    """The demo board T1 with nine dots (``kind: dots``, the defaults: 1.7 / 0.85 m dots, pitch 4.25 m)."""
    return demo_target().model_copy(update={"marks": DotMarks(kind="dots")})


DEMO_CAMERA_ENU_M = (14.0, 75.0, 2.0)
"""Camera C1 of the demo field: on the ground ~70 m in front of the board, a steep upward view."""
