"""The numpy-only PNG codec, checked against OpenCV and Pillow (test-only dependencies)."""
from __future__ import annotations

import io
import struct
import zlib

import cv2
import numpy as np
import pytest
from PIL import Image

from reglib_client import decode_png, encode_png


def _rgb_to_bgr(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return image
    order = [2, 1, 0] if image.shape[2] == 3 else [2, 1, 0, 3]
    return np.ascontiguousarray(image[:, :, order])


@pytest.mark.parametrize(("shape", "dtype"), [((17, 23), np.uint8), ((17, 23, 3), np.uint8), ((9, 5, 4), np.uint8),
                                              ((31, 40), np.uint16), ((8, 7, 3), np.uint16), ((1, 1), np.uint8)])
def test_encode_is_read_back_exactly_by_opencv(shape: tuple[int, ...], dtype: type) -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    decoded = cv2.imdecode(np.frombuffer(encode_png(image), np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded.dtype == dtype
    np.testing.assert_array_equal(decoded, _rgb_to_bgr(image))


@pytest.mark.parametrize(("shape", "dtype"), [((17, 23), np.uint8), ((33, 21, 3), np.uint8), ((9, 5, 4), np.uint8),
                                              ((31, 40), np.uint16), ((8, 7, 3), np.uint16)])
def test_decode_reads_opencv_output(shape: tuple[int, ...], dtype: type) -> None:
    rng = np.random.default_rng(1)
    image = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    ok, encoded = cv2.imencode(".png", _rgb_to_bgr(image))
    assert ok
    decoded = decode_png(encoded.tobytes())
    assert decoded.dtype == dtype
    np.testing.assert_array_equal(decoded, image)


def _filter_rows(raw: np.ndarray, kind: int, bpp: int) -> np.ndarray:
    """Reference PNG filtering of (H, stride) uint8 rows with one filter type for all rows."""
    a = raw.astype(np.int32)
    left = np.zeros_like(a)
    left[:, bpp:] = a[:, :-bpp]
    up = np.zeros_like(a)
    up[1:] = a[:-1]
    upleft = np.zeros_like(a)
    upleft[1:, bpp:] = a[:-1, :-bpp]
    if kind == 0:
        pred = np.zeros_like(a)
    elif kind == 1:
        pred = left
    elif kind == 2:
        pred = up
    elif kind == 3:
        pred = (left + up) // 2
    else:
        p = left + up - upleft
        pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
        pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
    return ((a - pred) % 256).astype(np.uint8)


def _png(width: int, height: int, depth: int, colour: int, idat: bytes, extra: bytes = b"") -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    header = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    body = chunk(b"IHDR", header) + extra + chunk(b"IDAT", zlib.compress(idat)) + chunk(b"IEND", b"")
    return b"\x89PNG\r\n\x1a\n" + body


@pytest.mark.parametrize("kind", [0, 1, 2, 3, 4])
@pytest.mark.parametrize("channels", [1, 3])
def test_decode_every_row_filter(kind: int, channels: int) -> None:
    rng = np.random.default_rng(kind)
    image = rng.integers(0, 256, (6, 11, channels)).astype(np.uint8)
    rows = image.reshape(6, -1)
    filtered = _filter_rows(rows, kind, channels)
    idat = np.concatenate([np.full((6, 1), kind, np.uint8), filtered], axis=1).tobytes()
    decoded = decode_png(_png(11, 6, 8, 0 if channels == 1 else 2, idat))
    np.testing.assert_array_equal(decoded, image[:, :, 0] if channels == 1 else image)


def test_decode_palette_and_low_bit_depth_from_pillow() -> None:
    rng = np.random.default_rng(2)
    index = rng.integers(0, 7, (13, 9)).astype(np.uint8)
    palette = rng.integers(0, 256, (7, 3)).astype(np.uint8)
    picture = Image.fromarray(index, mode="P")
    picture.putpalette(palette.reshape(-1).tolist())
    buffer = io.BytesIO()
    picture.save(buffer, format="PNG", bits=4)
    np.testing.assert_array_equal(decode_png(buffer.getvalue()), palette[index])

    bits = rng.integers(0, 2, (5, 12)).astype(bool)
    buffer = io.BytesIO()
    Image.fromarray(bits).save(buffer, format="PNG")  # 1-bit grey
    np.testing.assert_array_equal(decode_png(buffer.getvalue()), bits.astype(np.uint8))


def test_decode_interlaced() -> None:
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (19, 13, 3)).astype(np.uint8)
    passes = ((0, 0, 8, 8), (0, 4, 8, 8), (4, 0, 8, 4), (0, 2, 4, 4), (2, 0, 4, 2), (0, 1, 2, 2), (1, 0, 2, 1))
    idat = b""
    for row0, col0, row_step, col_step in passes:
        sub = image[row0::row_step, col0::col_step]
        if sub.size:
            rows = sub.reshape(sub.shape[0], -1)
            idat += np.concatenate([np.full((len(rows), 1), 4, np.uint8), _filter_rows(rows, 4, 3)], 1).tobytes()
    data = bytearray(_png(13, 19, 8, 2, idat))
    data[8 + 8 + 12] = 1  # interlace method byte of IHDR ...
    crc = zlib.crc32(bytes(data[12:29]))  # ... and its CRC
    data[29:33] = struct.pack(">I", crc)
    np.testing.assert_array_equal(decode_png(bytes(data)), image)


def test_encode_integer_and_bool_arrays() -> None:
    small = np.arange(12, dtype=np.int64).reshape(3, 4)
    assert decode_png(encode_png(small)).dtype == np.uint8
    wide = small * 1000
    np.testing.assert_array_equal(decode_png(encode_png(wide)), wide.astype(np.uint16))
    mask = small % 2 == 0
    np.testing.assert_array_equal(decode_png(encode_png(mask)), mask.astype(np.uint8) * 255)
    np.testing.assert_array_equal(decode_png(encode_png(small[:, :, None])), small)


@pytest.mark.parametrize(("image", "message"), [
    (np.zeros((4, 4), np.float32), "dtype must be"),
    (np.zeros((4, 4, 2), np.uint8), "must have shape"),
    (np.zeros((0, 4), np.uint8), "at least one pixel"),
    (np.full((2, 2), -1, np.int32), "must lie in 0..65535"),
])
def test_encode_errors(image: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        encode_png(image)


def test_decode_errors() -> None:
    good = encode_png(np.zeros((3, 3), np.uint8))
    with pytest.raises(ValueError, match="not a PNG"):
        decode_png(b"GIF89a")
    corrupt = bytearray(good)
    corrupt[20] ^= 0xFF  # inside IHDR: its CRC no longer matches
    with pytest.raises(ValueError, match="bad CRC"):
        decode_png(bytes(corrupt))
    with pytest.raises(ValueError, match="truncated"):
        decode_png(good[:40])
