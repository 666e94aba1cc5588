"""An independent reference of the PAINT / ARTIST rigid-body kinematics (two linear actuators).

This is the formula of ``../shared/realdata/README.md`` written out literally with 4×4 homogeneous
transforms, the way ARTIST's ``RigidBody.motor_positions_to_orientations`` composes them. It is
deliberately *not* built from helicalib's geometry (drive presets, actuator triangle, reflection):
it is what the imported field config is checked against.

    L(m)   = m / increment + initial_stroke_length                       (actuator length [m])
    φ(L)   = acos((o² + r² - L²) / (2 o r))                               (o = offset, r = pivot_radius)
    θ      = θ0 - (φ(L0) - φ(L))   if clockwise_axis_movement == 0
           = θ0 + (φ(L0) - φ(L))   otherwise
    θ0     = initial_angle (axis 2),  initial_angle - π/2 (axis 1: PAINT measures it from the zenith)
    T      = Tr(position) · Rn(t1n) Ru(t1u) Tr(j1) Re(θ1) · Re(t2e) Rn(t2n) Tr(j2) Ru(θ2) · Tr(c)
    normal = T · (0, -1, 0, 0);  mirror centre = T · (0, 0, 0, 1)

with c = (concentrator_translation_e, _n, _u) = (0, 0.175, 0) for the Jülich heliostats, so the
mirror centre is 0.175 m from the pivot *against* the normal (as ARTIST computes it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class PaintActuator:
    """One PAINT linear actuator (``kinematics_properties.actuators[i]`` or a HeliOS axis row)."""

    increment: float  # motor steps per metre of actuator length
    initial_stroke_length: float  # L0 [m]
    offset: float  # o [m]
    pivot_radius: float  # r [m]
    initial_angle: float  # [rad], as stored (axis 1 from the zenith)
    clockwise_axis_movement: int  # 0 or 1
    min_increment: float = 0.0
    max_increment: float = float("inf")
    type_axis: str = "linear"

    def length_m(self, steps) -> np.ndarray:
        return np.asarray(steps, dtype=float) / self.increment + self.initial_stroke_length

    def phi(self, length_m) -> np.ndarray:
        o, r = self.offset, self.pivot_radius
        return np.arccos((o * o + r * r - np.asarray(length_m, dtype=float) ** 2) / (2.0 * o * r))


def _re(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=float)


def _rn(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]], dtype=float)


def _ru(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)


def _tr(v) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = np.asarray(v, dtype=float)
    return t


@dataclass(frozen=True)
class PaintKinematics:
    """PAINT rigid-body kinematics of one heliostat at ``position_enu_m`` (plant ENU)."""

    position_enu_m: tuple[float, float, float]
    actuators: tuple[PaintActuator, PaintActuator]
    concentrator_translation: tuple[float, float, float] = (0.0, 0.175, 0.0)
    joint_translation_1: tuple[float, float, float] = (0.0, 0.0, 0.0)
    joint_translation_2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # deviation tilts (zero in the published PAINT properties; ARTIST learns them)
    first_joint_tilt_n: float = 0.0
    first_joint_tilt_u: float = 0.0
    second_joint_tilt_e: float = 0.0
    second_joint_tilt_n: float = 0.0
    initial_orientation: tuple[float, float, float] = field(default=(0.0, -1.0, 0.0))

    def joint_angles(self, motor_steps) -> tuple[float, float]:
        """Axis angles (θ1, θ2) [rad] for motor positions (m1, m2), θ1 from the horizontal."""
        out = []
        for i, (act, m) in enumerate(zip(self.actuators, motor_steps)):
            delta = float(act.phi(act.initial_stroke_length) - act.phi(act.length_m(m)))
            theta0 = act.initial_angle - (math.pi / 2 if i == 0 else 0.0)
            out.append(theta0 - delta if act.clockwise_axis_movement == 0 else theta0 + delta)
        return out[0], out[1]

    def transform(self, motor_steps) -> np.ndarray:
        t1, t2 = self.joint_angles(motor_steps)
        return (
            _tr(self.position_enu_m)
            @ _rn(self.first_joint_tilt_n)
            @ _ru(self.first_joint_tilt_u)
            @ _tr(self.joint_translation_1)
            @ _re(t1)
            @ _re(self.second_joint_tilt_e)
            @ _rn(self.second_joint_tilt_n)
            @ _tr(self.joint_translation_2)
            @ _ru(t2)
            @ _tr(self.concentrator_translation)
        )

    def normal(self, motor_steps) -> np.ndarray:
        t = self.transform(motor_steps)
        return t[:3, :3] @ np.asarray(self.initial_orientation, dtype=float)

    def mirror_centre(self, motor_steps) -> np.ndarray:
        return self.transform(motor_steps)[:3, 3].copy()

    def beam(self, motor_steps, sun_enu) -> tuple[np.ndarray, np.ndarray]:
        """(origin, unit direction) of the reflected central ray; ``sun_enu`` points to the sun."""
        n = self.normal(motor_steps)
        s = np.asarray(sun_enu, dtype=float)
        s = s / np.linalg.norm(s)
        d = 2.0 * float(s @ n) * n - s
        return self.mirror_centre(motor_steps), d / np.linalg.norm(d)

    def spot_on_plane(self, motor_steps, sun_enu, plane_point, plane_normal) -> np.ndarray:
        """Where the central ray meets the plane (ENU [m])."""
        o, d = self.beam(motor_steps, sun_enu)
        p0, nn = np.asarray(plane_point, dtype=float), np.asarray(plane_normal, dtype=float)
        t = float((p0 - o) @ nn) / float(d @ nn)
        return o + t * d


def sun_vector_paint(azimuth_deg_south0: float, elevation_deg: float) -> np.ndarray:
    """PAINT's sun angles (azimuth 0 = south, +90 = east) → unit vector to the sun (E, N, U)."""
    az, el = math.radians(azimuth_deg_south0), math.radians(elevation_deg)
    return np.array([math.cos(el) * math.sin(az), -math.cos(el) * math.cos(az), math.sin(el)])


def normal_error_mrad(kin: PaintKinematics, motor_steps, sun_enu, spot_enu) -> float:
    """Angle [mrad] between the kinematics' normal and the normal that would put the beam on the spot."""
    n = kin.normal(motor_steps)
    m = kin.mirror_centre(motor_steps)
    s = np.asarray(sun_enu, dtype=float) / np.linalg.norm(sun_enu)
    r = np.asarray(spot_enu, dtype=float) - m
    want = s + r / np.linalg.norm(r)
    want /= np.linalg.norm(want)
    return 1000.0 * math.acos(max(-1.0, min(1.0, float(n @ want))))
