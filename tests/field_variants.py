"""Variants of the demo field for geometry tests (plain helpers, imported by the test modules)."""

from __future__ import annotations

AZEL_DRIVE = {"kind": "azimuth-elevation", "mirror_offset_m": 0.3, "mirror_size_m": [6, 6], "actuators": [
    {"arm_fixed_m": 2.0, "arm_moving_m": 2.0, "gamma0_deg": 90, "sign": 1, "length_at_zero_stroke_m": 0.2,
     "stroke_range_mm": [-200, 3900]},
    {"arm_fixed_m": 1.5, "arm_moving_m": 1.2, "gamma0_deg": 130, "sign": -1, "length_at_zero_stroke_m": 0.5,
     "stroke_range_mm": [-200, 2200]}]}
"""An azimuth-elevation drive whose strokes reach every pointing a south field needs."""


def mirror_south(data):
    """The demo field reflected to the south of the tower (normals face north: azimuth near 0)."""
    for h in data["heliostats"]:
        e, n, u = h["position_enu_m"]
        h["position_enu_m"] = [e, -n, u]
    for t in data["targets"]:
        e, n, u = t["center_enu_m"]
        t["center_enu_m"] = [e, -n, u]
        t["normal_enu"] = [0.0, -1.0, 0.0]
        t["standby_offset_m"] = [-t["standby_offset_m"][0], 0.0]
    for c in data["cameras"]:
        e, n, u = c["position_enu_m"]
        c["position_enu_m"] = [e, -n, u]
    return data
