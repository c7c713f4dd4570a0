"""Reading an image at a working size: a TIFF larger than memory allows is reduced as it is read.

The pixel limit (``max_pixels``) guards memory, not file size: it bounds the pixels decoded into
memory at once. A TIFF file (tiled, striped or pyramidal) whose header says more is read reduced by a
whole factor k (:meth:`reglib.io.TiffRegions.reduced`: tile by tile, from a pyramid level where the
file has one), so that the copy is within the limit and no longer than the working side; other
formats have no random access and are refused above the limit as before (:func:`read_image`).

Coordinates: pixel (x', y') of the reduced copy is centred on (k x' + (k - 1) / 2, k y' + (k - 1) / 2)
of the full image (x the column), i.e. a copy resized by 1 / k in CONTRACTS.md's centre convention;
:meth:`reglib.KernelWarp.rescaled` maps a transform found on the copies back exactly.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import check_int
from ..errors import ImageTooLarge, InputError
from ._images import DEFAULT_MAX_PIXELS, read_image

__all__ = ["WorkingImage", "read_working_image", "is_tiff_file", "tiff_shape", "is_large_tiff"]


@dataclass(frozen=True, eq=False)
class WorkingImage:
    """An image as read for matching: the array, the whole factor it was reduced by, and the full size.

    Attributes
    ----------
    image : (h, w) or (h, w, C) ndarray
        The pixels read (every band, the file's dtype).
    factor : int
        k: the full image is k times larger (1: read whole).
    shape : (int, int)
        (H, W) of the full image.
    """

    image: np.ndarray
    factor: int
    shape: tuple[int, int]


def is_tiff_file(source: Any) -> bool:
    """Whether ``source`` is a path to an existing file that starts like a TIFF (either byte order, BigTIFF too)."""
    if not isinstance(source, (str, os.PathLike)) or not Path(source).is_file():
        return False
    with open(source, "rb") as fh:
        head = fh.read(4)
    return head in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def tiff_shape(path: str | os.PathLike[str], name: str = "image") -> tuple[int, int, int]:
    """(H, W, bands) of a TIFF's first image, from its header (nothing decoded)."""
    from ._tiff_regions import TiffRegions

    with TiffRegions(path, name) as tif:
        return tif.shape[0], tif.shape[1], tif.bands


def is_large_tiff(source: Any, max_pixels: int) -> bool:
    """Whether ``source`` is a path to a TIFF whose first image is over ``max_pixels`` (read at a working size)."""
    if not is_tiff_file(source):
        return False
    h, w, _ = tiff_shape(source)
    return h * w > max_pixels


def working_factor(shape: tuple[int, int], max_side: int, max_pixels: int) -> int:
    """The least whole k that brings an (H, W) image within ``max_pixels`` and a longer side of ``max_side``."""
    h, w = shape
    k = max(1, math.ceil(max(h, w) / max_side), math.ceil(math.sqrt(h * w / max_pixels)))
    while (h // k) * (w // k) > max_pixels:
        k += 1
    return k


def read_working_image(source: Any, *, max_side: int, max_pixels: int = DEFAULT_MAX_PIXELS,
                       name: str = "image") -> WorkingImage:
    """Read an image whole when it is within ``max_pixels``, else (a TIFF file) reduced by a whole factor.

    Parameters
    ----------
    source : ndarray, path or bytes
        What :func:`read_image` takes. Only a path to a TIFF is read reduced.
    max_side : int
        Longer side of the reduced copy, at most (for an image over ``max_pixels``).
    max_pixels : int
        Pixels decoded into memory, at most: an image within it is read whole.
    name : str
        How the image is called in error messages.

    Returns
    -------
    WorkingImage
        ``factor`` 1 and the image itself when it is within the limit.

    Raises
    ------
    ImageTooLarge
        Over ``max_pixels`` and not a TIFF file (bytes, arrays and other formats are read whole).
    InputError
        As :func:`read_image`; a TIFF that cannot be read by region.
    """
    check_int("max_side", max_side, 16)
    check_int("max_pixels", max_pixels, 1)
    if is_tiff_file(source):
        from ._tiff_regions import TiffRegions

        with TiffRegions(source, name) as tif:
            h, w = tif.shape
            if h * w > max_pixels:
                k = working_factor((h, w), max_side, max_pixels)
                if h // k < 1 or w // k < 1:
                    raise InputError(f"`{name}` ({Path(source).name}) is {w}x{h}: too thin to reduce by {k}")
                return WorkingImage(image=_checked(tif.reduced(k), name), factor=k, shape=(h, w))
    try:
        image = read_image(source, max_pixels=max_pixels, name=name)
    except ImageTooLarge as exc:
        raise ImageTooLarge(f"{exc}; only a TIFF file that large is read (at a working size), tile by tile") from None
    return WorkingImage(image=image, factor=1, shape=(int(image.shape[0]), int(image.shape[1])))


def _checked(image: np.ndarray, name: str) -> np.ndarray:
    """A reduced copy refused when it holds NaN or inf (as :func:`read_image` refuses such an image)."""
    if image.dtype.kind == "f" and not np.isfinite(image).all():
        raise InputError(f"`{name}` holds NaN or inf values")
    return image
