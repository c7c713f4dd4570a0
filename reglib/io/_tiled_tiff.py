"""Writing an image larger than memory as a tiled TIFF, band by band, with a pyramid on request.

The caller hands over the image as a function of a band of rows; the writer asks for one band of
tile rows at a time, cuts it into tiles for tifffile and, for a pyramid, halves it (the mean of each
2 x 2 block, an odd last row or column repeated) into a raw file of the next level beside the output,
which the next level is read from band by band in turn. Memory stays one band of rows whatever the
height. Levels follow the full image as reduced pages (``subfiletype`` 1) of the same tile size,
halving until the longer side fits in one tile: tifffile reads them as the series' levels, OpenSlide
and QuPath as a generic tiled pyramid. Files past 4 GB are BigTIFF. Compression is lossless (zlib,
which tifffile writes without imagecodecs).
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np

__all__ = ["TILE", "write_tiled_tiff", "pyramid_shapes"]

TILE = 256  # tile side of written files
_ZLIB_LEVEL = 1  # the fastest deflate: higher levels cost several times the time for little size
_BIG = 2**32 - 2**26  # past this many bytes (with room for tables) a file is written as BigTIFF

Rows = Callable[[int, int], np.ndarray]  # (r0, r1) -> rows r0..r1-1, (r1 - r0, W[, C])


def pyramid_shapes(shape: tuple[int, int], pyramid: bool) -> list[tuple[int, int]]:
    """(H, W) of each level written: the full size, then halved (rounding up) while the longer side exceeds a tile."""
    shapes = [shape]
    while pyramid and max(shapes[-1]) > TILE:
        h, w = shapes[-1]
        shapes.append(((h + 1) // 2, (w + 1) // 2))
    return shapes


def write_tiled_tiff(path: str | os.PathLike[str], rows: Rows, shape: tuple[int, int], dtype: np.dtype, bands: int,
                     *, pyramid: bool = False) -> int:
    """Write the image ``rows`` gives as a tiled TIFF at ``path`` (atomically); return the number of levels.

    Parameters
    ----------
    path : path
        The ``.tif`` to write; its folder must exist.
    rows : callable
        ``rows(r0, r1)`` returns rows r0..r1-1 as (r1 - r0, W) or (r1 - r0, W, C) of ``dtype``.
    shape : (int, int)
        (H, W) of the image.
    dtype : numpy.dtype
        Its sample type (kept).
    bands : int
        C (1 for grey).
    pyramid : bool
        Also write the halved levels (see the module docstring).
    """
    import tifffile

    target = Path(path)
    shapes = pyramid_shapes(shape, pyramid)
    dtype = np.dtype(dtype)
    total = sum(h * w for h, w in shapes) * bands * dtype.itemsize
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    raws: list[str] = []
    try:
        with tifffile.TiffWriter(tmp, bigtiff=total > _BIG) as writer:
            source = rows
            for level, (h, w) in enumerate(shapes):
                nxt = None
                if level + 1 < len(shapes):
                    fd, nxt = tempfile.mkstemp(prefix=f".{target.name}.level{level + 1}.", dir=target.parent)
                    raws.append(nxt)
                with open(fd, "wb") if nxt is not None else contextlib.nullcontext() as halved:
                    writer.write(_tiles(source, (h, w), dtype, bands, halved),
                                 shape=(h, w, bands) if bands > 1 else (h, w), dtype=dtype, tile=(TILE, TILE),
                                 photometric="rgb" if bands in (3, 4) else "minisblack", planarconfig="contig",
                                 compression="zlib", compressionargs={"level": _ZLIB_LEVEL},
                                 subfiletype=1 if level else 0, metadata=None)
                if nxt is not None:
                    source = _raw_rows(nxt, shapes[level + 1], dtype, bands)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; results are meant to be shared (as write_bytes_atomic's)
        os.replace(tmp, target)
    finally:
        for name in [*raws, tmp]:
            if os.path.exists(name):
                os.remove(name)
    return len(shapes)


def _tiles(rows: Rows, shape: tuple[int, int], dtype: np.dtype, bands: int,
           halved: BinaryIO | None) -> Iterator[np.ndarray]:
    """The tiles of the image ``rows`` gives, row-major, each (TILE, TILE[, C]) padded with zeros; with ``halved``,
    each band of rows is also appended, halved, to that raw file (before its tiles: tifffile stops drawing at
    the last tile)."""
    h, w = shape
    tail = (bands,) if bands > 1 else ()
    for r0 in range(0, h, TILE):
        band = np.asarray(rows(r0, min(r0 + TILE, h)), dtype).reshape(-1, w, *tail)
        if halved is not None:
            halved.write(np.ascontiguousarray(_halved(band)).tobytes())
        for c0 in range(0, w, TILE):
            part = band[:, c0:c0 + TILE]
            if part.shape[:2] == (TILE, TILE):
                yield np.ascontiguousarray(part)
            else:
                tile = np.zeros((TILE, TILE, *tail), dtype)
                tile[:part.shape[0], :part.shape[1]] = part
                yield tile


def _halved(band: np.ndarray) -> np.ndarray:
    """The mean of each 2 x 2 block of ``band`` (an odd last row or column repeated), in its dtype."""
    if band.shape[0] % 2 or band.shape[1] % 2:
        pad = [(0, band.shape[0] % 2), (0, band.shape[1] % 2)] + [(0, 0)] * (band.ndim - 2)
        band = np.pad(band, pad, mode="edge")
    h, w = band.shape[0] // 2, band.shape[1] // 2
    if band.dtype.type in (np.uint8, np.uint16, np.float32, np.float64) and (band.ndim == 2 or band.shape[2] <= 4):
        out = cv2.resize(band, (w, h), interpolation=cv2.INTER_AREA)  # the 2 x 2 block mean, rounded
        return out.reshape(h, w, *band.shape[2:])
    mean = band.reshape(h, 2, w, 2, *band.shape[2:]).astype(np.float64).mean(axis=(1, 3))
    if band.dtype.kind in "iu":
        info = np.iinfo(band.dtype)
        mean = np.clip(np.round(mean), info.min, info.max)
    elif band.dtype == bool:
        mean = mean >= 0.5
    return mean.astype(band.dtype)


def _raw_rows(path: str, shape: tuple[int, int], dtype: np.dtype, bands: int) -> Rows:
    """``rows(r0, r1)`` of a raw row-major file of an (H, W[, C]) image, read from disk per call."""
    row = shape[1] * bands * dtype.itemsize

    def rows(r0: int, r1: int) -> np.ndarray:
        data = np.fromfile(path, dtype=dtype, count=(r1 - r0) * shape[1] * bands, offset=r0 * row)
        return data.reshape(r1 - r0, shape[1], *((bands,) if bands > 1 else ()))

    return rows
