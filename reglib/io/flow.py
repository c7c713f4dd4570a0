"""Dense flow files: Middlebury ``.flo`` and ``.npy``, as files or as bytes.

Flow is ``(H, W, 2)`` float32 of (dx, dy), forward from image a (CONTRACTS.md).
"""
from __future__ import annotations

import io as _io
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from .files import write_bytes_atomic

__all__ = ["write_flo", "read_flo", "write_flow", "read_flow", "encode_flo", "encode_npy"]

_FLO_MAGIC = 202021.25
_MAX_FLO_PIXELS = 1 << 28


def encode_flo(flow: Any) -> bytes:
    """Middlebury ``.flo`` bytes of ``flow`` (H, W, 2): magic 202021.25, int32 width, int32 height,
    then the (dx, dy) float32 values row by row, all little-endian."""
    arr = _as_flow(flow)
    h, w = arr.shape[:2]
    return struct.pack("<fii", _FLO_MAGIC, w, h) + arr.astype("<f4").tobytes()


def encode_npy(array: Any) -> bytes:
    """``.npy`` bytes of a numeric array (no pickles)."""
    arr = np.asarray(array)
    if arr.dtype.kind not in "biuf":
        raise InputError(f"`array` must be numeric, got dtype {arr.dtype}")
    buffer = _io.BytesIO()
    np.save(buffer, arr, allow_pickle=False)
    return buffer.getvalue()


def write_flo(path: str | os.PathLike[str], flow: Any) -> None:
    """Write ``flow`` (H, W, 2) as a Middlebury ``.flo`` file (float32 dx, dy), atomically."""
    write_bytes_atomic(Path(path), encode_flo(flow))


def read_flo(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a Middlebury ``.flo`` file into an (H, W, 2) float32 array of (dx, dy).

    The header's sizes are checked against the file length before anything is allocated.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"no such flow file: {p}")
    with p.open("rb") as fh:
        head = fh.read(12)
        if len(head) < 12:
            raise InputError(f"{p.name}: too short for a .flo header ({len(head)} bytes)")
        magic, w, h = struct.unpack("<fii", head)
        if magic != _FLO_MAGIC:
            raise InputError(f"{p.name}: not a .flo file (magic {magic!r}, expected {_FLO_MAGIC})")
        if w <= 0 or h <= 0 or w * h > _MAX_FLO_PIXELS:
            raise InputError(f"{p.name}: implausible .flo size {w}x{h}")
        want = 8 * w * h
        size = p.stat().st_size - 12
        if size != want:
            raise InputError(f"{p.name}: header says {w}x{h} ({want} bytes of data), file holds {size}")
        data = np.frombuffer(fh.read(want), dtype="<f4")
    return data.reshape(h, w, 2).astype(np.float32)


def write_flow(path: str | os.PathLike[str], flow: Any) -> None:
    """Write flow to ``.flo`` or ``.npy``, chosen by the suffix of ``path``."""
    p = Path(path)
    if p.suffix == ".flo":
        write_flo(p, flow)
    elif p.suffix == ".npy":
        write_bytes_atomic(p, encode_npy(_as_flow(flow)))
    else:
        raise InputError(f"flow path must end in .flo or .npy, got {p.name!r}")


def read_flow(path: str | os.PathLike[str]) -> np.ndarray:
    """Read flow from ``.flo`` or ``.npy`` (an (H, W, 2) float array; no pickles)."""
    p = Path(path)
    if p.suffix == ".flo":
        return read_flo(p)
    if p.suffix != ".npy":
        raise InputError(f"flow path must end in .flo or .npy, got {p.name!r}")
    if not p.is_file():
        raise InputError(f"no such flow file: {p}")
    try:
        arr = np.load(p, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"{p.name}: not a readable .npy file: {exc}") from None
    if arr.ndim != 3 or arr.shape[2] != 2 or arr.dtype.kind != "f":
        raise InputError(f"{p.name}: flow must be a float (H, W, 2) array, got {arr.dtype} {arr.shape}")
    return np.array(arr, dtype=np.float32)


def _as_flow(flow: Any) -> np.ndarray:
    arr = np.asarray(flow)
    if arr.ndim != 3 or arr.shape[2] != 2 or arr.dtype.kind not in "fiu":
        raise InputError(f"`flow` must be a numeric (H, W, 2) array, got {arr.dtype} {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float32)
