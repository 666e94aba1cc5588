"""Camera frames as PNG files beside the database, written atomically.

A frame is written to a temporary file in its final directory, flushed (and fsync'ed when
``durable``), then renamed into place: a reader never sees half a PNG, and a process killed
mid-write leaves at most a ``*.tmp`` file that the database's next owner removes
(:meth:`~helicalib.store.sqlite.Store.take_ownership`; readers never delete anything). The store
writes frames BEFORE the database row that points to them.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from helicalib.errors import MeasurementError
from helicalib.store.damage import os_write_error

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
JPEG_MAGIC = b"\xff\xd8\xff"
_SAFE = re.compile(r"[^A-Za-z0-9._-]+")


def safe_name(text: str) -> str:
    """A string made safe for a file name (heliostat ids may hold anything)."""
    return _SAFE.sub("_", str(text)).strip("._") or "x"


def to_png_bytes(frame: bytes | np.ndarray) -> bytes:
    """A frame as PNG bytes.

    Parameters
    ----------
    frame : bytes or ndarray
        PNG bytes (kept as they are), JPEG bytes (decoded and re-encoded losslessly as PNG, so the
        stored frame is the very image that was measured), or an 8-bit image array, shape (H, W)
        or (H, W, 3).

    Raises
    ------
    MeasurementError
        The bytes are neither PNG nor a decodable JPEG, or the array is not an 8/16-bit image.
    """
    import cv2

    if isinstance(frame, (bytes, bytearray, memoryview)):
        data = bytes(frame)
        if data.startswith(PNG_MAGIC):
            return data
        if data.startswith(JPEG_MAGIC):
            image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise MeasurementError("frame: JPEG bytes could not be decoded")
            frame = image
        else:
            raise MeasurementError(f"frame: neither PNG nor JPEG ({len(data)} bytes)")
    image = np.asarray(frame)
    if image.dtype not in (np.uint8, np.uint16) or image.ndim not in (2, 3):
        raise MeasurementError(f"frame: expected an 8- or 16-bit image array, got {image.dtype} {image.shape}")
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise MeasurementError("frame: PNG encoding failed")
    return buf.tobytes()


def write_atomic(path: Path, data: bytes, *, durable: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (temporary file + rename).

    Raises :class:`~helicalib.errors.StorageError` naming the file when it cannot be written (full
    disk, read-only folder); no temporary file is left behind.

    Parameters
    ----------
    path : Path
        Final file path; its directory is created.
    data : bytes
        File content.
    durable : bool
        fsync the file and its directory, so the frame survives a power cut, not only a killed process.
    """
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:  # full disk, read-only folder, a path through a file
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        raise os_write_error(path, exc, "write the frame") from None
    if durable and hasattr(os, "O_DIRECTORY"):
        fd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def frame_relpath(campaign_id: int, heliostat_id: str, visit_id: int | None, iteration: int, kind: str) -> Path:
    """Relative path of a frame: ``c<campaign>/<heliostat>/v<visit>_i<iteration>_<kind>.png``.

    Built only from the controller's own numbers (campaign, visit, iteration) and a sanitised
    heliostat id: never from what a device reports (a camera's capture time of 1e300 once made
    every name too long). The capture time is in the observation's row."""
    visit = "x" if visit_id is None else str(int(visit_id))
    return Path(f"c{int(campaign_id)}") / safe_name(heliostat_id)[:64] / f"v{visit}_i{int(iteration)}_{safe_name(kind)}.png"


def unique_path(images_dir: Path, rel: Path) -> Path:
    """``rel`` or, if that file exists already, ``rel`` with ``-1``, ``-2``, ... before the suffix."""
    candidate = rel
    n = 0
    while (images_dir / candidate).exists():
        n += 1
        candidate = rel.with_name(f"{rel.stem}-{n}{rel.suffix}")
    return candidate


def clean_temporary(images_dir: Path) -> int:
    """Remove ``.*.tmp`` files left by a killed writer; returns how many were removed."""
    if not images_dir.exists():
        return 0
    removed = 0
    for tmp in images_dir.rglob(".*.tmp"):
        try:
            tmp.unlink()
            removed += 1
        except OSError:
            pass
    return removed
