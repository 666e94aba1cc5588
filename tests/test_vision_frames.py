"""vision.frames: decoding real PNG/JPEG files, and every broken input becomes a MeasurementError."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helicalib.errors import MeasurementError
from helicalib.vision.frames import decode_frame, encode_png, read_frame, write_png


def _gray(h=48, w=64, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (h, w), dtype=np.uint8)


def test_png_round_trip_through_a_real_file(tmp_path):
    g = _gray()
    path = write_png(tmp_path / "f.png", g)
    assert path.read_bytes().startswith(b"\x89PNG")
    back = read_frame(path, expected_shape=(48, 64))
    assert back.dtype == np.uint8 and np.array_equal(back, g)


def test_colour_and_16_bit_png_become_8_bit_gray(tmp_path):
    g = _gray()
    bgr = np.dstack([g, g, g])
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    assert np.array_equal(read_frame(tmp_path / "c.png"), g)
    cv2.imwrite(str(tmp_path / "w.png"), g.astype(np.uint16) * 257)
    assert np.array_equal(read_frame(tmp_path / "w.png"), g)


def test_jpeg_is_read(tmp_path):
    g = np.full((40, 60), 128, np.uint8)
    cv2.imwrite(str(tmp_path / "f.jpg"), g)
    back = read_frame(tmp_path / "f.jpg")
    assert back.shape == (40, 60) and abs(int(back.mean()) - 128) <= 1


@pytest.mark.parametrize("cut", [1, 10, 100, 0.5])
def test_truncated_png_is_a_measurement_error(tmp_path, cut):
    data = encode_png(_gray())
    n = int(len(data) * cut) if isinstance(cut, float) else cut
    (tmp_path / "t.png").write_bytes(data[:n])
    with pytest.raises(MeasurementError, match="t.png"):
        read_frame(tmp_path / "t.png")


def test_truncated_jpeg_empty_garbage_missing_and_wrong_size(tmp_path):
    ok, buf = cv2.imencode(".jpg", _gray())
    with pytest.raises(MeasurementError, match="truncated JPEG"):
        decode_frame(buf.tobytes()[: len(buf) // 2])
    with pytest.raises(MeasurementError, match="empty"):
        decode_frame(b"")
    with pytest.raises(MeasurementError, match="not a PNG or JPEG"):
        decode_frame(b"<html>502 Bad Gateway</html>")
    with pytest.raises(MeasurementError, match="not found"):
        read_frame(tmp_path / "missing.png")
    with pytest.raises(MeasurementError, match="wrong size 64×48 px, expected 1280×1024"):
        decode_frame(encode_png(_gray()), expected_shape=(1024, 1280))


def test_png_with_corrupt_body_is_a_measurement_error():
    data = bytearray(encode_png(_gray(seed=3)))
    data[60:200] = bytes(140)  # zero the compressed stream but keep the IEND trailer
    with pytest.raises(MeasurementError):
        decode_frame(bytes(data))


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300), st.sampled_from([b"", b"\x89PNG\r\n\x1a\n", b"\xff\xd8"]))
def test_any_bytes_give_an_image_or_a_measurement_error(body, head):
    try:
        g = decode_frame(head + body)
    except MeasurementError:
        return
    assert g.dtype == np.uint8 and g.ndim == 2
