"""What the dense stage correlates: grey images and descriptor fields as float32 (H, W, C), and their resized copies.

Every search, check and evidence of the dense stage reads its images through these helpers: a grey
image (H, W) becomes a one-channel field (H, W, 1), a descriptor field (H, W, C) (e.g. a
modality-independent structure field) stays as it is, and the two images of a pair must have the
same C. Images over the working size are matched on copies resized by exactly a given scale with
OpenCV's area interpolation (half-pixel centres: x' = s (x + 0.5) - 0.5), any number of channels.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["area_resized"]


def _as_field(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, C) -> float32 (H, W, C), contiguous (an ``InputError`` for other shapes)."""
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise InputError(f"an image must be (H, W) or (H, W, C), got shape {img.shape}")
    if img.ndim == 2:
        img = img[:, :, None]
    return np.ascontiguousarray(img, dtype=np.float32)


def _as_fields(image_a: np.ndarray, image_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both as float32 (H, W, C) fields with the same C (an ``InputError`` otherwise)."""
    fa, fb = _as_field(image_a), _as_field(image_b)
    if fa.ndim != 3 or fb.ndim != 3 or fa.shape[2] != fb.shape[2]:
        raise InputError(f"`image_a` and `image_b` must be (H, W) images or (H, W, C) fields with the same C, "
                         f"got shapes {np.shape(image_a)} and {np.shape(image_b)}")
    return fa, fb


def _downscaled(image: np.ndarray, mask: np.ndarray | None, s: float) -> tuple[np.ndarray, np.ndarray | None]:
    """float32 (H, W, C) copy resized by exactly ``s`` (OpenCV half-pixel centres), and the mask likewise.

    ``s >= 1`` leaves both as they are. Trusted input: does not validate."""
    g = _as_field(image)
    if s >= 1.0:
        return g, mask
    small = area_resized(g, s)
    m = None
    if mask is not None:
        m = cv2.resize(mask.astype(np.uint8), (small.shape[1], small.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    return small, m


def area_resized(field: np.ndarray, s: float) -> np.ndarray:
    """(H, W, C) float32 field resized by ``s`` with OpenCV's area interpolation, any C.

    OpenCV's area resampling takes at most 4 channels at a scale that is not 1 / integer (a
    structure field has 9): the channels, each resampled on its own anyway, go 4 at a time.
    Trusted input: does not validate."""
    parts = []
    for c in range(0, field.shape[2], 4):
        part = cv2.resize(np.ascontiguousarray(field[:, :, c:c + 4]), (0, 0), fx=s, fy=s, interpolation=cv2.INTER_AREA)
        parts.append(part.reshape(part.shape[0], part.shape[1], -1))
    return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=2)
