"""Image preparation for the detectors: intensity normalisation, grey copies, masks, working copies.

Images arrive in any real dtype (uint8, uint16, float) with any intensity range, grey or RGB.
The SIFT path works on a grey uint8 copy (:func:`to_gray_uint8`); the multimodal path on a grey
float32 copy in [0, 1] made by a robust percentile stretch (:func:`normalize_intensity`), so that
a few hot pixels of a 16-bit or float image do not squeeze its content into a few grey levels.

The stretch is the costliest step that every multimodal function repeats on the same image
(detection, match refinement, the structure field of the dense stage). A caller running several of
them on one image computes it once with :meth:`NormalizedImage.of` and passes that in place of the
image: :func:`~reglib.features.detect_multimodal`, :func:`~reglib.features.refine_matches` and
:func:`~reglib.features.structure_image` accept either and give the same numbers.

Coordinates: (x, y) pixels, x the column, the centre of the top-left pixel (0, 0). A working copy
resized by ``cv2.resize`` to the per-axis scales (sx, sy) = (W'/W, H'/H) keeps pixel centres at
half-integers of the scale: a point x' of the copy is x = (x' + 0.5) / sx - 0.5 in the image.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..errors import InputError
from ..io import to_uint8

__all__ = ["NormalizedImage", "check_mask", "normalize_intensity", "to_gray_uint8"]


def normalize_intensity(image: np.ndarray, *, low: float = 0.5, high: float = 99.5) -> np.ndarray:
    """Grey float32 copy in [0, 1] of an (H, W) or (H, W, 3) image of any real dtype.

    Colour is reduced to luminance (ITU-R 601 weights on RGB); NaN and inf count as 0. The
    ``low`` and ``high`` percentiles (of at most about 250 000 evenly subsampled pixels) map to 0
    and 1 and values beyond are clipped, so a few hot pixels of a 16-bit or float image (medical
    data) do not squeeze its content into a few grey levels. A constant image becomes all zeros.

    Examples
    --------
    >>> img = np.array([[0, 1000], [2000, 65535]], np.uint16)
    >>> np.round(normalize_intensity(img, low=0, high=100), 3)
    array([[0.   , 0.015],
           [0.031, 1.   ]], dtype=float32)
    """
    arr = np.asarray(image)
    if arr.ndim == 3:
        arr = arr[:, :, :3].astype(np.float32)
        gray = arr[:, :, 0] * 0.299 + arr[:, :, 1] * 0.587 + arr[:, :, 2] * 0.114
    else:
        gray = arr.astype(np.float32)
    gray = np.nan_to_num(gray, nan=0.0, posinf=0.0, neginf=0.0)
    if gray.size == 0:
        return gray
    step = max(1, int(np.sqrt(gray.size / 250_000)))
    lo, hi = np.percentile(gray[::step, ::step], [low, high])
    if not hi > lo:
        lo, hi = float(gray.min()), float(gray.max())
    if not hi > lo:
        return np.zeros(gray.shape, np.float32)
    out = (gray - np.float32(lo)) * np.float32(1.0 / (hi - lo))
    return np.clip(out, 0.0, 1.0, out=out)


@dataclass(frozen=True, eq=False)
class NormalizedImage:
    """An image's :func:`normalize_intensity` copy, made once and passed to every multimodal step.

    Attributes
    ----------
    gray : (H, W) float32 ndarray
        Values in [0, 1], read-only.

    Examples
    --------
    >>> from skimage.data import camera
    >>> norm = NormalizedImage.of(camera())
    >>> norm.gray.dtype, norm.shape
    (dtype('float32'), (512, 512))
    """

    gray: np.ndarray

    @classmethod
    def of(cls, image: np.ndarray) -> NormalizedImage:
        """Normalize an (H, W) or (H, W, 3 or 4) image of any real dtype (:func:`normalize_intensity`).

        Raises
        ------
        InputError
            When ``image`` is not a real (H, W) or (H, W, 3) array.
        """
        arr = _check_image(image)
        gray = normalize_intensity(arr)
        gray.flags.writeable = False
        return cls(gray)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the image."""
        return self.gray.shape[0], self.gray.shape[1]


def _check_image(image: Any) -> np.ndarray:
    """The array of a real (H, W) or (H, W, 3 or 4) image, or an :class:`InputError` naming ``image``."""
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] not in (3, 4)) or arr.dtype.kind not in "biuf":
        raise InputError(f"`image` must be a real (H, W) or (H, W, 3) array, got shape {arr.shape} dtype {arr.dtype}")
    return arr


def _normalized(image: np.ndarray | NormalizedImage) -> np.ndarray:
    """The grey [0, 1] copy of an image, or of a :class:`NormalizedImage` as it is (trusted input)."""
    if isinstance(image, NormalizedImage):
        return image.gray
    return normalize_intensity(image)


def to_gray_uint8(image: np.ndarray) -> np.ndarray:
    """Grey uint8 copy of an (H, W) or (H, W, 3) RGB image of any real dtype.

    The intensity mapping is :func:`reglib.io.to_uint8`'s; colour is reduced by OpenCV's RGB to
    grey weights.
    """
    u8 = to_uint8(image)
    if u8.ndim == 3:
        u8 = cv2.cvtColor(np.ascontiguousarray(u8), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(u8)


def check_mask(mask: Any, shape: tuple[int, int], name: str) -> np.ndarray | None:
    """Validate an optional region-of-interest mask: (H, W) array, nonzero = inside.

    Returns
    -------
    (H, W) bool ndarray or None
        ``mask != 0``; None when ``mask`` is None (no mask: every pixel is inside).

    Raises
    ------
    InputError
        When ``mask`` (called ``name`` in the message) does not have the image's ``shape`` (an
        (H, W, 1) array counts as (H, W)) or is not boolean or numeric.
    """
    if mask is None:
        return None
    arr = np.asarray(mask)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.shape != tuple(shape):
        raise InputError(f"`{name}` must have the image's shape {tuple(shape)}, got {arr.shape}")
    if arr.dtype.kind not in "biuf":
        raise InputError(f"`{name}` must be a boolean or numeric array, got {arr.dtype}")
    return arr != 0


def _working_copy(gray: np.ndarray, max_side: int) -> tuple[np.ndarray, float, float]:
    """Resize a [0, 1] image so that its longer side is ``max_side``; the exact per-axis scales W'/W, H'/H.

    Down by area averaging, up by bicubic interpolation (clipped back to [0, 1]); an image of that
    size already is returned as it is, with scales 1.
    """
    h, w = gray.shape
    s = max_side / max(h, w)
    nw, nh = max(1, round(w * s)), max(1, round(h * s))
    if (nw, nh) == (w, h):
        return gray, 1.0, 1.0
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC
    work = cv2.resize(gray, (nw, nh), interpolation=interp)
    return np.clip(work, 0.0, 1.0), nw / w, nh / h
