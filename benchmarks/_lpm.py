"""Locality Preserving Matching (LPM), a benchmark peer written from the paper.

J. Ma, J. Zhao, J. Jiang, H. Zhou, X. Guo, "Locality Preserving Matching", IJCV 127(5), 2019
(doi:10.1007/s11263-018-1117-z), with the defaults of the authors' demo (``demo_LPM_v2``):

* A true match keeps its neighbourhood: most of the K nearest neighbours of x_i among the src
  points are, as matches, also among the K nearest neighbours of y_i among the dst points.
* The cost of match i at one scale K is (c1 + c2) / K, with c1 = K - n_i (n_i the neighbours the
  two K-NN sets share) and c2 the shared neighbours j whose motion v_j = y_j - x_j disagrees with
  v_i: s(v_i, v_j) = cos(v_i, v_j) * min(|v_i|^2, |v_j|^2) / max(|v_i|^2, |v_j|^2) < tau.
* Multi-scale: the cost is averaged over K + 2, K, K - 2; a match is kept when it is <= lambda.
* Two iterations: the first with the neighbourhoods among all matches (lambda 0.8), the second
  with the neighbourhoods among the matches the first kept (lambda 0.5); K = 6 and tau = 0.2
  in both.

The demo truncates its neighbour lists cumulatively across the scales (each scale also drops the
previous one's nearest neighbour); this version uses the K nearest at every scale, as the paper
describes.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["lpm_filter"]


def _cost(nx: np.ndarray, ny: np.ndarray, vec: np.ndarray, k: int, tau: float) -> np.ndarray:
    """Multi-scale locality cost of every match; ``nx``, ``ny`` (N, >= k + 2) neighbour indices, self excluded."""
    n = len(vec)
    d2 = (vec * vec).sum(1)
    total = np.zeros(n)
    scales = (k + 2, k, k - 2)
    for kk in scales:
        a, b = nx[:, :kk], ny[:, :kk]
        # shared neighbours: entries of a that are also in b (row by row)
        shared = (a[:, :, None] == b[:, None, :]).any(2)  # (N, kk)
        ni = shared.sum(1)
        vj, d2j = vec[a], d2[a]
        dot = (vj * vec[:, None, :]).sum(2)
        denom = np.sqrt(d2j * d2[:, None])
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.where(denom > 0, dot / np.where(denom > 0, denom, 1.0), 1.0)
            ratio = np.where(np.maximum(d2j, d2[:, None]) > 0,
                             np.minimum(d2j, d2[:, None]) / np.maximum(np.maximum(d2j, d2[:, None]), 1e-300), 1.0)
        c2 = (shared & (cos * ratio < tau)).sum(1)
        total += (kk - ni + c2) / kk
    return total / len(scales)


def _neighbours(points: np.ndarray, among: np.ndarray, k: int) -> np.ndarray:
    """Indices (into ``among``) of the k nearest of ``among``'s points to each point, the first hit dropped."""
    tree = cKDTree(points[among])
    kq = min(k + 1, len(among))
    _, idx = tree.query(points, k=kq)
    idx = np.asarray(idx).reshape(len(points), kq)
    return among[idx[:, 1:]]


def lpm_filter(src: np.ndarray, dst: np.ndarray, *, k: tuple[int, int] = (6, 6),
               lam: tuple[float, float] = (0.8, 0.5), tau: tuple[float, float] = (0.2, 0.2)) -> np.ndarray:
    """Boolean mask of the matches LPM keeps (two iterations, the demo's defaults)."""
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    n = len(src)
    if n < k[0] + 4:
        return np.zeros(n, bool)
    vec = dst - src
    everyone = np.arange(n)
    kmax = k[0] + 2
    keep = _cost(_neighbours(src, everyone, kmax), _neighbours(dst, everyone, kmax), vec, k[0], tau[0]) <= lam[0]
    idx = np.flatnonzero(keep)
    if len(idx) >= k[1] + 4:
        kmax = k[1] + 2
        # Neighbours among the kept matches, for every match; the nearest hit (itself when kept) is dropped.
        keep = _cost(_neighbours(src, idx, kmax), _neighbours(dst, idx, kmax), vec, k[1], tau[1]) <= lam[1]
    return keep
