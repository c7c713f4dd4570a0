"""A change of sensor with a known similarity: the truth the multimodal feature and alignment tests share."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from skimage import data


@dataclass(frozen=True)
class SensorChange:
    """scikit-image's camera image (512 x 512) seen by another 'sensor' after a known similarity."""

    image: np.ndarray

    @staticmethod
    def remap(img: np.ndarray) -> np.ndarray:
        """A non-monotonic change of 'sensor': inverted, gamma 0.5, plus a bump in the mid-greys."""
        u = img.astype(np.float64) / 255.0
        v = 1.0 - np.sqrt(u) + 0.25 * np.exp(-((u - 0.5) / 0.1) ** 2)
        return np.clip(v * 200.0, 0, 255).astype(np.uint8)

    def similarity(self, angle: float, scale: float, shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """The 2 x 3 map rotating by ``angle`` degrees and scaling about the image centre, then shifting."""
        h, w = self.image.shape
        m = cv2.getRotationMatrix2D((w / 2 - 0.5, h / 2 - 0.5), angle, scale)
        m[:, 2] += shift
        return m

    @staticmethod
    def apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Points (N, 2) mapped by the 2 x 3 matrix ``m``."""
        return pts @ m[:, :2].T + m[:, 2]

    def pair(self, angle: float, scale: float,
             shift: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """The image moved by the similarity and remapped, and the similarity (image -> moved)."""
        m = self.similarity(angle, scale, shift)
        h, w = self.image.shape
        b = cv2.warpAffine(self.image, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        return self.remap(b), m


@pytest.fixture(scope="session")
def sensor() -> SensorChange:
    return SensorChange(data.camera())
