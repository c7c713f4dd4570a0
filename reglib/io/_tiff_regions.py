"""Reading a large TIFF by region: only the tiles (or strips) a region covers are decoded.

Whole-slide scans and satellite scenes do not fit in memory decoded. :class:`TiffRegions` opens a
TIFF's first image and reads any rectangle of it, or of one of its pyramid levels (tiled or
pyramidal TIFF, OME-TIFF, SVS as tifffile reads them), decoding the segments (tiles or strips) that
rectangle touches and keeping the most recently decoded ones within a small byte budget, so that
neighbouring reads share them. :meth:`TiffRegions.reduced` makes a copy smaller by a whole factor k
(the mean of each k x k block) band by band, from the coarsest pyramid level that allows it, so
the whole image is never decoded at once.

Coordinates: the centre of a reduced pixel (x', y') lies at (k x' + (k - 1) / 2, k y' + (k - 1) / 2)
of the full image (x the column, pixel centres at integers), which is exact for block means; a
partial block at the right or bottom edge is left out, so the reduced size is (H // k, W // k).
"""
from __future__ import annotations

import math
import os
from collections import OrderedDict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["TiffRegions", "open_tiff"]

_CACHE_BYTES = 96 << 20  # decoded segments kept for neighbouring reads
_BAND_BYTES = 64 << 20  # rows decoded at once while reducing (a whole number of segment rows, at least one)
_CV_AREA_TYPES = (np.uint8, np.uint16, np.float32, np.float64)  # cv2.resize INTER_AREA takes these


class _Level:
    """One pyramid level: its page, whole factor k to the full image, and segment layout."""

    def __init__(self, page: Any, factor: int) -> None:
        self.page = page
        self.factor = factor
        shaped = page.shaped  # (separate samples, depth, length, width, contig samples)
        if shaped[0] > 1 or shaped[1] > 1:
            raise InputError("a TIFF of separate sample planes or depth is not read by region")
        self.height, self.width, self.samples = int(shaped[2]), int(shaped[3]), int(shaped[4])
        if page.is_tiled:
            self.seg_h, self.seg_w = int(page.tilelength), int(page.tilewidth)
        else:
            self.seg_h, self.seg_w = int(page.rowsperstrip or self.height), self.width
            self.seg_h = min(self.seg_h, self.height)
        self.n_cols = math.ceil(self.width / self.seg_w)


class TiffRegions:
    """The first image of a TIFF, read by region (see the module docstring).

    Parameters
    ----------
    path : path
        The TIFF file.
    name : str
        How the image is called in error messages.

    Attributes
    ----------
    shape : (int, int)
        (H, W) of the full-resolution image.
    bands : int
        Samples per pixel (1 for grey).
    dtype : numpy.dtype
        The stored sample type.

    Raises
    ------
    InputError
        Not a TIFF tifffile reads, or a first image that is not (H, W) or (H, W, S) in one page.
    """

    def __init__(self, path: str | os.PathLike[str], name: str = "image") -> None:
        import tifffile

        self.name = name
        self.path = Path(path)
        try:
            self._tif = tifffile.TiffFile(self.path)
        except Exception as exc:  # noqa: BLE001 - any parse failure: not a TIFF read here
            raise InputError(f"`{name}` ({self.path.name}) cannot be opened as a TIFF: {exc}") from None
        try:
            self._levels = self._find_levels()
        except Exception:
            self._tif.close()
            raise
        full = self._levels[0]
        self.shape = (full.height, full.width)
        self.bands = full.samples
        self.dtype = np.dtype(full.page.dtype)
        self._cache: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._cache_bytes = 0

    def _find_levels(self) -> list[_Level]:
        if not self._tif.series:
            raise InputError(f"`{self.name}` ({self.path.name}) cannot be read as a TIFF: it holds no image")
        series = self._tif.series[0]
        axes = str(series.axes)
        if axes not in ("YX", "YXS") or len(series.levels[0].pages) != 1:
            raise InputError(f"`{self.name}` ({self.path.name}): a TIFF whose first image has axes {axes!r} "
                             f"in {len(series.levels[0].pages)} pages; expected one page of rows, columns[, samples]")
        full = _Level(series.levels[0].pages[0], 1)
        levels = [full]
        for level in series.levels[1:]:
            if len(level.pages) != 1:
                continue
            page = level.pages[0]
            if page is None:
                continue
            k = round(full.width / max(int(page.shaped[3]), 1))
            # a level is used only at a whole factor k of the full size (floor or ceiling of W / k, H / k)
            ok = k >= 2 and all(int(page.shaped[i]) in (n // k, -(-n // k))
                                for i, n in ((2, full.height), (3, full.width)))
            if ok and page.shaped[4] == full.samples and page.dtype == full.page.dtype:
                levels.append(_Level(page, k))
        return levels

    def __enter__(self) -> TiffRegions:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (decoded segments are dropped)."""
        self._cache.clear()
        self._tif.close()

    @property
    def factors(self) -> tuple[int, ...]:
        """Whole factors of the pyramid levels read (1 first: the full image)."""
        return tuple(level.factor for level in self._levels)

    def read(self, y0: int, y1: int, x0: int, x1: int, *, level: int = 0) -> np.ndarray:
        """Rows y0..y1-1 and columns x0..x1-1 of pyramid level ``level`` (0: full resolution).

        Returns an (h, w) array for one band, (h, w, S) for S bands, in the stored dtype. The
        rectangle is clipped to the level's bounds by the caller (trusted input).
        """
        lv = self._levels[level]
        out = np.empty((y1 - y0, x1 - x0, lv.samples), self.dtype)
        for ty in range(y0 // lv.seg_h, (y1 - 1) // lv.seg_h + 1):
            for tx in range(x0 // lv.seg_w, (x1 - 1) // lv.seg_w + 1):
                seg = self._segment(level, ty * lv.n_cols + tx)
                sy, sx = ty * lv.seg_h, tx * lv.seg_w
                r0, r1 = max(y0, sy), min(y1, sy + seg.shape[0])
                c0, c1 = max(x0, sx), min(x1, sx + seg.shape[1])
                out[r0 - y0:r1 - y0, c0 - x0:c1 - x0] = seg[r0 - sy:r1 - sy, c0 - sx:c1 - sx]
        return out[:, :, 0] if lv.samples == 1 else out

    def _segment(self, level: int, index: int) -> np.ndarray:
        """Segment ``index`` of level ``level`` decoded as (rows, cols, S), cached."""
        key = (level, index)
        seg = self._cache.get(key)
        if seg is not None:
            self._cache.move_to_end(key)
            return seg
        page = self._levels[level].page
        fh = self._tif.filehandle
        fh.seek(page.dataoffsets[index])
        data = fh.read(page.databytecounts[index])
        try:
            decoded, _, _ = page.decode(data, index, jpegtables=page.jpegtables)
        except Exception as exc:  # noqa: BLE001 - a codec tifffile lacks (imagecodecs), or broken data
            raise InputError(_decode_message(self.name, self.path, page, exc)) from None
        seg = np.asarray(decoded).reshape(decoded.shape[-3:])
        self._cache[key] = seg
        self._cache_bytes += seg.nbytes
        while self._cache_bytes > _CACHE_BYTES and len(self._cache) > 1:
            _, old = self._cache.popitem(last=False)
            self._cache_bytes -= old.nbytes
        return seg

    def reduced(self, factor: int) -> np.ndarray:
        """The image reduced by the whole factor k: the mean of each k x k block, (H // k, W // k[, S]).

        Read from the coarsest pyramid level whose factor divides k, band by band (one band of
        segment rows decoded at a time). Integer images are rounded to their dtype.
        """
        k = int(factor)
        level = max((i for i, f in enumerate(self.factors) if k % f == 0), key=lambda i: self.factors[i])
        lv, m = self._levels[level], k // self.factors[level]
        h, w = self.shape[0] // k, self.shape[1] // k
        out = np.empty((h, w, lv.samples), self.dtype)
        row_bytes = lv.width * lv.samples * self.dtype.itemsize
        band = max(lv.seg_h, (_BAND_BYTES // max(row_bytes, 1)) // lv.seg_h * lv.seg_h)
        band = max(m, band // m * m)  # whole blocks per band
        for r in range(0, h * m, band):
            rows = self.read(r, min(r + band, h * m), 0, w * m, level=level)
            out[r // m:r // m + rows.shape[0] // m] = _block_mean(rows, m).reshape(-1, w, lv.samples)
        return out[:, :, 0] if lv.samples == 1 else out


def _block_mean(rows: np.ndarray, m: int) -> np.ndarray:
    """The mean of each m x m block of ``rows`` (whose sides are multiples of m), in its dtype."""
    if m == 1:
        return rows
    h, w = rows.shape[0] // m, rows.shape[1] // m
    if rows.dtype.type in _CV_AREA_TYPES and (rows.ndim == 2 or rows.shape[2] <= 4):
        out = cv2.resize(rows, (w, h), interpolation=cv2.INTER_AREA)  # exactly the block mean at a whole factor
        return out
    shaped = rows.reshape(h, m, w, m, *rows.shape[2:]).astype(np.float64)
    mean = shaped.mean(axis=(1, 3))
    if rows.dtype.kind in "iu":
        info = np.iinfo(rows.dtype)
        mean = np.clip(np.round(mean), info.min, info.max)
    return mean.astype(rows.dtype)


def _decode_message(name: str, path: Path, page: Any, exc: Exception) -> str:
    """Why a segment could not be decoded; names the package when a codec is missing."""
    text = str(exc)
    if "imagecodecs" in text or "ImportError" in type(exc).__name__:
        return (f"`{name}` ({path.name}) is compressed as {page.compression.name}, which needs the imagecodecs "
                "package: pip install 'reglib[large]'")
    return f"`{name}` ({path.name}) cannot be decoded: {text}"


def open_tiff(path: str | os.PathLike[str], name: str = "image") -> TiffRegions:
    """A :class:`TiffRegions` on ``path`` (close it, or use it as a context manager)."""
    return TiffRegions(path, name)
