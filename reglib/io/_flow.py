"""Dense flow files: Middlebury ``.flo``, ``.npy``, and the ITK displacement fields medical tools
open (``.mha``, ``.nrrd``, ``.nii``, ``.nii.gz``; see :mod:`reglib.io._displacement`), as files or bytes.

Flow is ``(H, W, 2)`` float32 of (dx, dy), forward from image a (CONTRACTS.md):
``flow[r, c] = f((c, r)) - (c, r)`` for the transform f that maps a into b, x the column.
"""
from __future__ import annotations

import io as _io
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ._displacement import (
    DISPLACEMENT_SUFFIXES,
    displacement_suffix,
    encode_mha,
    encode_nifti,
    encode_nrrd,
    read_displacement,
)
from ._files import write_bytes_atomic

__all__ = ["FLOW_SUFFIXES", "write_flo", "read_flo", "write_flow", "read_flow", "encode_flo", "encode_npy",
           "encode_flow"]

FLOW_SUFFIXES = (".flo", ".npy", *DISPLACEMENT_SUFFIXES)

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


def _suffix(path: Path) -> str:
    """The flow suffix of ``path`` (lower case; ``.nii.gz`` whole), or an ``InputError`` listing them."""
    suffix = displacement_suffix(path) or path.suffix.lower()
    if suffix not in FLOW_SUFFIXES:
        raise InputError(f"flow path must end in one of {', '.join(FLOW_SUFFIXES)}, got {path.name!r}")
    return suffix


def encode_flow(flow: Any, suffix: str) -> bytes:
    """The bytes of the flow file with ``suffix`` (one of :data:`FLOW_SUFFIXES`, e.g. ``".mha"``)."""
    suffix = _suffix(Path("flow" + suffix.lower()))
    if suffix == ".flo":
        return encode_flo(flow)
    if suffix == ".npy":
        return encode_npy(_as_flow(flow))
    if suffix == ".mha":
        return encode_mha(flow)
    if suffix == ".nrrd":
        return encode_nrrd(flow)
    return encode_nifti(flow, compress=suffix == ".nii.gz")


def write_flow(path: str | os.PathLike[str], flow: Any) -> None:
    """Write an (H, W, 2) flow of (dx, dy) by the suffix of ``path``, atomically.

    ``.flo`` (Middlebury), ``.npy``, or an ITK displacement field: ``.mha`` (MetaImage), ``.nrrd``,
    ``.nii`` / ``.nii.gz`` (NIfTI-1). The displacement fields are 2-D images of 2-component float32
    vectors with spacing 1, origin 0 and the identity direction, so ITK's physical point of pixel
    (row r, column c) is (x, y) = (c, r), x the column; each vector is (dx, dy) in pixels, and
    ITK's ``DisplacementFieldTransform`` of the field maps a point p of image a (the fixed image) to
    ``p + flow(p)`` in image b's pixel frame (the moving image): the transform a -> b itself at
    pixel centres. See :mod:`reglib.io._displacement`.

    Raises
    ------
    InputError
        An unknown suffix (the message lists them), or a flow that is not a numeric (H, W, 2) array
        (for displacement fields: non-empty and finite).

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "flow.mha"
    >>> write_flow(path, np.full((4, 5, 2), 0.5, np.float32))
    >>> read_flow(path).shape
    (4, 5, 2)
    """
    p = Path(path)
    write_bytes_atomic(p, encode_flow(flow, _suffix(p)))


def read_flow(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an (H, W, 2) float32 flow of (dx, dy) by the suffix of ``path`` (see :func:`write_flow`).

    ``.npy`` holds a float (H, W, 2) array (no pickles); the displacement fields must lie on the
    pixel grid (spacing 1, origin 0, identity direction), as :func:`write_flow` writes them.
    """
    p = Path(path)
    suffix = _suffix(p)
    if suffix == ".flo":
        return read_flo(p)
    if suffix != ".npy":
        return read_displacement(p)
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
