"""SIFT keypoints with RootSIFT descriptors.

Keypoints are (x, y) pixels of the image given, x the column, the centre of the top-left pixel at
(0, 0). Images larger than ``max_side`` are detected on a copy resized by ``cv2.resize`` (which
puts pixel centres at half-integers of the scale: a pixel x' of the copy is x = (x' + 0.5) / s - 0.5
of the original) and mapped back exactly.

Match them with :func:`reglib.features.match_descriptors` (nearest neighbours in Euclidean
distance, Lowe's ratio test, optional mutual check).

References
----------
.. [1] D. G. Lowe, "Distinctive Image Features from Scale-Invariant Keypoints", IJCV 60, 2004.
       :doi:`10.1023/B:VISI.0000029664.99615.94`
.. [2] R. Arandjelovic, A. Zisserman, "Three things everyone should know to improve object
       retrieval", CVPR 2012 (RootSIFT). :doi:`10.1109/CVPR.2012.6248018`
"""
from __future__ import annotations

import cv2
import numpy as np

from ._keypoints import Features

__all__ = ["detect_sift", "resize_factor", "root_sift"]

_MIN_SIDE = 8  # SIFT finds nothing useful below this; smaller images give no keypoints


def resize_factor(shape: tuple[int, int], max_side: int) -> tuple[int, int, float, float]:
    """New (W', H') no longer than ``max_side`` and the exact per-axis scales W'/W, H'/H.

    Examples
    --------
    >>> resize_factor((300, 400), 200)
    (200, 150, 0.5, 0.5)
    """
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

    Trusted input: ``gray`` as :func:`~reglib.features.to_gray_uint8` gives it, ``mask`` as
    :func:`~reglib.features.check_mask` does.

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

    Returns
    -------
    Features
        (K, 128) RootSIFT descriptors; no keypoints for images under 8 px a side or an empty mask.
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
    """RootSIFT ([2]_): L1-normalize, take the element-wise square root (unit L2 norm after).

    Examples
    --------
    >>> root_sift(np.array([[1, 3, 0]], np.float32))
    array([[0.5      , 0.8660254, 0.       ]], dtype=float32)
    """
    d = desc.astype(np.float32)
    d /= np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
    return np.sqrt(d, out=d)
