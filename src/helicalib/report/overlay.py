"""The before/after frames of a heliostat's latest visit with what the vision saw drawn on them.

The stored frames are read back and measured again with :func:`helicalib.vision.marks.find_marks`
and :func:`helicalib.vision.spot.measure_spot` (the same functions the visit used, so the drawing
is the measurement): the four L marks and their corners (green), the board centre (cyan cross), the
annex A window (yellow square) and the spot centre (red cross). The centre stored in the database
is drawn as a magenta circle; the two agree unless the frames were measured with other settings.
Without the field config only the stored centre can be drawn. Both are cropped to the board (when
its marks are found), put side by side and scaled to ``width_px``; drawing uses OpenCV only (a few ms per heliostat).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

GREEN, CYAN, YELLOW, RED, MAGENTA = (60, 200, 60), (230, 220, 0), (0, 220, 240), (40, 40, 235), (220, 60, 220)


def _cross(img, xy, colour, size, thick):
    import cv2

    x, y = int(round(xy[0])), int(round(xy[1]))
    cv2.line(img, (x - size, y), (x + size, y), colour, thick, cv2.LINE_AA)
    cv2.line(img, (x, y - size), (x, y + size), colour, thick, cv2.LINE_AA)


def _poly(img, pts, colour, thick, closed=True):
    import cv2

    p = np.asarray(pts, dtype=float)
    if p.size and np.all(np.isfinite(p)):
        cv2.polylines(img, [np.round(p).astype(np.int32).reshape(-1, 1, 2)], closed, colour, thick, cv2.LINE_AA)


def measure(before, afters, target, camera, method: str = "grlm-centroid"):
    """(MarksResult or None, SpotResult or None) of stored frames; None where it cannot be measured."""
    from helicalib.vision.marks import find_marks
    from helicalib.vision.spot import measure_spot

    marks = find_marks(before, target, camera)
    spot = measure_spot(before, afters, target, camera, method=method, marks=marks) if marks.found else None
    return marks, spot


def crop_box(shape: tuple[int, int], marks, margin: float = 0.25) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) [px]: the board (its marks' corners) with ``margin`` of its size around, or the whole frame."""
    h, w = shape[:2]
    if marks is None or not marks.found or not np.all(np.isfinite(marks.corners_px)):
        return 0, 0, w, h
    lo, hi = marks.corners_px.min(axis=0), marks.corners_px.max(axis=0)
    pad = margin * (hi - lo)
    x0, y0 = np.maximum(np.floor(lo - pad), 0).astype(int)
    x1, y1 = np.minimum(np.ceil(hi + pad), [w, h]).astype(int)
    return (int(x0), int(y0), int(x1), int(y1)) if x1 - x0 > 16 and y1 - y0 > 16 else (0, 0, w, h)


def draw(gray: np.ndarray, marks, spot, stored_px, box, scale: float, label: str) -> np.ndarray:
    """A BGR copy of ``gray[box]`` resized by ``scale`` with the marks, window and centres drawn."""
    import cv2

    x0, y0, x1, y1 = box
    img = cv2.resize(gray[y0:y1, x0:x1], None, fx=scale, fy=scale,
                     interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    off = np.array([x0, y0], dtype=float)

    def px(p):
        return (np.asarray(p, dtype=float) - off) * scale

    thick = 2
    if marks is not None and marks.found:
        for k in range(4):
            _poly(img, px(marks.corners_px.reshape(4, 6, 2)[k]), GREEN, thick)
        _cross(img, px(marks.center_px), CYAN, 14, thick)
    if spot is not None:
        if spot.window_px is not None:
            _poly(img, px(spot.window_px), YELLOW, thick)
        if spot.spot_center_px is not None:
            _cross(img, px(spot.spot_center_px), RED, 12, thick)
    if stored_px is not None:
        c = px(stored_px)
        cv2.circle(img, (int(round(c[0])), int(round(c[1]))), 9, MAGENTA, 1, cv2.LINE_AA)
    cv2.rectangle(img, (0, 0), (img.shape[1], 24), (0, 0, 0), -1)
    cv2.putText(img, label, (6, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def overlay_latest(images_dir: Path, latest: dict, cfg, out_path: Path, width_px: int = 1200) -> dict:
    """Write the side-by-side before/after overlay of ``latest`` (:func:`sheets.latest_frame_observation`).

    Returns what was drawn, for the sheet: ``{"png": path or None, "note": str, "remeasured": {...} or None}``.
    """
    import cv2

    from helicalib.errors import MeasurementError
    from helicalib.vision.frames import read_frame

    try:
        before = read_frame(Path(images_dir) / latest["before"])
        afters = [read_frame(Path(images_dir) / p) for p in latest["after"]]
    except (MeasurementError, OSError) as err:
        return {"png": None, "note": f"the stored frames could not be read ({err})", "remeasured": None}
    marks = spot = None
    note = ""
    if cfg is not None:
        try:
            target = cfg.target(latest["target_id"])
            cams = cfg.cameras_for(target.id)
            method = cfg.calibration.spot_method
            marks, spot = measure(before, afters, target, cams[0] if cams else None, method)
            if not marks.found:
                note = f"marks not found again: {marks.message}"
            elif spot is not None and not spot.valid:
                note = f"spot measured again: {spot.reason} — {spot.message}"
        except Exception as err:  # noqa: BLE001 - a drawing must never stop the report
            note = f"the frames could not be measured again ({type(err).__name__}: {err})"
    else:
        note = "no field config: only the stored spot centre is drawn"
    box = crop_box(before.shape, marks)
    scale = min(2.0, (width_px / 2) / (box[2] - box[0]))
    left = draw(before, marks, None, None, box, scale, f"before  (visit {latest['visit_id']})")
    right = draw(afters[-1], marks, spot, latest["spot_px"], box, scale,
                 f"after, placement {latest['iteration']}: {latest['reason']}"
                 + (f", {latest['error_mrad']:.2f} mrad" if latest["error_mrad"] is not None else ""))
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    gap = np.full((left.shape[0], 6, 3), 255, np.uint8)
    if not cv2.imwrite(str(out_path), np.hstack([left, gap, right]), [cv2.IMWRITE_PNG_COMPRESSION, 1]):
        return {"png": None, "note": f"could not write {out_path}", "remeasured": None}
    remeasured = None
    if spot is not None:
        remeasured = {"valid": spot.valid, "reason": spot.reason,
                      "spot_center_px": None if spot.spot_center_px is None else [float(x) for x in spot.spot_center_px],
                      "offset_m": None if spot.offset_m is None else [float(x) for x in spot.offset_m]}
    return {"png": out_path, "note": note, "remeasured": remeasured}
