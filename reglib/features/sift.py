"""SIFT keypoints with RootSIFT descriptors, and deterministic k-NN matching.

Keypoints are (x, y) pixels of the image given, x the column, the centre of the top-left pixel at
(0, 0). Images larger than ``max_side`` are detected on a copy resized by ``cv2.resize`` (which
puts pixel centres at half-integers of the scale: a pixel x' of the copy is x = (x' + 0.5) / s - 0.5
of the original) and mapped back exactly.

Matching is brute force (``cv2.BFMatcher``): deterministic, unlike an unseeded FLANN index.

References
----------
.. [1] D. G. Lowe, "Distinctive Image Features from Scale-Invariant Keypoints", IJCV 60, 2004.
       :doi:`10.1023/B:VISI.0000029664.99615.94`
.. [2] R. Arandjelovic, A. Zisserman, "Three things everyone should know to improve object
       retrieval", CVPR 2012 (RootSIFT). :doi:`10.1109/CVPR.2012.6248018`
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..errors import InputError
from ..io import to_uint8

__all__ = ["Features", "detect_sift", "match_descriptors", "to_gray_uint8", "resize_factor"]

_MIN_SIDE = 8  # SIFT finds nothing useful below this; smaller images give no keypoints


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints and their descriptors.

    Attributes
    ----------
    points : (K, 2) float64 ndarray
        (x, y) pixel positions in the original image.
    sizes : (K,) float64 ndarray
        Keypoint diameters in original pixels.
    angles : (K,) float64 ndarray
        Orientations in degrees (OpenCV's convention).
    descriptors : (K, 128) float32 ndarray
        RootSIFT descriptors (unit L2 norm).
    """

    points: np.ndarray
    sizes: np.ndarray
    angles: np.ndarray
    descriptors: np.ndarray

    @classmethod
    def empty(cls) -> "Features":
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 128), np.float32))


def to_gray_uint8(image: np.ndarray) -> np.ndarray:
    """Grey uint8 copy of an (H, W) or (H, W, 3) RGB image of any real dtype.

    The intensity mapping is :func:`reglib.io.to_uint8`'s.
    """
    u8 = to_uint8(image)
    if u8.ndim == 3:
        u8 = cv2.cvtColor(np.ascontiguousarray(u8), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(u8)


def resize_factor(shape: tuple[int, int], max_side: int) -> tuple[int, int, float, float]:
    """New (W', H') no longer than ``max_side`` and the exact per-axis scales W'/W, H'/H."""
    h, w = shape
    side = max(h, w)
    if side <= max_side:
        return w, h, 1.0, 1.0
    s = max_side / side
    nw, nh = max(1, round(w * s)), max(1, round(h * s))
    return nw, nh, nw / w, nh / h


def detect_sift(gray: np.ndarray, *, mask: np.ndarray | None = None, max_keypoints: int = 4000,
                max_side: int = 1600) -> Features:
    """Detect SIFT keypoints on ``gray`` (uint8 (H, W)) and describe them with RootSIFT.

    Parameters
    ----------
    gray : (H, W) uint8 ndarray
    mask : (H, W) bool ndarray, optional
        Keypoints are only detected where it is True.
    max_keypoints : int
        Keep at most this many, the strongest by detector response.
    max_side : int
        Detect on a copy resized so that its longer side is at most this; positions, sizes are
        mapped back to ``gray``'s pixels.
    """
    h, w = gray.shape
    if min(h, w) < _MIN_SIDE:
        return Features.empty()
    nw, nh, sx, sy = resize_factor((h, w), max_side)
    work, work_mask = gray, mask
    if (nw, nh) != (w, h):
        work = cv2.resize(gray, (nw, nh), interpolation=cv2.INTER_AREA)
        if mask is not None:
            work_mask = cv2.resize(mask.astype(np.uint8), (nw, nh), interpolation=cv2.INTER_NEAREST) > 0
    m8 = None if work_mask is None else work_mask.astype(np.uint8) * 255
    if m8 is not None and not m8.any():
        return Features.empty()
    sift = cv2.SIFT.create(nfeatures=int(max_keypoints))
    kps, desc = sift.detectAndCompute(work, m8)
    if desc is None or len(kps) == 0:
        return Features.empty()
    if len(kps) > max_keypoints:  # OpenCV can return a few more than nfeatures (ties in response)
        order = np.argsort([-k.response for k in kps], kind="stable")[:max_keypoints]
        kps = [kps[i] for i in order]
        desc = desc[order]
    pts = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
    pts[:, 0] = (pts[:, 0] + 0.5) / sx - 0.5
    pts[:, 1] = (pts[:, 1] + 0.5) / sy - 0.5
    sizes = np.array([k.size for k in kps], dtype=np.float64) / np.sqrt(sx * sy)
    angles = np.array([k.angle for k in kps], dtype=np.float64)
    return Features(pts, sizes, angles, root_sift(desc))


def root_sift(desc: np.ndarray) -> np.ndarray:
    """RootSIFT: L1-normalize, take the element-wise square root (unit L2 norm after)."""
    d = desc.astype(np.float32)
    d /= np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
    return np.sqrt(d, out=d)


def match_descriptors(desc_a: np.ndarray, desc_b: np.ndarray, *, ratio: float = 0.8,
                      mutual: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour matches from a to b with Lowe's ratio test and an optional mutual check.

    Parameters
    ----------
    desc_a, desc_b : (Ka, F), (Kb, F) float32 ndarray
    ratio : float
        Keep a match when its distance is below ``ratio`` times the second-nearest one
        (1.0 keeps every nearest neighbour).
    mutual : bool
        Keep only pairs that are each other's nearest neighbour.

    Returns
    -------
    idx_a, idx_b : (N,) int ndarray
        Matched rows of ``desc_a`` and ``desc_b``, sorted by ``idx_a``.
    """
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    k = 2 if len(desc_b) >= 2 else 1
    knn = bf.knnMatch(desc_a, desc_b, k=k)
    ia, ib = [], []
    for row in knn:
        if not row:
            continue
        best = row[0]
        if ratio < 1.0:
            if len(row) < 2 or not best.distance < ratio * row[1].distance:
                continue
        ia.append(best.queryIdx)
        ib.append(best.trainIdx)
    idx_a, idx_b = np.asarray(ia, np.intp), np.asarray(ib, np.intp)
    if mutual and len(idx_a):
        back = bf.match(desc_b, desc_a)
        nn_ba = np.full(len(desc_b), -1, np.intp)
        for mt in back:
            nn_ba[mt.queryIdx] = mt.trainIdx
        keep = nn_ba[idx_b] == idx_a
        idx_a, idx_b = idx_a[keep], idx_b[keep]
    order = np.argsort(idx_a, kind="stable")
    return idx_a[order], idx_b[order]


def check_mask(mask: Any, shape: tuple[int, int], name: str) -> np.ndarray | None:
    """Validate an optional region-of-interest mask: (H, W) array, nonzero = inside."""
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
