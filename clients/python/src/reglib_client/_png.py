"""A small PNG encoder and decoder on numpy and zlib only (no OpenCV, no Pillow).

Images are ``(H, W)`` grey, ``(H, W, 3)`` RGB or ``(H, W, 4)`` RGBA arrays of ``uint8`` or
``uint16``, indexed ``[row, col]``. The encoder writes non-interlaced PNG with filter 0 on every
row (zlib does the work); the decoder reads what other encoders write: 8 and 16 bit grey,
grey+alpha, RGB and RGBA, palette images, every row filter, and Adam7 interlacing.
"""
from __future__ import annotations

import struct
import zlib

import numpy as np

__all__ = ["encode_png", "decode_png", "PNG_SIGNATURE"]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

# colour type -> channels
_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
# Adam7 passes: (row start, col start, row step, col step)
_ADAM7 = ((0, 0, 8, 8), (0, 4, 8, 8), (4, 0, 8, 4), (0, 2, 4, 4), (2, 0, 4, 2), (0, 1, 2, 2), (1, 0, 2, 1))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _as_pixels(image: np.ndarray) -> np.ndarray:
    """Pick the PNG sample type for ``image``: bool -> 0/255, integers -> uint8 or uint16 by range."""
    if image.dtype == np.bool_:
        return image.astype(np.uint8) * np.uint8(255)
    if image.dtype in (np.uint8, np.uint16):
        return image
    if np.issubdtype(image.dtype, np.integer):
        lo = int(image.min()) if image.size else 0
        hi = int(image.max()) if image.size else 0
        if lo < 0 or hi > 0xFFFF:
            raise ValueError(f"image values must lie in 0..65535 to be sent as PNG, got {lo}..{hi}")
        return image.astype(np.uint8 if hi <= 0xFF else np.uint16)
    raise ValueError(
        f"image dtype must be uint8, uint16, another integer type or bool, got {image.dtype}; "
        "convert floating-point images explicitly, e.g. (img * 255).round().astype(np.uint8)"
    )


def encode_png(image: np.ndarray, *, level: int = 6) -> bytes:
    """Encode ``image`` (H, W), (H, W, 1), (H, W, 3) RGB or (H, W, 4) RGBA as PNG bytes.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array, C in {1, 3, 4}
        Pixel values indexed ``[row, col]``. ``uint8`` and ``uint16`` are written as they are,
        other integer arrays as ``uint8`` (values up to 255) or ``uint16``; ``bool`` as 0/255.
        Colour arrays are taken as RGB(A), the numpy / Pillow / scikit-image order.
    level : int
        zlib compression level, 0..9.

    Returns
    -------
    bytes
        A complete PNG file.

    Raises
    ------
    ValueError
        For a shape, size or dtype that PNG cannot hold.
    """
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim == 2:
        colour_type = 0
    elif arr.ndim == 3 and arr.shape[2] in (3, 4):
        colour_type = 2 if arr.shape[2] == 3 else 6
    else:
        raise ValueError(f"image must have shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got {arr.shape}")
    height, width = arr.shape[:2]
    if height == 0 or width == 0:
        raise ValueError(f"image must have at least one pixel, got shape {arr.shape}")
    if height >= 2**31 or width >= 2**31:
        raise ValueError(f"image is too large for PNG, got shape {arr.shape}")
    pixels = _as_pixels(arr)
    bit_depth = 8 if pixels.dtype == np.uint8 else 16
    rows = np.ascontiguousarray(pixels.astype(">u2") if bit_depth == 16 else pixels).reshape(height, -1)
    rows = rows.view(np.uint8).reshape(height, -1)
    raw = np.empty((height, rows.shape[1] + 1), dtype=np.uint8)
    raw[:, 0] = 0  # filter type "None" on every row
    raw[:, 1:] = rows
    header = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    return (PNG_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(raw.tobytes(), level))
            + _chunk(b"IEND", b""))


# ---------------------------------------------------------------------------------------- decode
def _unfilter(data: memoryview, offset: int, height: int, stride: int, bpp: int) -> tuple[np.ndarray, int]:
    """Undo the per-row filters of one (sub)image; returns (height, stride) uint8 and the new offset."""
    out = np.zeros((height, stride), dtype=np.uint8)
    prior = np.zeros(stride, dtype=np.uint8)
    for row in range(height):
        if offset + 1 + stride > len(data):
            raise ValueError("PNG image data is truncated")
        kind = data[offset]
        line = np.frombuffer(data, dtype=np.uint8, count=stride, offset=offset + 1)
        offset += 1 + stride
        if kind == 0:
            cur = line.copy()
        elif kind == 1:  # Sub: running sum along the row, per byte position modulo bpp
            cur = np.zeros(stride + (-stride) % bpp, dtype=np.uint8)
            cur[:stride] = line
            cur = np.cumsum(cur.reshape(-1, bpp), axis=0, dtype=np.uint8).reshape(-1)[:stride]
        elif kind == 2:  # Up
            cur = line + prior
        elif kind in (3, 4):  # Average, Paeth: sequential along the row
            cur = _unfilter_sequential(kind, line.tolist(), prior.tolist(), bpp)
        else:
            raise ValueError(f"PNG row filter must be 0..4, got {kind}")
        out[row] = cur
        prior = out[row]
    return out, offset


def _unfilter_sequential(kind: int, line: list[int], prior: list[int], bpp: int) -> np.ndarray:
    cur = bytearray(len(line))
    for i, value in enumerate(line):
        left = cur[i - bpp] if i >= bpp else 0
        up = prior[i]
        if kind == 3:
            cur[i] = (value + ((left + up) >> 1)) & 0xFF
        else:
            upleft = prior[i - bpp] if i >= bpp else 0
            p = left + up - upleft
            pa, pb, pc = abs(p - left), abs(p - up), abs(p - upleft)
            pred = left if pa <= pb and pa <= pc else (up if pb <= pc else upleft)
            cur[i] = (value + pred) & 0xFF
    return np.frombuffer(bytes(cur), dtype=np.uint8)


def _samples(rows: np.ndarray, width: int, channels: int, bit_depth: int) -> np.ndarray:
    """Unpack filtered-out rows (h, stride) into (h, width, channels) samples."""
    height = rows.shape[0]
    if bit_depth == 16:
        return rows.view(">u2").astype(np.uint16).reshape(height, width, channels)
    if bit_depth == 8:
        return rows.reshape(height, width, channels)
    bits = np.unpackbits(rows, axis=1).reshape(height, -1, bit_depth)
    weights = (1 << np.arange(bit_depth - 1, -1, -1)).astype(np.uint8)
    values = (bits * weights).sum(axis=2, dtype=np.uint8)
    return values[:, : width * channels].reshape(height, width, channels)


def decode_png(data: bytes) -> np.ndarray:
    """Decode PNG ``data`` into an (H, W) grey, (H, W, 2) grey+alpha, (H, W, 3) RGB or (H, W, 4) RGBA array.

    Samples keep their depth: ``uint16`` for 16-bit files, ``uint8`` otherwise (1, 2 and 4-bit grey
    are returned as their sample values, not rescaled). Palette images are expanded to RGB, or to
    RGBA when the file has a ``tRNS`` chunk.

    Raises
    ------
    ValueError
        When ``data`` is not a well-formed PNG.
    """
    buf = memoryview(bytes(data))
    if bytes(buf[:8]) != PNG_SIGNATURE:
        raise ValueError("data is not a PNG file (bad signature)")
    pos = 8
    header: tuple[int, ...] | None = None
    idat: list[bytes] = []
    palette: np.ndarray | None = None
    trns: bytes | None = None
    while pos + 8 <= len(buf):
        (length,) = struct.unpack(">I", buf[pos:pos + 4])
        kind = bytes(buf[pos + 4:pos + 8])
        body = bytes(buf[pos + 8:pos + 8 + length])
        if len(body) != length or pos + 12 + length > len(buf):
            raise ValueError(f"PNG chunk {kind!r} is truncated")
        (crc,) = struct.unpack(">I", buf[pos + 8 + length:pos + 12 + length])
        if crc != zlib.crc32(kind + body) & 0xFFFFFFFF:
            raise ValueError(f"PNG chunk {kind!r} has a bad CRC")
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"PLTE":
            palette = np.frombuffer(body, dtype=np.uint8).reshape(-1, 3)
        elif kind == b"tRNS":
            trns = body
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if header is None:
        raise ValueError("PNG has no IHDR chunk")
    width, height, bit_depth, colour_type, compression, filter_method, interlace = header
    if colour_type not in _CHANNELS or compression != 0 or filter_method != 0 or interlace not in (0, 1):
        raise ValueError(f"PNG header is not supported: colour type {colour_type}, interlace {interlace}")
    if bit_depth not in (1, 2, 4, 8, 16) or (colour_type in (2, 4, 6) and bit_depth < 8):
        raise ValueError(f"PNG bit depth {bit_depth} is not valid for colour type {colour_type}")
    if width == 0 or height == 0:
        raise ValueError("PNG has zero width or height")
    try:
        raw = memoryview(zlib.decompress(b"".join(idat)))
    except zlib.error as exc:
        raise ValueError(f"PNG image data cannot be decompressed: {exc}") from None
    channels = _CHANNELS[colour_type]
    bits_per_pixel = channels * bit_depth
    bpp = max(1, bits_per_pixel // 8)
    dtype = np.uint16 if bit_depth == 16 else np.uint8
    image = np.zeros((height, width, channels), dtype=dtype)
    offset = 0
    passes = _ADAM7 if interlace else ((0, 0, 1, 1),)
    for row0, col0, row_step, col_step in passes:
        sub_h = (height - row0 + row_step - 1) // row_step if height > row0 else 0
        sub_w = (width - col0 + col_step - 1) // col_step if width > col0 else 0
        if sub_h == 0 or sub_w == 0:
            continue
        stride = (sub_w * bits_per_pixel + 7) // 8
        rows, offset = _unfilter(raw, offset, sub_h, stride, bpp)
        image[row0::row_step, col0::col_step] = _samples(rows, sub_w, channels, bit_depth)
    if colour_type == 3:
        if palette is None:
            raise ValueError("palette PNG has no PLTE chunk")
        index = image[:, :, 0]
        if int(index.max()) >= len(palette):
            raise ValueError("PNG palette index out of range")
        rgb = palette[index]
        if trns is None:
            return rgb
        alpha = np.full(len(palette), 255, dtype=np.uint8)
        alpha[: len(trns)] = np.frombuffer(trns, dtype=np.uint8)[: len(palette)]
        return np.concatenate([rgb, alpha[index][:, :, None]], axis=2)
    return image[:, :, 0] if channels == 1 else image
