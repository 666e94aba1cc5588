"""Draw a spot measurement on its frame: marks, board outline, annex A window, spot and target centres."""

from __future__ import annotations

import numpy as np

from helicalib.config import Target
from helicalib.vision.homography import board_to_image

GREEN, RED, CYAN, YELLOW, MAGENTA = (0, 200, 0), (0, 0, 255), (255, 200, 0), (0, 220, 255), (255, 0, 255)


def draw_overlay(gray: np.ndarray, result, target: Target) -> np.ndarray:
    """A BGR uint8 image (H, W, 3): the frame with the measurement drawn on it.

    Marks corners or dot centres (green), board outline (cyan), the square window (yellow), the target centre
    (magenta cross) and the spot centre (red cross), and a status line.
    """
    import cv2

    img = cv2.cvtColor(np.asarray(gray, dtype=np.uint8), cv2.COLOR_GRAY2BGR)
    shift = 4  # sub-pixel drawing: coordinates × 16
    scale = 1 << shift

    def pts(a):
        return np.rint(np.asarray(a, dtype=float) * scale).astype(np.int32)

    def cross(c, colour, size=12):
        x, y = pts(c)
        s = size * scale
        cv2.line(img, (x - s, y), (x + s, y), colour, 2, cv2.LINE_AA, shift)
        cv2.line(img, (x, y - s), (x, y + s), colour, 2, cv2.LINE_AA, shift)

    marks = result.marks
    if marks is not None and np.all(np.isfinite(marks.homography)):
        for c in marks.corners_px if marks.dots_px is None else marks.dots_px:  # L corners or dot centres
            if np.all(np.isfinite(c)):
                cv2.circle(img, tuple(pts(c)), 3 * scale, GREEN, 1, cv2.LINE_AA, shift)
        w, h = target.size_m[0] / 2, target.size_m[1] / 2
        t = np.linspace(-1, 1, 21)
        outline = np.concatenate([np.column_stack([t * w, np.full_like(t, h)]),
                                  np.column_stack([np.full_like(t, w), -t * h]),
                                  np.column_stack([-t * w, np.full_like(t, -h)]),
                                  np.column_stack([np.full_like(t, -w), t * h])])
        cv2.polylines(img, [pts(board_to_image(marks, outline)).reshape(-1, 1, 2)], True, CYAN, 1, cv2.LINE_AA, shift)
        cross(marks.center_px, MAGENTA)
    if result.window_px is not None:
        cv2.polylines(img, [pts(result.window_px).reshape(-1, 1, 2)], True, YELLOW, 1, cv2.LINE_AA, shift)
    if result.spot_center_px is not None:
        cross(result.spot_center_px, RED)
    text = "valid" if result.valid else f"invalid: {result.reason}"
    if result.offset_m is not None:
        text += f"  u {result.offset_m[0]:+.3f} m  v {result.offset_m[1]:+.3f} m"
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.8, 1)
    cv2.rectangle(img, (4, 4), (16 + tw, 36), (0, 0, 0), -1)
    cv2.putText(img, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 1, cv2.LINE_AA)
    return img
