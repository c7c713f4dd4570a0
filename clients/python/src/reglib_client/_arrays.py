"""Read arrays the service sends as files: ``.npy``, Middlebury ``.flo`` and PNG images."""
from __future__ import annotations

import io
import struct

import numpy as np

from ._png import PNG_SIGNATURE, decode_png

__all__ = ["decode_flow", "decode_image", "FLO_MAGIC"]

FLO_MAGIC = b"PIEH"  # the float 202021.25 in little-endian bytes
_NPY_MAGIC = b"\x93NUMPY"


def _load_npy(content: bytes) -> np.ndarray:
    return np.load(io.BytesIO(content), allow_pickle=False)


def _load_flo(content: bytes) -> np.ndarray:
    if len(content) < 12:
        raise ValueError(".flo data is shorter than its header")
    width, height = struct.unpack("<ii", content[4:12])
    if width <= 0 or height <= 0 or len(content) != 12 + width * height * 8:
        raise ValueError(f".flo header says {width} x {height} but the data has {len(content) - 12} bytes")
    return np.frombuffer(content, dtype="<f4", offset=12).reshape(height, width, 2).astype(np.float32)


def decode_flow(content: bytes) -> np.ndarray:
    """A (H, W, 2) float32 flow from ``.npy`` or ``.flo`` bytes (recognized by their magic numbers)."""
    if content.startswith(_NPY_MAGIC):
        flow = _load_npy(content)
    elif content.startswith(FLO_MAGIC):
        flow = _load_flo(content)
    else:
        raise ValueError("flow data is neither .npy nor .flo")
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must have shape (H, W, 2), got {flow.shape}")
    flow = np.array(flow, dtype=np.float32)
    flow.setflags(write=False)
    return flow


def decode_image(content: bytes) -> np.ndarray:
    """An image array from PNG or ``.npy`` bytes (the formats the client reads without OpenCV)."""
    if content.startswith(PNG_SIGNATURE):
        image = decode_png(content)
    elif content.startswith(_NPY_MAGIC):
        image = _load_npy(content)
    else:
        raise ValueError("image data is neither PNG nor .npy (the client decodes no other format)")
    image.setflags(write=False)
    return image
