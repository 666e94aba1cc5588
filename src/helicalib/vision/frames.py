"""Frames: encoded PNG/JPEG bytes or files → 8-bit grayscale arrays, and back.

A camera answers with an 8-bit grayscale PNG (JPEG may be met in the field). Anything else a
broken camera or a broken disk can produce (empty body, truncated file, colour or 16-bit frame,
wrong size) is turned into a :class:`~helicalib.errors.MeasurementError` whose message says what
is wrong, never a traceback from the decoder.

The decoding core (:func:`decode_frame`, :func:`as_gray_u8`) is pure; :func:`read_frame` and
:func:`write_png` are the thin file wrappers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from helicalib.errors import MeasurementError

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"
_JPEG_MAGIC = b"\xff\xd8"
_JPEG_END = b"\xff\xd9"


def sniff_format(data: bytes) -> str | None:
    """``"png"``, ``"jpeg"`` or None, from the first bytes of an encoded frame."""
    if data.startswith(_PNG_MAGIC):
        return "png"
    if data.startswith(_JPEG_MAGIC):
        return "jpeg"
    return None


def as_gray_u8(image: np.ndarray, what: str = "frame") -> np.ndarray:
    """Check or convert an image array to 8-bit grayscale, shape (H, W).

    Colour frames (H, W, 3|4) are converted with OpenCV's luma weights (BGR order), 16-bit
    frames are scaled by 1/257. Raises :class:`MeasurementError` for anything else.
    """
    import cv2

    a = np.asarray(image)
    if a.size == 0:
        raise MeasurementError(f"{what}: empty image")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY if a.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if a.ndim != 2:
        raise MeasurementError(f"{what}: expected a grayscale image (H, W), got shape {a.shape}")
    if a.dtype == np.uint16:
        a = (a.astype(np.uint32) // 257).astype(np.uint8)
    elif a.dtype == np.bool_:
        a = a.astype(np.uint8) * 255
    elif a.dtype != np.uint8:
        if not np.issubdtype(a.dtype, np.number) or not np.all(np.isfinite(a)):
            raise MeasurementError(f"{what}: pixel values are not finite numbers ({a.dtype})")
        if a.min() < 0 or a.max() > 255:
            raise MeasurementError(f"{what}: {a.dtype} pixel values outside 0..255")
        a = np.rint(a).astype(np.uint8)
    if min(a.shape) < 8:
        raise MeasurementError(f"{what}: image of {a.shape[1]}×{a.shape[0]} px is too small")
    return np.ascontiguousarray(a)


def check_shape(gray: np.ndarray, expected_shape: tuple[int, int] | None, what: str = "frame") -> None:
    """Raise :class:`MeasurementError` when ``gray.shape`` (H, W) is not ``expected_shape`` (H, W)."""
    if expected_shape is not None and tuple(gray.shape[:2]) != tuple(expected_shape):
        h, w = expected_shape
        raise MeasurementError(
            f"{what}: wrong size {gray.shape[1]}×{gray.shape[0]} px, expected {w}×{h} px"
        )


def decode_frame(data: bytes, expected_shape: tuple[int, int] | None = None, what: str = "frame") -> np.ndarray:
    """Decode an encoded PNG or JPEG frame to 8-bit grayscale.

    Parameters
    ----------
    data : bytes
        The encoded frame (an HTTP body or a file's content).
    expected_shape : (int, int), optional
        (height, width) [px] the frame must have.
    what : str
        Name of the frame in error messages.

    Returns
    -------
    numpy.ndarray
        uint8, shape (H, W).

    Raises
    ------
    MeasurementError
        Empty, unknown-format, truncated or undecodable data, or a frame of the wrong size.
    """
    import cv2

    if data is None or len(data) == 0:
        raise MeasurementError(f"{what}: empty data (0 bytes)")
    data = bytes(data)
    fmt = sniff_format(data)
    if fmt is None:
        raise MeasurementError(f"{what}: not a PNG or JPEG image (starts with {data[:8]!r})")
    if fmt == "png" and _PNG_END not in data[-64:]:
        raise MeasurementError(f"{what}: truncated PNG ({len(data)} bytes, no IEND chunk)")
    if fmt == "jpeg" and _JPEG_END not in data[-16:]:
        raise MeasurementError(f"{what}: truncated JPEG ({len(data)} bytes, no end-of-image marker)")
    buf = np.frombuffer(data, dtype=np.uint8)
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:  # pragma: no cover - OpenCV usually returns None instead
        raise MeasurementError(f"{what}: cannot decode {fmt.upper()} ({str(exc).strip()[:80]})") from None
    if img is None:
        raise MeasurementError(f"{what}: cannot decode {fmt.upper()} ({len(data)} bytes, corrupt data)")
    gray = as_gray_u8(img, what)
    check_shape(gray, expected_shape, what)
    return gray


def read_frame(path: str | Path, expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a PNG/JPEG file as uint8 grayscale (H, W); :class:`MeasurementError` if unusable."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise MeasurementError(f"{p}: file not found") from None
    except OSError as exc:
        raise MeasurementError(f"{p}: cannot read ({exc.strerror or exc})") from None
    return decode_frame(data, expected_shape, what=str(p))


def encode_png(gray: np.ndarray, compression: int = 1) -> bytes:
    """Encode a uint8 grayscale image (H, W) as PNG bytes (fast compression by default)."""
    import cv2

    g = as_gray_u8(gray, "image to encode")
    ok, buf = cv2.imencode(".png", g, [cv2.IMWRITE_PNG_COMPRESSION, int(compression)])
    if not ok:  # pragma: no cover
        raise MeasurementError("cannot encode PNG")
    return buf.tobytes()


def write_png(path: str | Path, gray: np.ndarray, compression: int = 1) -> Path:
    """Write a uint8 grayscale (H, W) or BGR (H, W, 3) image as PNG; returns the path."""
    import cv2

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    img = np.asarray(gray)
    if not (img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8):
        img = as_gray_u8(img, str(p))
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, int(compression)])
    if not ok:  # pragma: no cover
        raise MeasurementError(f"{p}: cannot encode PNG")
    p.write_bytes(buf.tobytes())
    return p
