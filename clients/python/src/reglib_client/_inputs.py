"""Turn what callers pass (images, point sets, options) into request parts."""
from __future__ import annotations

import json
import math
import os
from typing import IO, Any, Union

import numpy as np

from ._png import encode_png

__all__ = ["ImageInput", "image_part", "points_json", "form_fields", "json_options"]

ImageInput = Union[str, "os.PathLike[str]", bytes, bytearray, memoryview, IO[bytes], np.ndarray]

_MAGIC = (
    (b"\x89PNG\r\n\x1a\n", "image/png", ".png"),
    (b"\xff\xd8\xff", "image/jpeg", ".jpg"),
    (b"BM", "image/bmp", ".bmp"),
    (b"II*\x00", "image/tiff", ".tif"),
    (b"MM\x00*", "image/tiff", ".tif"),
)


def _media_type(data: bytes) -> tuple[str, str]:
    for magic, media, suffix in _MAGIC:
        if data.startswith(magic):
            return media, suffix
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "image/webp", ".webp"
    return "application/octet-stream", ""


def image_part(image: ImageInput, name: str) -> tuple[str, bytes, str]:
    """(filename, bytes, media type) for one multipart file.

    ``image`` is a path (str or os.PathLike), encoded bytes, a binary file object (read from its
    current position) or an (H, W) / (H, W, 3) RGB / (H, W, 4) RGBA integer numpy array, which is
    encoded to PNG here. The service decides from the bytes whether it can read them.
    """
    if isinstance(image, np.ndarray):
        data = encode_png(image)
        return f"{name}.png", data, "image/png"
    if isinstance(image, (bytes, bytearray, memoryview)):
        data = bytes(image)
        filename = name
    elif isinstance(image, (str, os.PathLike)):
        path = os.fspath(image)
        with open(path, "rb") as handle:
            data = handle.read()
        filename = os.path.basename(path) or name
    elif hasattr(image, "read"):
        data = image.read()
        if not isinstance(data, (bytes, bytearray)):
            raise TypeError(f"`{name}` file object must be opened in binary mode, it gave {type(data).__name__}")
        data = bytes(data)
        filename = os.path.basename(str(getattr(image, "name", ""))) or name
    else:
        raise TypeError(f"`{name}` must be a path, bytes, a binary file object or a numpy array, "
                        f"got {type(image).__name__}")
    if not data:
        raise ValueError(f"`{name}` is empty (0 bytes)")
    media, suffix = _media_type(data)
    if filename == name:
        filename += suffix
    return filename, data, media


def points_json(points: Any, name: str) -> list[list[float]]:
    """(N, D) array_like -> nested lists of floats; checked for shape and finiteness before sending."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.size == 0 and arr.ndim <= 2:
        arr = arr.reshape(0, arr.shape[-1] if arr.ndim == 2 else 2)
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise ValueError(f"`{name}` must have shape (N, 2) or (N, 3), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"`{name}` must hold only finite numbers")
    return arr.tolist()


def scan_json(points: Any, name: str) -> list[Any]:
    """(N, D) points, or an organized (H, W, 3) scan with NaN pixels (sent as null), as nested lists."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 3:
        return points_json(arr, name)
    if arr.shape[2] != 3:
        raise ValueError(f"`{name}` as an organized scan must have shape (H, W, 3), got {arr.shape}")
    if np.isinf(arr).any():
        raise ValueError(f"`{name}` must not hold inf (missing pixels are NaN)")
    return [[None if np.isnan(p).any() else p.tolist() for p in row] for row in arr]


def _jsonable(value: Any, name: str) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"option `{name}` must be finite, got {value!r}")
    return value


def json_options(options: dict[str, Any]) -> dict[str, Any]:
    """Options for a JSON body: numpy values made plain, ``None`` dropped (the server's default applies)."""
    return {key: _jsonable(value, key) for key, value in options.items() if value is not None}


def form_fields(options: dict[str, Any]) -> dict[str, str]:
    """Options as multipart form fields: booleans as ``true``/``false``, lists and dicts as JSON.

    ``None`` values are dropped so the server's default applies. Field names are sent as given:
    the service rejects a name it does not know (422), so a misspelling is never silently ignored.
    """
    fields: dict[str, str] = {}
    for key, value in options.items():
        value = _jsonable(value, key)
        if value is None:
            continue
        if isinstance(value, bool):
            fields[key] = "true" if value else "false"
        elif isinstance(value, (list, tuple, dict)):
            fields[key] = json.dumps(value, allow_nan=False)
        else:
            fields[key] = str(value)
    return fields
