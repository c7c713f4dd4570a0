"""Keypoints and their descriptors: what every image detector of the package returns.

Positions are (x, y) pixels of the image given, x the column, the centre of the top-left pixel
at (0, 0), whatever working copy the detector ran on.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._repr import short_repr

__all__ = ["Features"]


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints and their descriptors.

    Attributes
    ----------
    points : (K, 2) float64 ndarray
        (x, y) pixel positions in the original image.
    sizes : (K,) float64 ndarray
        Keypoint diameters (SIFT) or described patch sides (multimodal) in original pixels.
    angles : (K,) float64 ndarray
        Orientations in degrees (OpenCV's convention; 0 for the multimodal features, whose
        rotation is one global hypothesis chosen at matching time).
    descriptors : (K, L) float32 ndarray
        One row per keypoint: RootSIFT (L = 128, unit L2 norm) or the multimodal maximum-index-map
        histograms (:func:`~reglib.features.detect_multimodal`).

    Examples
    --------
    >>> Features.empty().descriptors.shape, Features.empty(24).descriptors.shape
    ((0, 128), (0, 24))
    """

    points: np.ndarray
    sizes: np.ndarray
    angles: np.ndarray
    descriptors: np.ndarray

    def __repr__(self) -> str:
        return short_repr(self, ("points", "descriptors"))

    @classmethod
    def empty(cls, dim: int = 128) -> Features:
        """No keypoints, with descriptors of length ``dim`` (128: SIFT's)."""
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, dim), np.float32))
