"""Non-rigid image pairs with exact ground truth, made from scikit-image's bundled sample photographs.

Image b is image a seen through a known forward map T (a -> b):

    T(p) = c + s R(theta) (p + v(p) - c) + t

with a random similarity (rotation up to +-25 degrees, scale 0.8-1.25, shift up to 5 % of the size,
about the image centre c) and a smooth random field v, a sum of a few Gaussian bumps whose
displacements reach about 10 % of the image size (kept invertible: |dv/dp| < 0.5). b is rendered
by inverting T at every pixel of b (Newton's method, exact to 1e-6 px) and sampling a there, with
mild photometric change (gain, gamma, Gaussian noise). So every SIFT match (p, q) and every flow
vector T(p) - p has a known true answer.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import skimage.data

__all__ = ["SAMPLES", "Pair", "make_pair", "make_pairs"]

SAMPLES = ("astronaut", "camera", "coffee", "chelsea", "rocket", "brick", "hubble_deep_field",
           "immunohistochemistry", "retina", "stereo_motorcycle")


@dataclass(frozen=True, eq=False)
class Pair:
    name: str
    a: np.ndarray
    b: np.ndarray
    center: np.ndarray
    rot: np.ndarray  # s R, (2, 2)
    shift: np.ndarray
    bump_centers: np.ndarray  # (K, 2)
    bump_amps: np.ndarray  # (K, 2)
    bump_radius: np.ndarray  # (K,)

    def forward(self, p: np.ndarray) -> np.ndarray:
        """T(p) for (N, 2) points (x, y) of a."""
        return self.center + (p + self._field(p) - self.center) @ self.rot.T + self.shift

    def _field(self, p: np.ndarray) -> np.ndarray:
        d2 = ((p[:, None, :] - self.bump_centers[None]) ** 2).sum(-1)
        g = np.exp(-d2 / (2 * self.bump_radius[None] ** 2))
        return g @ self.bump_amps

    def _jacobian(self, p: np.ndarray) -> np.ndarray:
        diff = p[:, None, :] - self.bump_centers[None]  # (N, K, 2)
        g = np.exp(-(diff ** 2).sum(-1) / (2 * self.bump_radius[None] ** 2))  # (N, K)
        dg = -diff * (g / self.bump_radius[None] ** 2)[..., None]  # (N, K, 2) d g_k / d p_j
        jv = np.einsum("ki,nkj->nij", self.bump_amps, dg)
        jv += np.eye(2)
        return self.rot[None] @ jv

    def inverse(self, q: np.ndarray) -> np.ndarray:
        """T^-1(q) by Newton's method from the inverse similarity."""
        p = (q - self.shift - self.center) @ np.linalg.inv(self.rot).T + self.center
        for _ in range(30):
            r = self.forward(p) - q
            if np.abs(r).max() < 1e-6:
                break
            p = p - np.linalg.solve(self._jacobian(p), r[..., None])[..., 0]
        return p

    def true_flow(self) -> np.ndarray:
        h, w = self.a.shape[:2]
        ys, xs = np.mgrid[0:h, 0:w]
        p = np.c_[xs.ravel(), ys.ravel()].astype(float)
        out = np.empty((h * w, 2))
        for s in range(0, len(p), 65536):
            out[s:s + 65536] = self.forward(p[s:s + 65536]) - p[s:s + 65536]
        return out.reshape(h, w, 2)


def _load(name: str, max_side: int) -> np.ndarray:
    img = getattr(skimage.data, name)()
    if isinstance(img, tuple):  # stereo_motorcycle returns (left, right, disparity)
        img = img[0]
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    if img.dtype != np.uint8:
        img = np.clip(img * 255.0 if img.max() <= 1.0 else img, 0, 255).astype(np.uint8)
    s = max_side / max(img.shape[:2])
    if s < 1:
        img = cv2.resize(img, (round(img.shape[1] * s), round(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img)


def make_pair(name: str, seed: int, *, max_side: int = 512) -> Pair:
    """One pair from sample image ``name`` with warp and photometric change drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    a = _load(name, max_side)
    h, w = a.shape[:2]
    size = max(h, w)
    theta = np.deg2rad(rng.uniform(-25, 25))
    scale = np.exp(rng.uniform(np.log(0.8), np.log(1.25)))
    rot = scale * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    shift = rng.uniform(-0.05, 0.05, 2) * [w, h]
    k = 4
    centers = rng.uniform([0.1 * w, 0.1 * h], [0.9 * w, 0.9 * h], (k, 2))
    radius = rng.uniform(0.18, 0.3, k) * size
    amps = rng.normal(0, 1, (k, 2))
    amps *= (rng.uniform(0.05, 0.1, k) * size / np.linalg.norm(amps, axis=1))[:, None]
    # keep |dv/dp| < 0.5 so that T stays one-to-one (max slope of a bump: |A| / (r sqrt(e)))
    slope = (np.linalg.norm(amps, axis=1) / (radius * np.sqrt(np.e))).sum()
    if slope > 0.5:
        amps *= 0.5 / slope
    pair = Pair(name, a, a, np.array([w / 2, h / 2]), rot, shift, centers, amps, radius)
    ys, xs = np.mgrid[0:h, 0:w]
    q = np.c_[xs.ravel(), ys.ravel()].astype(float)
    p = np.empty_like(q)
    for s in range(0, len(q), 65536):
        p[s:s + 65536] = pair.inverse(q[s:s + 65536])
    m = p.astype(np.float32).reshape(h, w, 2)
    b = cv2.remap(a, m[..., 0], m[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    gain, gamma = rng.uniform(0.8, 1.2), rng.uniform(0.8, 1.25)
    bf = gain * (b.astype(np.float64) / 255.0) ** gamma * 255.0 + rng.normal(0, 2.0, b.shape)
    b = np.clip(np.round(bf), 0, 255).astype(np.uint8)
    return Pair(name, a, b, pair.center, rot, shift, centers, amps, radius)


def make_pairs(n: int = 20, *, seed: int = 0, max_side: int = 512) -> list[Pair]:
    """``n`` pairs cycling over the sample images (at least 6 different images when n >= 6)."""
    return [make_pair(SAMPLES[i % len(SAMPLES)], seed + i, max_side=max_side) for i in range(n)]
