"""The texture of a's patches: grid points whose patch is nearly flat are not searched (it correlates with anything).

A (2 h + 1)^2 patch's texture is the root mean over channels of its variance: :func:`texture_map`
per pixel (cheaper once for a whole grey image), :func:`texture_at` at grid points only (cheaper
for a multi-channel field, the same values); ``_default_min_std`` is the threshold when none is given.
"""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["texture_at", "texture_map"]


def texture_map(field: np.ndarray, half_patch: int) -> np.ndarray:
    """(H, W) float32: per pixel, the root mean over channels of the (2 h + 1)^2 patch variance.

    ``field`` is (H, W, C) float32, h = ``half_patch``. Trusted input: does not validate.
    """
    k = (2 * half_patch + 1, 2 * half_patch + 1)
    var = np.zeros(field.shape[:2], np.float32)
    for c in range(field.shape[2]):
        ch = field[:, :, c]
        mean = cv2.boxFilter(ch, cv2.CV_32F, k, normalize=True)
        sq = cv2.boxFilter(ch * ch, cv2.CV_32F, k, normalize=True)
        var += np.maximum(sq - mean * mean, 0.0)
    return np.sqrt(var / field.shape[2])


def texture_at(field: np.ndarray, half_patch: int, gy: np.ndarray, gx: np.ndarray) -> np.ndarray:
    """:func:`texture_map` at the pixels (gx, gy) only (their patches inside the field), from the patches themselves.

    The same float32 means of x and x^2 (summed in float64, as OpenCV's box filter does), the same
    variance. Trusted input: does not validate.
    """
    hp = int(half_patch)
    p = 2 * hp + 1
    dy, dx = np.mgrid[-hp:hp + 1, -hp:hp + 1]
    patches = field[gy[:, None, None] + dy, gx[:, None, None] + dx].reshape(len(gy), p * p, field.shape[2])
    mean = patches.mean(axis=1, dtype=np.float64).astype(np.float32)
    sq = (patches * patches).mean(axis=1, dtype=np.float64).astype(np.float32)
    var = np.maximum(sq - mean * mean, np.float32(0.0)).sum(axis=1, dtype=np.float32)
    return np.sqrt(var / np.float32(field.shape[2]))


def _default_min_std(field: np.ndarray) -> float:
    """2 grey levels for a grey image; for a descriptor field, 5 % of its channels' mean spread."""
    if field.shape[2] == 1:
        return 2.0
    return 0.05 * float(np.mean(field.reshape(-1, field.shape[2]).std(axis=0)))
