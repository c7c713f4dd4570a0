"""Edge points: a contour or silhouette image as a point set (the input of shape-context matching)."""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["edge_points"]


def edge_points(gray: np.ndarray, n_points: int, mask: np.ndarray | None = None) -> np.ndarray:
    """About ``n_points`` (x, y) points spread evenly along the edges of a grey uint8 image.

    Edges are Canny's (thresholds from the median grey level, after a light blur); the edge
    curves (``cv2.findContours``) are concatenated and sampled at equal steps of their total length.
    """
    if min(gray.shape) < 3:
        return np.zeros((0, 2))
    blur = cv2.GaussianBlur(gray, (5, 5), 1.0)
    med = float(np.median(blur))
    lo, hi = max(0.0, 0.66 * med), min(255.0, 1.33 * med)
    if hi - lo < 20:  # near-black or near-white backgrounds (silhouettes): fixed thresholds
        lo, hi = 50.0, 150.0
    edges = cv2.Canny(blur, lo, hi)
    if mask is not None:
        edges[~mask] = 0
    contours, _ = cv2.findContours(edges, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float64)
    # findContours walks each thin edge curve twice (both sides): drop repeated pixels
    _, first = np.unique(pts, axis=0, return_index=True)
    pts = pts[np.sort(first)]
    if len(pts) <= n_points:
        return pts
    idx = np.linspace(0, len(pts) - 1, n_points).round().astype(np.intp)
    return pts[idx]
