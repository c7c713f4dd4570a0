"""Reading images safely, and encoding PNG, TIFF and BMP.

Images are returned as ``(H, W)`` or ``(H, W, C)`` arrays in the dtype the file holds (uint8,
uint16, int, float): every band is kept, colour in RGB order like scikit-image (a 4th channel,
alpha or near infrared, is the 4th band). TIFFs of four or more samples per pixel are read by
tifffile (scikit-image's own TIFF reader), since OpenCV reads some of them as grey or refuses
them; 2-D NIfTI, MetaImage and NRRD images by :mod:`reglib.io._medical`.
The pixel count is read from the file's header *before* anything is decoded, so a small file
that claims a huge image (a "decompression bomb") is refused without allocating it; a file
whose header gives no size is refused too. (OpenCV's own limit, the environment variable
``OPENCV_IO_MAX_IMAGE_PIXELS``, is read when OpenCV loads: a process that wants it, like the
service's workers, sets it before importing reglib.)
"""
from __future__ import annotations

import io as _io
import os
import struct
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .._validation import check_int
from ..errors import ImageTooLarge, InputError, UnsupportedFormat
from ._medical import MEDICAL_FORMATS, decode_medical, medical_format, medical_header

__all__ = ["DEFAULT_MAX_PIXELS", "ALLOWED_FORMATS", "read_image", "image_format", "image_size", "check_image_header",
           "encode_png", "encode_image", "IMAGE_OUT_SUFFIXES", "to_uint8"]

DEFAULT_MAX_PIXELS = 40_000_000
ALLOWED_FORMATS = ("png", "jpeg", "tiff", "bmp", "webp", *MEDICAL_FORMATS)
IMAGE_OUT_SUFFIXES = (".png", ".tif", ".tiff", ".bmp")  # lossless: label maps keep their values


def image_format(data: bytes) -> str | None:
    """Name the image format from the first bytes of ``data`` (its magic number).

    Returns one of ``"png", "jpeg", "tiff", "bmp", "webp", "nifti", "metaimage", "nrrd"`` (the
    allowed ones), the name of a recognized but not allowed format (``"gif", "jpeg2000", "pnm",
    "exr", "hdr", "ico"``), or None when the bytes are no image format known here.
    """
    medical = medical_format(data)
    if medical is not None:
        return medical
    head = bytes(data[:16])
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if head.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if head.startswith((b"II*\x00", b"MM\x00*")):
        return "tiff"
    if head.startswith(b"BM") and len(head) >= 14:
        return "bmp"
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        return "webp"
    if head.startswith((b"GIF87a", b"GIF89a")):
        return "gif"
    if head.startswith((b"\x00\x00\x00\x0cjP  ", b"\xff\x4f\xff\x51")):
        return "jpeg2000"
    if len(head) >= 2 and head[0:1] == b"P" and head[1:2] in b"1234567":
        return "pnm"
    if head.startswith(b"v/1\x01"):
        return "exr"
    if head.startswith(b"#?RADIANCE") or head.startswith(b"#?RGBE"):
        return "hdr"
    if head.startswith(b"\x00\x00\x01\x00"):
        return "ico"
    return None


def image_size(data: bytes) -> tuple[int, int] | None:
    """(W, H) of an encoded PNG, JPEG, BMP, WebP, TIFF, NIfTI, MetaImage or NRRD image, read from its header only.

    The common layouts are parsed here; others (e.g. a TIFF whose first directory lies far in
    the file) are read by Pillow's header parser, which decodes no pixels either. Returns None
    when neither can read the header (truncated, unusual).
    """
    size = _parsed_size(data)
    if size is None and image_format(data) in ALLOWED_FORMATS:
        size = _pillow_size(data)
    return size


def _pillow_size(data: bytes) -> tuple[int, int] | None:
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its own decompression-bomb warning: the limit is ours
            with Image.open(_io.BytesIO(data)) as im:
                w, h = im.size
    except Exception:  # noqa: BLE001 - any parse failure means "size unknown"
        return None
    return int(w), int(h)


def _parsed_size(data: bytes) -> tuple[int, int] | None:
    fmt = image_format(data)
    try:
        if fmt == "png":
            if len(data) < 24 or data[12:16] != b"IHDR":
                return None
            w, h = struct.unpack(">II", data[16:24])
            return int(w), int(h)
        if fmt == "jpeg":
            return _jpeg_size(data)
        if fmt == "bmp":
            if len(data) < 26:
                return None
            header_size = struct.unpack("<I", data[14:18])[0]
            if header_size == 12:  # OS/2 BITMAPCOREHEADER: 16-bit sizes
                w, h = struct.unpack("<HH", data[18:22])
            else:
                w, h = struct.unpack("<ii", data[18:26])
            return abs(int(w)), abs(int(h))
        if fmt == "webp":
            return _webp_size(data)
        if fmt == "tiff":
            return _tiff_size(data)
        if fmt in MEDICAL_FORMATS:
            header = medical_header(data, "image")
            return header.width, header.height
    except (struct.error, InputError):
        return None
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01,) or 0xD0 <= marker <= 0xD9:  # markers without a length
            i += 2
            continue
        length = struct.unpack(">H", data[i + 2:i + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            if i + 9 > n:
                return None
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return int(w), int(h)
        i += 2 + length
    return None


def _webp_size(data: bytes) -> tuple[int, int] | None:
    chunk = data[12:16]
    if chunk == b"VP8 " and len(data) >= 30:
        w, h = struct.unpack("<HH", data[26:30])
        return int(w & 0x3FFF), int(h & 0x3FFF)
    if chunk == b"VP8L" and len(data) >= 25:
        bits = struct.unpack("<I", data[21:25])[0]
        return int((bits & 0x3FFF) + 1), int(((bits >> 14) & 0x3FFF) + 1)
    if chunk == b"VP8X" and len(data) >= 30:
        w = int.from_bytes(data[24:27], "little") + 1
        h = int.from_bytes(data[27:30], "little") + 1
        return w, h
    return None


def _tiff_tags(data: bytes) -> dict[int, int]:
    """Width (256), height (257) and samples per pixel (277) of a TIFF's first directory, those found."""
    endian = "<" if data[:2] == b"II" else ">"
    offset = struct.unpack(endian + "I", data[4:8])[0]
    if offset + 2 > len(data):
        return {}
    count = struct.unpack(endian + "H", data[offset:offset + 2])[0]
    found: dict[int, int] = {}
    for k in range(count):
        entry = data[offset + 2 + 12 * k: offset + 14 + 12 * k]
        if len(entry) < 12:
            break
        tag, typ = struct.unpack(endian + "HH", entry[:4])
        if tag in (256, 257, 277):
            value = struct.unpack(endian + ("H" if typ == 3 else "I"), entry[8:10] if typ == 3 else entry[8:12])[0]
            found[tag] = int(value)
    return found


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    found = _tiff_tags(data)
    if 256 in found and 257 in found:
        return found[256], found[257]
    return None


def read_image(source: Any, *, max_pixels: int = DEFAULT_MAX_PIXELS, name: str = "image") -> np.ndarray:
    """Read an image from an array, a file path or encoded bytes, refusing bad input by name.

    Parameters
    ----------
    source : ndarray, str, os.PathLike or bytes
        An (H, W) or (H, W, C) array of any real dtype (C >= 3: the first three bands RGB); a path
        to a PNG, JPEG, TIFF, BMP, WebP, NIfTI (``.nii``, ``.nii.gz``), MetaImage (``.mha``, or
        ``.mhd`` with its data file beside it) or NRRD file holding one 2-D image; or the encoded
        bytes of one (a single file: the data inside).
    max_pixels : int
        Largest W * H accepted; for encoded input it is read from the header before decoding.
    name : str
        How the image is called in error messages (e.g. ``"image_a"``).

    Returns
    -------
    (H, W) or (H, W, C) ndarray
        Every band, in the file's (or array's) dtype; an (H, W, 1) array becomes (H, W). Arrays
        are returned without copying when nothing had to change (never modified in place).

    Raises
    ------
    ImageTooLarge
        More than ``max_pixels`` pixels.
    UnsupportedFormat
        Encoded in a recognized format that is not read here (GIF, JPEG 2000, ...).
    InputError
        Empty, undecodable, zero-size, NaN/inf-holding or wrongly shaped input; a 3-D volume (its
        size named); a missing file.
    MemoryError
        Decoding needs more memory than the process may have (an address-space cap, say): the
        image may be fine, so this is not an ``InputError``.
    """
    check_int("max_pixels", max_pixels)
    if isinstance(source, np.ndarray):
        return _check_array(source, max_pixels, name)
    if isinstance(source, (bytes, bytearray, memoryview)):
        return _decode(bytes(source), max_pixels, name)
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if not path.is_file():
            raise InputError(f"`{name}`: no such file: {path}")
        return _decode(path.read_bytes(), max_pixels, f"{name} ({path.name})", path.parent)
    raise InputError(f"`{name}` must be an image array, a path or encoded bytes, got {type(source).__name__}")


def _check_array(arr: np.ndarray, max_pixels: int, name: str) -> np.ndarray:
    if arr.dtype == bool:
        arr = arr.astype(np.uint8) * 255
    if arr.dtype.kind not in "uif":
        raise InputError(f"`{name}` must have a real numeric dtype, got {arr.dtype}")
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] == 0):
        raise InputError(f"`{name}` must have shape (H, W) or (H, W, C) (C bands), got {arr.shape}")
    h, w = arr.shape[:2]
    if h == 0 or w == 0:
        raise InputError(f"`{name}` is empty: shape {arr.shape}")
    if h * w > max_pixels:
        raise ImageTooLarge(f"`{name}` has {w}x{h} = {w * h} pixels, over the limit of {max_pixels}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise InputError(f"`{name}` holds NaN or inf values")
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    return arr


def check_image_header(data: bytes, *, max_pixels: int = DEFAULT_MAX_PIXELS,
                       allowed: tuple[str, ...] = ALLOWED_FORMATS, name: str = "image") -> tuple[str, int, int]:
    """Check encoded image bytes from their first bytes and header alone, before any decoding.

    Returns
    -------
    (format, width, height)

    Raises
    ------
    UnsupportedFormat
        A known image format not in ``allowed``.
    ImageTooLarge
        The header says more than ``max_pixels`` pixels.
    InputError
        Empty bytes, no image format known here, a header without a readable size, or a zero size;
        a medical image that is a 3-D volume (its size named) or of a layout not read here.
    """
    if len(data) == 0:
        raise InputError(f"`{name}` is empty (0 bytes)")
    fmt = image_format(data)
    if fmt is None:
        raise InputError(f"`{name}` cannot be decoded: not an image in a format known here (allowed: "
                         f"{', '.join(f.upper() for f in allowed)})")
    if fmt not in allowed:
        names = ", ".join(f.upper() for f in allowed)
        raise UnsupportedFormat(f"`{name}` is {fmt.upper()}; allowed formats are {names}")
    if fmt in MEDICAL_FORMATS:
        header = medical_header(data, f"`{name}`")  # its own words for a volume or an unread layout
        size: tuple[int, int] | None = (header.width, header.height)
    else:
        size = image_size(data)
    if size is None:
        # Without a size from the header the pixel limit cannot be checked before decoding.
        raise InputError(f"`{name}` cannot be decoded as {fmt.upper()}: its header is truncated or unreadable")
    w, h = size
    if w * h > max_pixels:
        raise ImageTooLarge(f"`{name}` is {w}x{h} = {w * h} pixels (from its header), over the limit of {max_pixels}")
    if w == 0 or h == 0:
        raise InputError(f"`{name}` is empty: its header says {w}x{h}")
    return fmt, w, h


def _imdecode(data: bytes, name: str) -> tuple[np.ndarray | None, str]:
    """OpenCV's decoding of ``data``, or None and OpenCV's last line of complaint. An allocation that fails is a
    ``MemoryError``: the memory at hand is short, and the image may well be right."""
    # OpenCV's warnings (e.g. on the extra samples of a 4-channel TIFF it wrote itself) would reach the
    # user's terminal for a file that reads fine; its errors still come through
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(min(level, cv2.utils.logging.LOG_LEVEL_ERROR))
    try:
        return cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED), ""
    except cv2.error as exc:
        detail = str(exc).strip().splitlines()[-1] if str(exc).strip() else ""
        if getattr(exc, "code", None) == cv2.Error.StsNoMem:
            raise MemoryError(f"decoding `{name}` needs more memory than this process may use: {detail}") from None
        return None, detail
    finally:
        cv2.utils.logging.setLogLevel(level)


def _decode(data: bytes, max_pixels: int, name: str, folder: Path | None = None) -> np.ndarray:
    fmt, w, h = check_image_header(data, max_pixels=max_pixels, name=name)
    if fmt in MEDICAL_FORMATS:
        return _check_array(decode_medical(data, f"`{name}`", folder), max_pixels, name)
    if fmt == "tiff" and _tiff_tags(data).get(277, 1) > 4:  # OpenCV reads at most 4
        return _check_array(_decode_tiff_bands(data, name), max_pixels, name)
    img, detail = _imdecode(data, name)
    if img is None and fmt == "tiff" and _tiff_tags(data).get(277, 1) not in (1, 3):
        return _check_array(_decode_tiff_bands(data, name), max_pixels, name)
    if img is None:
        pixel_limit = int(os.environ.get("OPENCV_IO_MAX_IMAGE_PIXELS", "0") or 0)
        if pixel_limit and w * h > pixel_limit:
            raise ImageTooLarge(f"`{name}` is {w}x{h} pixels, over OpenCV's decoding limit {pixel_limit} "
                                "(raise the environment variable OPENCV_IO_MAX_IMAGE_PIXELS before starting)")
        raise InputError(f"`{name}` cannot be decoded as {fmt.upper()} (corrupt or truncated) {detail}".rstrip())
    samples = _tiff_tags(data).get(277, 1) if fmt == "tiff" else None
    if samples is not None and samples != (1 if img.ndim == 2 else img.shape[2]):
        # OpenCV reads some TIFFs of 2 or 4+ samples as grey and refuses others: read every sample
        return _check_array(_decode_tiff_bands(data, name), max_pixels, name)
    if img.ndim == 3 and img.shape[2] >= 3:  # OpenCV's BGR[A] to RGB[A], by index: every dtype (cvtColor takes few)
        img = img[:, :, [2, 1, 0, *range(3, img.shape[2])]]
    return _check_array(np.ascontiguousarray(img), max_pixels, name)


def _decode_tiff_bands(data: bytes, name: str) -> np.ndarray:
    """The first image of a TIFF of 2 or 4+ samples per pixel, every sample a band (as stored)."""
    import tifffile

    try:
        with tifffile.TiffFile(_io.BytesIO(data)) as tif:
            page = tif.pages.first
            image, axes = page.asarray(), str(page.axes)
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 - a missing codec or a broken file: either way not readable
        raise InputError(f"`{name}` cannot be decoded as a TIFF of several bands: {exc}") from None
    if sorted(axes) != ["S", "X", "Y"]:
        raise InputError(f"`{name}`: a TIFF whose first image has axes {axes!r}; expected rows, columns, samples")
    return np.ascontiguousarray(np.transpose(image, [axes.index("Y"), axes.index("X"), axes.index("S")]))


def encode_png(array: Any) -> bytes:
    """Encode an (H, W) or (H, W, 3) RGB array (uint8 or uint16; bool and others converted) as PNG."""
    return encode_image(array, ".png")


_CV_TIFF_TYPES = (np.uint8, np.int8, np.uint16, np.int16, np.int32, np.float32, np.float64)  # OpenCV writes these


def encode_image(array: Any, suffix: str) -> bytes:
    """Encode an (H, W) or (H, W, C) image (RGB[A] for 3 and 4 bands) as ``.png``, ``.tif`` / ``.tiff`` or ``.bmp``.

    TIFF keeps every band and the dtype (integers of 8 to 64 bits, float32 and float64; float16
    becomes float32): through OpenCV for 1, 3 or 4 bands of the types it writes (a 4th band is
    tagged alpha, as OpenCV tags it), else through tifffile (bands as extra samples). PNG keeps
    uint8 and uint16, BMP 8 bits, both with 1, 3 or 4 bands (a wider integer image is refused for
    BMP, so label values are never squeezed). bool becomes 0 / 255; any other dtype is converted
    for PNG and BMP by :func:`to_uint8`.

    Raises
    ------
    InputError
        Another suffix (the message lists these), an empty or wrongly shaped array, a 16-bit (or
        wider) integer image for BMP, or a band count other than 1, 3 or 4 for PNG and BMP.
    """
    fmt = suffix.lower()
    if fmt not in IMAGE_OUT_SUFFIXES:
        raise InputError(f"images are written as {', '.join(IMAGE_OUT_SUFFIXES)}; got {suffix!r}")
    arr = _writable(np.asarray(array), fmt)
    bands = 1 if arr.ndim == 2 else arr.shape[2]
    if fmt in (".tif", ".tiff") and (bands not in (1, 3, 4) or arr.dtype.type not in _CV_TIFF_TYPES):
        return _encode_tiff_bands(arr)
    if bands >= 3:  # RGB[A] to OpenCV's BGR[A], by index: every dtype
        arr = arr[:, :, [2, 1, 0, *range(3, bands)]]
    ok, buf = cv2.imencode(fmt, np.ascontiguousarray(arr))
    if not ok:  # pragma: no cover - OpenCV refuses only shapes excluded above
        raise InputError(f"{fmt[1:].upper()} encoding failed")
    return buf.tobytes()


def _writable(arr: np.ndarray, fmt: str) -> np.ndarray:
    """``arr`` checked for the format ``fmt`` and in a dtype it holds (see :func:`encode_image`)."""
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] == 0) or arr.size == 0:
        raise InputError(f"`array` must be a non-empty (H, W) or (H, W, C) image, got shape {arr.shape}")
    if arr.dtype.kind not in "biuf":
        raise InputError(f"`array` must have a real dtype, got {arr.dtype}")
    bands = 1 if arr.ndim == 2 else arr.shape[2]
    tiff = fmt in (".tif", ".tiff")
    if not tiff and bands not in (1, 3, 4):
        raise InputError(f"{fmt[1:].upper()} holds 1, 3 or 4 bands; an image of {bands} bands is written as .tif")
    if fmt == ".bmp" and arr.dtype.kind in "iu" and arr.dtype != np.uint8:
        raise InputError(f"BMP holds 8 bits per channel; a {arr.dtype} image is written as .png or .tif")
    if arr.dtype == bool:
        arr = arr.astype(np.uint8) * 255
    elif tiff and arr.dtype == np.float16:
        arr = arr.astype(np.float32)
    elif not tiff and arr.dtype not in {".png": (np.uint8, np.uint16)}.get(fmt, (np.uint8,)):
        arr = to_uint8(arr)
    return arr


def _encode_tiff_bands(arr: np.ndarray) -> bytes:
    """TIFF bytes (tifffile, deflate) of an image OpenCV does not write: bands as samples of one grey page."""
    import tifffile

    buf = _io.BytesIO()
    tifffile.imwrite(buf, np.ascontiguousarray(arr), photometric="minisblack", compression="zlib",
                     planarconfig="contig" if arr.ndim == 3 else None)
    return buf.getvalue()


def to_uint8(arr: np.ndarray) -> np.ndarray:
    """uint8 copy of an image of any real dtype, channels kept.

    uint8 is kept; uint16 is divided by 257; floats in [0, 1] are scaled by 255; any other range
    is stretched from its min..max (a constant image becomes all zeros; NaN counts as 0).
    """
    if arr.dtype == np.uint8:
        return arr
    if arr.dtype == np.uint16:
        return np.round(arr / 257.0).astype(np.uint8)
    a = np.nan_to_num(np.asarray(arr, dtype=np.float64))
    lo, hi = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
    if arr.dtype.kind == "f" and lo >= 0.0 and hi <= 1.0:
        return np.round(a * 255.0).astype(np.uint8)
    if hi <= lo:
        return np.zeros(a.shape, np.uint8)
    return np.round((a - lo) * (255.0 / (hi - lo))).astype(np.uint8)
