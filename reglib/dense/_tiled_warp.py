"""Warping an image larger than memory: ``warp_image`` tile by tile, from a file to a tiled TIFF.

For each block of a's frame the transform is evaluated on that block alone (the same field
evaluation as :func:`warp_image`, on the block's own node grid), the rectangle of b those positions
fall in (one pixel of margin for linear sampling) is read from b's file, decoding only the tiles or
strips it covers (:class:`reglib.io.TiffRegions`), and resampled as :func:`warp_image` resamples;
the blocks are written as a tiled TIFF (:func:`reglib.io._tiled_tiff.write_tiled_tiff`) with every
band and the dtype kept. Memory holds one band of output rows and the few source tiles it needs,
whatever the size.

Coordinates as in :mod:`reglib.dense._flow`: (x, y), x the column; out[p] = b(f(p)) for every pixel
p of a; 0 where f(p) falls outside b.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

import cv2
import numpy as np

from .._transforms import KernelWarp
from .._validation import as_choice
from ..errors import InputError
from ._flow import as_shape, as_transform, remap_image, sample_positions

__all__ = ["WarpedFile", "warp_image_file"]

_BLOCK_W = 2048  # columns of a's frame resampled at once (one tile row high)
_MAX_REGION = 1 << 26  # pixels of b read for one block, at most; a block whose positions spread wider is split
_MIN_BLOCK = 16  # a block is not split below this side


class _Source(Protocol):
    shape: tuple[int, int]
    bands: int
    dtype: np.dtype

    def read(self, y0: int, y1: int, x0: int, x1: int) -> np.ndarray: ...


class _ArraySource:
    """An image in memory, read by region like a file."""

    def __init__(self, image: np.ndarray) -> None:
        self.image = image
        self.shape = (int(image.shape[0]), int(image.shape[1]))
        self.bands = 1 if image.ndim == 2 else int(image.shape[2])
        self.dtype = image.dtype

    def read(self, y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
        return self.image[y0:y1, x0:x1]


@dataclass(frozen=True)
class WarpedFile:
    """What :func:`warp_image_file` wrote.

    Attributes
    ----------
    path : Path
        The tiled TIFF.
    shape : (int, int)
        (H_a, W_a) of its full-resolution image.
    bands : int
        Bands written (b's).
    dtype : str
        Sample type written (b's; bool as uint8 0 / 255).
    levels : int
        Pyramid levels (1 without a pyramid).
    inside : float
        Share of a's pixels whose f(p) falls inside b.
    """

    path: Path
    shape: tuple[int, int]
    bands: int
    dtype: str
    levels: int
    inside: float


def warp_image_file(image_b: Any, transform: KernelWarp | dict[str, Any], shape_a: Any,
                    out: str | os.PathLike[str], *, interpolation: Literal["linear", "nearest"] = "linear",
                    pyramid: bool = False, max_pixels: int | None = None) -> WarpedFile:
    """Resample image b into a's frame tile by tile and write it as a tiled TIFF: ``out[p] = b(f(p))``.

    :func:`warp_image` for images that do not fit in memory: b is read by region from its file
    (only the tiles each block of the output needs) and the result is written band by band.

    Parameters
    ----------
    image_b : path or ndarray
        A TIFF file of any size (tiled, striped or pyramidal; read by region), another image file
        within ``max_pixels`` (read whole by :func:`reglib.io.read_image`), or an array.
    transform : KernelWarp or dict
        Maps a's pixels (x, y) into b (a -> b, as :func:`reglib.match_images` returns it).
    shape_a : tuple
        (H_a, W_a) of the output, any size.
    out : path
        The ``.tif`` / ``.tiff`` to write (atomically); its folder must exist. BigTIFF past 4 GB.
    interpolation : {"linear", "nearest"}
        As :func:`warp_image`; "nearest" keeps label values exactly.
    pyramid : bool
        Also write halved levels down to one tile (reduced pages: tifffile, OpenSlide and QuPath read
        them as a pyramid); the full resolution comes first.
    max_pixels : int, optional
        Largest image of another format read whole (default :data:`reglib.io.DEFAULT_MAX_PIXELS`).

    Returns
    -------
    WarpedFile
        Path, shape, bands, dtype, levels and the share of a inside b.

    Raises
    ------
    InputError
        ``out`` not a ``.tif`` / ``.tiff`` in an existing folder, an unreadable ``image_b``, a bad
        ``transform`` or ``shape_a``, another ``interpolation``.
    """
    from ..io import DEFAULT_MAX_PIXELS, TiffRegions, is_tiff_file, read_image, write_tiled_tiff

    interpolation = as_choice(interpolation, "interpolation", ("linear", "nearest"))
    f = as_transform(transform)
    h, w = as_shape(shape_a, "shape_a", bounded=False)
    target = Path(out)
    if target.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"`out` of a tiled warp must be a .tif or .tiff file, got {target.name!r}")
    if not target.parent.is_dir():
        raise InputError(f"`out`: no such folder: {target.parent}")
    if isinstance(image_b, np.ndarray):
        source: _Source = _ArraySource(image_b)
    elif is_tiff_file(image_b):
        source = TiffRegions(image_b, "image_b")
    else:
        limit = DEFAULT_MAX_PIXELS if max_pixels is None else max_pixels
        source = _ArraySource(read_image(image_b, max_pixels=limit, name="image_b"))
    try:
        if source.dtype.kind not in "biuf" or source.shape[0] < 1 or source.shape[1] < 1:
            raise InputError(f"`image_b` must be a non-empty image of a real dtype, got {source.dtype}")
        counter = [0]
        dtype = np.dtype(np.uint8) if source.dtype == bool else np.dtype(source.dtype)

        def rows(r0: int, r1: int) -> np.ndarray:
            band, inside = _warp_band(source, f, (r0, r1), w, interpolation)
            counter[0] += inside
            return band.astype(np.uint8) * 255 if band.dtype == bool else band

        levels = write_tiled_tiff(target, rows, (h, w), dtype, source.bands, pyramid=bool(pyramid))
    finally:
        if isinstance(source, TiffRegions):
            source.close()
    return WarpedFile(path=target, shape=(h, w), bands=source.bands, dtype=str(dtype), levels=levels,
                      inside=counter[0] / (h * w))


def _warp_band(source: _Source, f: KernelWarp, rows: tuple[int, int], width: int,
               interpolation: str) -> tuple[np.ndarray, int]:
    """Rows r0..r1-1 of the warp over a's full width, block by block; and how many of its pixels fall inside b."""
    r0, r1 = rows
    tail = (source.bands,) if source.bands > 1 else ()
    band = np.zeros((r1 - r0, width, *tail), source.dtype)
    inside = 0
    for c0 in range(0, width, _BLOCK_W):
        c1 = min(c0 + _BLOCK_W, width)
        inside += _warp_block(source, f, (r0, r1, c0, c1), band[:, c0:c1], interpolation)
    return band, inside


def _warp_block(source: _Source, f: KernelWarp, rect: tuple[int, int, int, int], out: np.ndarray,
                interpolation: str) -> int:
    """Warp a's pixels in rows r0..r1-1, columns c0..c1-1 into ``out`` (zeros on entry); the count inside b.

    A block whose positions spread over more than ``_MAX_REGION`` pixels of b is split in two along
    its longer side."""
    r0, r1, c0, c1 = rect
    pos = sample_positions(f.source_shifted((-c0, -r0)), (r1 - r0, c1 - c0))  # f(p + (c0, r0)) on the block
    hb, wb = source.shape
    (x_min, x_max, _, _), (y_min, y_max, _, _) = (cv2.minMaxLoc(plane) for plane in cv2.split(pos))  # fast bounds
    lo = np.floor([x_min, y_min]) - 1
    hi = np.ceil([x_max, y_max]) + 2
    x0, y0 = int(min(max(lo[0], 0), wb)), int(min(max(lo[1], 0), hb))
    x1, y1 = int(min(max(hi[0], 0), wb)), int(min(max(hi[1], 0), hb))
    if x1 <= x0 or y1 <= y0:
        return 0  # the whole block maps outside b
    if (x1 - x0) * (y1 - y0) > _MAX_REGION and max(r1 - r0, c1 - c0) > _MIN_BLOCK:
        if c1 - c0 >= r1 - r0:
            mid = (c0 + c1) // 2
            return (_warp_block(source, f, (r0, r1, c0, mid), out[:, :mid - c0], interpolation)
                    + _warp_block(source, f, (r0, r1, mid, c1), out[:, mid - c0:], interpolation))
        mid = (r0 + r1) // 2
        return (_warp_block(source, f, (r0, mid, c0, c1), out[:mid - r0], interpolation)
                + _warp_block(source, f, (mid, r1, c0, c1), out[mid - r0:], interpolation))
    region = source.read(y0, y1, x0, x1)
    pos -= np.array([x0, y0], np.float32)
    warped, valid = remap_image(np.ascontiguousarray(region), pos, interpolation)
    out[...] = warped.reshape(out.shape)
    return int(np.count_nonzero(valid))

