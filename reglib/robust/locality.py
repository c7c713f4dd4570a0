"""Neighbourhood consistency of putative matches: a locality prior for the first estimate.

A true match keeps its neighbourhood: under any smooth one-to-one motion (a rotation by 180
degrees, a threefold scale change, a strong non-rigid field alike), most of the K nearest
neighbours of x_i among the src points are, as matches, also among the K nearest neighbours of
y_i among the dst points; for a false match the two neighbourhoods are unrelated. This is the
topological term of Locality Preserving Matching (Ma, Zhao, Jiang, Zhou, Guo, IJCV 2019) and of
its guided form GLPM, averaged over three scales K as there. It needs no model and no start, is
invariant to any similarity or smooth warp of either set and deterministic, which is what the
RKHS estimators lack: they start from the identity and descend to the nearest optimum.

Everything is in normalized coordinates on trusted arrays (validated upstream).

References
----------
.. [1] J. Ma, J. Zhao, J. Jiang, H. Zhou, X. Guo, "Locality Preserving Matching", Int. J. Computer
       Vision 127(5), 2019. :doi:`10.1007/s11263-018-1117-z`
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["SCALES", "neighborhood_consistency"]

SCALES = (4, 6, 8)  # the multi-scale K of LPM's demo (K - 2, K, K + 2 for K = 6)


def _knn(points: np.ndarray, k: int) -> np.ndarray:
    """(N, k) indices of each point's k nearest other points (nearest first)."""
    _, idx = cKDTree(points).query(points, k=k + 1)
    idx = np.asarray(idx).reshape(len(points), k + 1)
    own = idx == np.arange(len(points))[:, None]
    if own[:, 0].all():  # the usual case: each point is its own nearest
        return idx[:, 1:]
    # Where duplicates tie, the point itself may be elsewhere (or beyond k): drop it, keep k.
    first = np.where(own.any(1), own.argmax(1), k)
    keep = np.ones_like(own)
    keep[np.arange(len(points)), first] = False
    return idx[keep].reshape(len(points), k)


def neighborhood_consistency(u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Share of each match's src neighbours that are also its dst neighbours, in [0, 1].

    The mean over K in :data:`SCALES` of |N_K(x_i) & N_K(y_i)| / K, neighbours as match indices.
    Fewer matches than the largest K + 2 give all zeros (no neighbourhood to compare).
    """
    n = len(u)
    kmax = SCALES[-1]
    if n < kmax + 2:
        return np.zeros(n)
    nx, ny = _knn(u, kmax), _knn(y, kmax)
    # same[i, a, b]: the a-th src neighbour of i is its b-th dst neighbour.
    same = nx[:, :, None] == ny[:, None, :]
    score = np.zeros(n)
    for k in SCALES:
        score += same[:, :k, :k].sum((1, 2)) / k
    return score / len(SCALES)
