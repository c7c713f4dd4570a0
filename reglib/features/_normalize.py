"""Image preparation for the detectors: intensity normalisation, grey copies, masks, working copies.

Images arrive in any real dtype (uint8, uint16 with 12 or 16 bits of data, int, float) with any
intensity range and any number of bands. The features see one grey rendering of them
(:func:`feature_bands`: the first three bands read as RGB, or one band picked) brought to their
working range by one rule (:func:`intensity_range`: the 0.5 and 99.5 percentiles of the pixels
become black and white), so that neither the bit depth nor a few hot pixels of a 16-bit or float
image decide what the detectors find. The SIFT path and the dense stage work on a grey uint8 copy
(:func:`to_gray_uint8`; an 8-bit image keeps its values), the multimodal path on a grey float32
copy in [0, 1] (:func:`normalize_intensity`).

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

__all__ = ["HIGH_PERCENTILE", "LOW_PERCENTILE", "NormalizedImage", "check_mask", "feature_bands", "intensity_range",
           "normalize_intensity", "to_gray_uint8"]


LOW_PERCENTILE, HIGH_PERCENTILE = 0.5, 99.5  # the stretch of every image that is not 8-bit


def feature_bands(image: np.ndarray, band: int | None = None) -> np.ndarray:
    """The bands of an image that the features see: (H, W), or (H, W, 3) taken as RGB.

    The grey rendering of an (H, W, C) image: one band is itself; two bands (grey and alpha) are
    their first; three or more are the first three, read as RGB (a 4th band, alpha or near
    infrared, and any further ones are carried by warps but do not steer the features). ``band``
    picks one band instead (0-based).

    Raises
    ------
    InputError
        ``band`` is not a band of the image.
    """
    arr = np.asarray(image)
    n_bands = 1 if arr.ndim == 2 else arr.shape[2]
    if band is not None:
        if not 0 <= band < n_bands:
            raise InputError(f"`band` {band} is not a band of the image: it has {n_bands} band(s), 0..{n_bands - 1}")
        return arr if arr.ndim == 2 else arr[:, :, band]
    if arr.ndim == 2:
        return arr
    if n_bands < 3:
        return arr[:, :, 0]
    return arr[:, :, :3]


def _luminance(arr: np.ndarray) -> np.ndarray:
    """Grey float32 copy of :func:`feature_bands`' (H, W) or (H, W, 3) result (ITU-R 601 weights on RGB);
    NaN and inf count as 0."""
    if arr.ndim == 3:
        rgb = arr.astype(np.float32)
        gray = rgb[:, :, 0] * 0.299 + rgb[:, :, 1] * 0.587 + rgb[:, :, 2] * 0.114
    else:
        gray = arr.astype(np.float32)
    return np.nan_to_num(gray, nan=0.0, posinf=0.0, neginf=0.0)


def intensity_range(gray: np.ndarray, dtype: np.dtype | None = None, *, low: float = LOW_PERCENTILE,
                    high: float = HIGH_PERCENTILE) -> tuple[float, float]:
    """The values that map to black and white: the ``low`` and ``high`` percentiles of a grey image.

    Percentiles of at most about 250 000 evenly subsampled pixels, so that a few hot pixels of a
    16-bit, float or medical image do not squeeze its content into a few grey levels, whatever
    range the data fill (12 bits in uint16, floats in [0, 1] or in Hounsfield units). A flat image
    (no spread between them) falls back on its min and max, then on the range of ``dtype`` (the
    image's before the grey copy): an integer type's full range, or [0, 1] for floats.
    """
    step = max(1, int(np.sqrt(gray.size / 250_000)))
    lo, hi = (float(v) for v in np.percentile(gray[::step, ::step], [low, high]))
    if not hi > lo:
        lo, hi = float(gray.min()), float(gray.max())
    if not hi > lo and dtype is not None:
        if np.dtype(dtype).kind in "iu":
            info = np.iinfo(dtype)
            lo, hi = float(info.min), float(info.max)
        elif np.dtype(dtype).kind == "f":
            lo, hi = 0.0, 1.0
    return lo, hi


def normalize_intensity(image: np.ndarray, *, low: float = LOW_PERCENTILE,
                        high: float = HIGH_PERCENTILE) -> np.ndarray:
    """Grey float32 copy in [0, 1] of an (H, W) or (H, W, C) image of any real dtype.

    The grey rendering of :func:`feature_bands` (luminance, ITU-R 601 weights, of the first three
    bands read as RGB); NaN and inf count as 0. The ``low`` and ``high`` percentiles
    (:func:`intensity_range`) map to 0 and 1 and values beyond are clipped. A constant image
    becomes all zeros.

    Examples
    --------
    >>> img = np.array([[0, 1000], [2000, 65535]], np.uint16)
    >>> np.round(normalize_intensity(img, low=0, high=100), 3)
    array([[0.   , 0.015],
           [0.031, 1.   ]], dtype=float32)
    """
    gray = _luminance(feature_bands(np.asarray(image)))
    if gray.size == 0:
        return gray
    lo, hi = intensity_range(gray, low=low, high=high)
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
        """Normalize an (H, W) or (H, W, C) image of any real dtype (:func:`normalize_intensity`).

        Raises
        ------
        InputError
            When ``image`` is not a real (H, W) or (H, W, C) array.
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
    """The array of a real (H, W) or (H, W, C) image, or an :class:`InputError` naming ``image``."""
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] == 0) or arr.dtype.kind not in "biuf":
        raise InputError(f"`image` must be a real (H, W) or (H, W, C) array, got shape {arr.shape} dtype {arr.dtype}")
    return arr


def _normalized(image: np.ndarray | NormalizedImage) -> np.ndarray:
    """The grey [0, 1] copy of an image, or of a :class:`NormalizedImage` as it is (trusted input)."""
    if isinstance(image, NormalizedImage):
        return image.gray
    return normalize_intensity(image)


def to_gray_uint8(image: np.ndarray, band: int | None = None) -> np.ndarray:
    """Grey uint8 copy of an (H, W) or (H, W, C) image of any real dtype: what SIFT and the dense stage see.

    The bands are :func:`feature_bands`' (``band``, or the first three read as RGB, reduced by
    OpenCV's RGB to grey weights). An 8-bit image keeps its values; any other dtype (uint16 with
    12 bits of data, int, float in any range) is stretched so that its 0.5 and 99.5 percentiles
    (:func:`intensity_range`) become 0 and 255, values beyond clipped.

    Examples
    --------
    >>> twelve_bit = np.array([[0, 1000], [2000, 4000]], np.uint16)
    >>> to_gray_uint8(twelve_bit)
    array([[  0,  64],
           [128, 255]], dtype=uint8)
    """
    arr = feature_bands(np.asarray(image), band)
    if arr.dtype == np.uint8:
        if arr.ndim == 3:
            arr = cv2.cvtColor(np.ascontiguousarray(arr), cv2.COLOR_RGB2GRAY)
        return np.ascontiguousarray(arr)
    gray = _luminance(arr)
    lo, hi = intensity_range(gray, arr.dtype)
    if not hi > lo:
        return np.zeros(gray.shape, np.uint8)
    out = np.clip((gray - np.float32(lo)) * np.float32(255.0 / (hi - lo)), 0.0, 255.0)
    return np.round(out).astype(np.uint8)


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
