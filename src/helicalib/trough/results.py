"""The overlay analysis as one call, and its plain-JSON form (pure: arrays in, dicts out)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helicalib.trough.camera import PinholeCamera
from helicalib.trough.config import Collector
from helicalib.trough.measure import Detection, TiltEstimate, detect_edges, estimate_tilts
from helicalib.trough.overlay import Overlay, edges_in_image, v_at_u


@dataclass(frozen=True)
class Analysis:
    """Theoretical overlay, and when a photo was given, detection and tilt estimates."""

    collector: Collector
    camera: PinholeCamera
    overlay: Overlay
    detection: Detection | None = None
    estimate: TiltEstimate | None = None


def analyse(collector: Collector, camera: PinholeCamera, photo: np.ndarray | None = None) -> Analysis:
    """Compute the theoretical overlay and, given a grey ``photo`` (height, width), the tilts."""
    layout = collector.facets()
    overlay = edges_in_image(collector, layout, camera)
    if photo is None:
        return Analysis(collector, camera, overlay)
    detection = detect_edges(photo, overlay, camera)
    estimate = estimate_tilts(collector, overlay, camera, detection)
    return Analysis(collector, camera, overlay, detection, estimate)


def _num(x, digits: int = 4):
    x = float(x)
    return round(x, digits) if np.isfinite(x) else None


def _seg(seg) -> list | None:
    return [[_num(p[0], 3), _num(p[1], 3)] for p in seg] if np.all(np.isfinite(seg)) else None


def to_json(a: Analysis) -> dict:
    """Plain JSON-ready dict: one entry per facet with theory, and detection/tilt when measured."""
    ov, lay = a.overlay, a.overlay.layout
    facets = []
    for i, fid in enumerate(lay.ids):
        item = {
            "id": fid, "row": int(lay.row[i]), "column": int(lay.column[i]),
            "y_range_mm": [_num(lay.y_min_mm[i], 2), _num(lay.y_max_mm[i], 2)],
            "x_range_mm": [_num(lay.x_min_mm[i], 2), _num(lay.x_max_mm[i], 2)],
            "shows_tube": bool(ov.found[i]),
            "visible": bool(ov.visible[i]),
        }
        if ov.found[i]:
            item["theory"] = {
                "B_lower": {"y_mm": _num(ov.lower_yz_mm[i, 0], 3), "z_mm": _num(ov.lower_yz_mm[i, 1], 3),
                            "x_range_mm": [_num(v, 2) for v in ov.lower_x_mm[i]], "clipped": bool(ov.lower_clipped[i]),
                            "image_px": _seg(ov.lower_uv_px[i])},
                "E_upper": {"y_mm": _num(ov.upper_yz_mm[i, 0], 3), "z_mm": _num(ov.upper_yz_mm[i, 1], 3),
                            "x_range_mm": [_num(v, 2) for v in ov.upper_x_mm[i]], "clipped": bool(ov.upper_clipped[i]),
                            "image_px": _seg(ov.upper_uv_px[i])},
            }
        d, e = a.detection, a.estimate
        if d is not None and e is not None and e.status[i] != "not_visible":
            u = d.u_px[i]
            item["measured"] = {
                "u_px": _num(u, 2),
                "B_lower": {"v_px": _num(d.lower_v_px[i], 3), "offset_px": _num(d.lower_offset_px[i], 3),
                            "theory_v_px": _num(v_at_u(ov.lower_uv_px[i:i + 1], np.array([u]))[0], 3) if np.isfinite(u) else None},
                "E_upper": {"v_px": _num(d.upper_v_px[i], 3), "offset_px": _num(d.upper_offset_px[i], 3),
                            "theory_v_px": _num(v_at_u(ov.upper_uv_px[i:i + 1], np.array([u]))[0], 3) if np.isfinite(u) else None},
                "columns_used": int(d.columns_used[i]),
            }
            tilt = e.tilt_mrad[i]
            item["tilt"] = {
                "tilt_mrad": _num(tilt), "from_B_mrad": _num(e.lower_tilt_mrad[i]), "from_E_mrad": _num(e.upper_tilt_mrad[i]),
                "spread_mrad": _num(e.spread_mrad[i]),
                "direction": (None if not np.isfinite(tilt) else
                              "upper edge towards the focal line" if tilt > 0 else "upper edge away from the focal line"),
                "upper_edge_shift_mm": _num(e.upper_edge_shift_mm[i], 2),
                "verdict": e.status[i],
            }
        facets.append(item)
    c = a.collector
    return {
        "method": "theoretical overlay photographic method (Ren et al. 2014)",
        "frame": "O-XYZ: vertex origin, Z optical axis, Y across the aperture, X along the collector; mm",
        "camera_position_mm": [float(v) for v in a.camera.position_mm],
        "image_size_px": list(a.camera.image_size_px),
        "focal_length_mm": c.focal_length_mm, "tube_radius_mm": c.tube_radius_mm,
        "tilt_tolerance_mrad": c.tilt_tolerance_mrad,
        "tilt_sign": "positive = rotation about +X (right hand): the facet's upper edge moves towards the focal line",
        "measured": a.detection is not None,
        "facets": facets,
    }
