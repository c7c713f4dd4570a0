"""The dense flow of a frame larger than memory, written band by band (``.flo`` and ``.npy``).

Both formats hold the (H, W, 2) float32 (dx, dy) values row by row after a short header, so the
flow is evaluated on one band of rows at a time (the transform on that band alone, as
:func:`dense_flow` evaluates it) and appended: memory holds one band whatever the height. The ITK
formats (``.mha``, ``.nrrd``, ``.nii``, ``.nii.gz``) are written whole and are refused past the
dense grid's limit. Flow is forward: ``flow[r, c] = f((c, r)) - (c, r)``, x the column.
"""
from __future__ import annotations

import os
import struct
import tempfile
from pathlib import Path

import numpy as np

from .._transforms import KernelWarp
from ..errors import InputError
from ._flow import dense_flow

__all__ = ["BANDED_FLOW_SUFFIXES", "write_flow_banded"]

BANDED_FLOW_SUFFIXES = (".flo", ".npy")
_BAND_ROWS = 256
_FLO_MAGIC = 202021.25


def write_flow_banded(path: str | os.PathLike[str], transform: KernelWarp, shape: tuple[int, int]) -> None:
    """Write the flow a -> b on an (H, W) frame of any size to ``path`` (``.flo`` or ``.npy``), atomically.

    Raises
    ------
    InputError
        Another suffix (the ITK formats are written whole by :func:`reglib.io.write_flow`).
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in BANDED_FLOW_SUFFIXES:
        raise InputError(f"a flow this large is written as {' or '.join(BANDED_FLOW_SUFFIXES)} (band by band), "
                         f"got {target.name!r}")
    h, w = int(shape[0]), int(shape[1])
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            if suffix == ".flo":
                fh.write(struct.pack("<fii", _FLO_MAGIC, w, h))
            else:
                np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": (h, w, 2)})
            for r0 in range(0, h, _BAND_ROWS):
                r1 = min(r0 + _BAND_ROWS, h)
                band = dense_flow(transform.source_shifted((0.0, -float(r0))), (r1 - r0, w))  # f(p + (0, r0)) - p
                band[..., 1] -= r0
                fh.write(band.astype("<f4", copy=False).tobytes())
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; results are meant to be shared
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
