"""A large synthetic pair written tile by tile: image a, and b = a under a known smooth map.

The texture is continuous (octaves of value noise, each a small random lattice sampled by cubic
interpolation), so any pixel of a or b is computed where it is needed and the generator holds one
band of tiles at a time, whatever the size. b(q) = T(q + d(q)) with a smooth displacement d of
about ``amplitude`` px, so the true transform a -> b is f(p) = q solving q + d(q) = p (fixed-point
iteration; d varies slowly). Coordinates are (x, y), x the column, pixel centres at integers.
"""
from __future__ import annotations

import os
from collections.abc import Iterator

import cv2
import numpy as np
import tifffile

_TILE = 512


class BigPair:
    """The texture and the map of a pair of ``size`` x ``size`` uint8 images (a seeded recipe)."""

    def __init__(self, size: int, *, amplitude: float = 25.0, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self.size = size
        self.amplitude = amplitude
        self.spacings = [s for s in (6, 12, 24, 48, 96, 192, 384, 768) if s * 4 <= size]
        self.lattices = [rng.standard_normal((size // s + 4, size // s + 4)).astype(np.float32)
                         for s in self.spacings]
        self.weights = [float(s) ** 0.35 for s in self.spacings]
        self.phases = rng.uniform(0, 2 * np.pi, 4)
        total = float(np.sqrt(sum(w * w for w in self.weights)))
        self.gain = 38.0 / total  # about 3.3 sigma within 0..255

    def displacement(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d(q) at points (x, y) of b, px (smooth: periods of about half the image)."""
        n, a, p = float(self.size), self.amplitude, self.phases
        dx = a * (0.7 * np.sin(2 * np.pi * y / (0.45 * n) + p[0]) + 0.3 * np.cos(2 * np.pi * x / (0.65 * n) + p[1]))
        dy = a * (0.6 * np.cos(2 * np.pi * x / (0.55 * n) + p[2]) + 0.4 * np.sin(2 * np.pi * (x + y) / (0.75 * n)
                                                                                  + p[3]))
        return dx, dy

    def texture(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """T at float32 positions (x, y) (any shape), uint8."""
        acc = np.zeros(x.shape, np.float32)
        for s, lattice, weight in zip(self.spacings, self.lattices, self.weights, strict=True):
            u = (x / s + 1.0).astype(np.float32)
            v = (y / s + 1.0).astype(np.float32)
            acc += weight * cv2.remap(lattice, u, v, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        return np.clip(np.round(128.0 + self.gain * acc), 0, 255).astype(np.uint8)

    def band(self, which: str, r0: int, r1: int, c0: int = 0, c1: int | None = None) -> np.ndarray:
        """Rows r0..r1-1 (columns c0..c1-1) of image ``which`` ("a" or "b")."""
        c1 = self.size if c1 is None else c1
        y, x = np.mgrid[r0:r1, c0:c1].astype(np.float32)
        if which == "b":
            dx, dy = self.displacement(x, y)
            x, y = x + dx.astype(np.float32), y + dy.astype(np.float32)
        return self.texture(x, y)

    def true_map(self, points: np.ndarray) -> np.ndarray:
        """f(p) for (N, 2) points (x, y) of a: the q with q + d(q) = p."""
        p = np.asarray(points, np.float64)
        q = p.copy()
        for _ in range(60):
            dx, dy = self.displacement(q[:, 0], q[:, 1])
            q = p - np.stack([dx, dy], axis=1)
        return q

    def tiles(self, which: str) -> Iterator[np.ndarray]:
        """The tiles of image ``which`` in row-major order, one band of tiles computed at a time."""
        for r0 in range(0, self.size, _TILE):
            band = self.band(which, r0, min(r0 + _TILE, self.size))
            for c0 in range(0, self.size, _TILE):
                tile = np.zeros((_TILE, _TILE), np.uint8)
                part = band[:, c0:c0 + _TILE]
                tile[:part.shape[0], :part.shape[1]] = part
                yield tile

    def write(self, folder: str | os.PathLike[str]) -> tuple[str, str]:
        """Write A.tif and B.tif (tiled, uncompressed) into ``folder``; their paths."""
        paths = []
        for which in ("a", "b"):
            path = os.path.join(folder, f"{which.upper()}.tif")
            tifffile.imwrite(path, self.tiles(which), shape=(self.size, self.size), dtype=np.uint8,
                             tile=(_TILE, _TILE), photometric="minisblack", metadata=None,
                             bigtiff=self.size * self.size > 3 * 2**30)
            paths.append(path)
        return paths[0], paths[1]
