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


@dataclass(frozen=True)
class LargePair:
    """A tiled TIFF pair made for the large-image paths: b(q) = a(q + d(q)) with a smooth d of a few pixels."""

    path_a: str
    path_b: str
    image_a: np.ndarray
    image_b: np.ndarray
    amplitude: float

    def displacement(self, pts: np.ndarray) -> np.ndarray:
        """d at (N, 2) points (x, y) of b."""
        n, a = float(self.image_a.shape[0]), self.amplitude
        x, y = pts[:, 0], pts[:, 1]
        return np.stack([a * np.sin(2 * np.pi * y / (0.8 * n) + 0.4), a * np.cos(2 * np.pi * x / (0.9 * n) + 1.0)], 1)

    def true_map(self, pts: np.ndarray) -> np.ndarray:
        """f(p) = q with q + d(q) = p: the transform a -> b (d varies slowly: fixed-point iteration)."""
        q = np.asarray(pts, np.float64).copy()
        for _ in range(50):
            q = pts - self.displacement(q)
        return q


@pytest.fixture(scope="session")
def large_pair(tmp_path_factory: pytest.TempPathFactory) -> LargePair:
    """3000 x 3000 uint8 tiled TIFFs (256-px tiles), a smooth texture and b = a under a smooth map of ~8 px."""
    import tifffile

    n = 3000
    rng = np.random.default_rng(5)
    noise = rng.standard_normal((n, n)).astype(np.float32)
    a = cv2.GaussianBlur(noise, (0, 0), 2.0) + 0.6 * cv2.GaussianBlur(noise, (0, 0), 6.0)
    a = np.clip(128 + 60 * a / a.std(), 0, 255).astype(np.uint8)
    pair = LargePair("", "", a, a, 8.0)
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    d = pair.displacement(np.stack([xx.ravel(), yy.ravel()], 1)).astype(np.float32).reshape(n, n, 2)
    b = cv2.remap(a, xx + d[..., 0], yy + d[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    folder = tmp_path_factory.mktemp("large")
    paths = []
    for name, img in (("A.tif", a), ("B.tif", b)):
        tifffile.imwrite(folder / name, img, tile=(256, 256), photometric="minisblack", metadata=None)
        paths.append(str(folder / name))
    return LargePair(paths[0], paths[1], a, b, 8.0)
