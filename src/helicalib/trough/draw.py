"""Draw the theoretical overlay (and detected edges with verdicts) over a photo — pure, returns pixels."""

from __future__ import annotations

import cv2
import numpy as np

from helicalib.trough.measure import Detection, TiltEstimate
from helicalib.trough.overlay import Overlay, v_at_u

THEORY_BGR = (0, 200, 0)
FACET_BGR = (200, 120, 40)
DETECTED_BGR = (0, 0, 255)
OK_BGR = (0, 160, 0)
ADJUST_BGR = (0, 0, 230)
_SHIFT = 4  # fixed-point bits for sub-pixel drawing


def _pt(uv) -> tuple[int, int]:
    return int(round(uv[0] * (1 << _SHIFT))), int(round(uv[1] * (1 << _SHIFT)))


def _line(img, seg, colour, thickness=1):
    if np.all(np.isfinite(seg)):
        cv2.line(img, _pt(seg[0]), _pt(seg[1]), colour, thickness, cv2.LINE_AA, _SHIFT)


def draw_overlay(overlay: Overlay, image_size_px: tuple[int, int], photo: np.ndarray | None = None,
                 detection: Detection | None = None, estimate: TiltEstimate | None = None) -> np.ndarray:
    """The overlay picture: facet outlines, theoretical edges, detected edges and verdicts.

    Parameters
    ----------
    overlay : Overlay
    image_size_px : (int, int)
        ``(width, height)`` [px].
    photo : ndarray, shape (height, width) or (height, width, 3), optional
        The photo to draw on (grey or BGR); a grey canvas if omitted.
    detection, estimate : optional
        Detected edges and tilt verdicts to mark.

    Returns
    -------
    ndarray of uint8, shape (height, width, 3)
        BGR picture.
    """
    w, h = image_size_px
    if photo is None:
        img = np.full((h, w, 3), 110, np.uint8)
    else:
        img = np.asarray(photo)
        img = cv2.cvtColor(img.astype(np.uint8), cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.astype(np.uint8).copy()
    scale = max(0.35, min(w, h) / 1400.0)
    thick = max(1, int(round(min(w, h) / 800)))
    for i in range(overlay.found.shape[0]):
        _line(img, overlay.strip_top_uv_px[i], FACET_BGR, 1)
        _line(img, overlay.strip_bottom_uv_px[i], FACET_BGR, 1)
        if not overlay.found[i]:
            continue
        _line(img, overlay.lower_uv_px[i], THEORY_BGR, thick)
        _line(img, overlay.upper_uv_px[i], THEORY_BGR, thick)
    if detection is not None:
        u_range = overlay.u_range_px()
        for i in np.flatnonzero(np.isfinite(detection.u_px)):
            lo, hi = u_range[i]
            for seg, off in ((overlay.lower_uv_px, detection.lower_offset_px), (overlay.upper_uv_px, detection.upper_offset_px)):
                off = off[i]
                if not np.isfinite(off):
                    continue
                us = np.array([lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo)])
                vs = v_at_u(seg[i:i + 1], us[None, :])[0] + off
                _line(img, np.stack([us, vs], axis=1), DETECTED_BGR, thick)
    if estimate is not None:
        for i, status in enumerate(estimate.status):
            if status == "not_visible":
                continue
            seg = overlay.upper_uv_px[i]
            if not np.all(np.isfinite(seg)):
                continue
            tilt = estimate.tilt_mrad[i]
            text = f"{overlay.layout.ids[i]} {tilt:+.2f} mrad" if np.isfinite(tilt) else f"{overlay.layout.ids[i]} {status}"
            colour = OK_BGR if status == "ok" else ADJUST_BGR
            u0 = int(max(2, min(seg[:, 0].min() + 4, w - 200 * scale)))
            v0 = int(max(14, seg[:, 1].min() - 8 * scale))
            cv2.putText(img, text, (u0, v0), cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, colour, thick, cv2.LINE_AA)
    return img
