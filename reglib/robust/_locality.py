"""Neighbourhood consistency of putative matches: a locality prior for the first estimate, and
the residual agreement that tells a steep local deformation from false matches.

A true match keeps its neighbourhood: under any smooth one-to-one motion (a rotation by 180
degrees, a threefold scale change, a strong non-rigid field alike), most of the K nearest
neighbours of x_i among the src points are, as matches, also among the K nearest neighbours of
y_i among the dst points; for a false match the two neighbourhoods are unrelated. This is the
topological term of Locality Preserving Matching (Ma, Zhao, Jiang, Zhou, Guo, IJCV 2019) and of
its guided form GLPM, averaged over three scales K as there. It needs no model and no start, is
invariant to any similarity or smooth warp of either set and deterministic, which is what the
RKHS estimators lack: they start from the identity and descend to the nearest optimum.

A field estimate can miss a steep local deformation (a part of the scene pushed far, over a short
distance, from where a smooth field would put it). Its true matches are then far from the field,
like false ones, but their residuals agree with their neighbours' residuals (the deformation is
smooth on their own scale), while false matches' residuals are spread over the whole image
(:func:`agreeing_far`).

Everything is in normalized coordinates on trusted arrays (validated upstream).

References
----------
.. [1] J. Ma, J. Zhao, J. Jiang, H. Zhou, X. Guo, "Locality Preserving Matching", Int. J. Computer
       Vision 127(5), 2019. :doi:`10.1007/s11263-018-1117-z`
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["CANDIDATE_R2", "EXPLAINED_R2", "SCALES", "agreeing_far", "neighborhood_consistency"]

SCALES = (4, 6, 8)  # the multi-scale K of LPM's demo (K - 2, K, K + 2 for K = 6)
# agreeing_far: neighbours looked at, and how many of them must agree. A false match's residual falls within the
# tolerance below of another's with probability about (area of the tolerance disc) / (the image's area in
# normalized units), well under 1 % for neighbours a few match spacings away: three of eight agreeing by
# chance is then below about 1e-5 per match.
# squared residuals, in units of the true matches' residual variance: beyond CANDIDATE_R2 (4 spreads) a match is
# outside the estimator's candidate radius (*far*), within EXPLAINED_R2 (3 spreads) the field explains it
CANDIDATE_R2 = 16.0
EXPLAINED_R2 = 9.0
_AGREE_K = 8
_AGREE_MIN = 3
# ... the residual field may change by this much per unit of distance between neighbours (a local stretch of
# 50 %: strongly bent fields have local Jacobian determinants far from 1)
_AGREE_GRADIENT = 0.5


def _knn(points: np.ndarray, k: int, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(R, k) distances and indices of the k nearest other points of ``points[rows]`` (all rows when None),
    nearest first."""
    rows = np.arange(len(points)) if rows is None else rows
    dist, idx = cKDTree(points).query(points[rows], k=k + 1)
    dist, idx = np.asarray(dist).reshape(len(rows), k + 1), np.asarray(idx).reshape(len(rows), k + 1)
    own = idx == rows[:, None]
    if own[:, 0].all():  # the usual case: each point is its own nearest
        return dist[:, 1:], idx[:, 1:]
    # Where duplicates tie, the point itself may be elsewhere (or beyond k): drop it, keep k.
    first = np.where(own.any(1), own.argmax(1), k)
    keep = np.ones_like(own)
    keep[np.arange(len(rows)), first] = False
    return dist[keep].reshape(len(rows), k), idx[keep].reshape(len(rows), k)


def neighborhood_consistency(u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Share of each match's src neighbours that are also its dst neighbours, in [0, 1].

    The mean over K in :data:`SCALES` of |N_K(x_i) & N_K(y_i)| / K, neighbours as match indices.
    Fewer matches than the largest K + 2 give all zeros (no neighbourhood to compare).
    """
    n = len(u)
    kmax = SCALES[-1]
    if n < kmax + 2:
        return np.zeros(n)
    nx, ny = _knn(u, kmax)[1], _knn(y, kmax)[1]
    # same[i, a, b]: the a-th src neighbour of i is its b-th dst neighbour.
    same = nx[:, :, None] == ny[:, None, :]
    score = np.zeros(n)
    for k in SCALES:
        score += same[:, :k, :k].sum((1, 2)) / k
    return score / len(SCALES)


def agreeing_far(u: np.ndarray, residuals: np.ndarray, e2: np.ndarray, spread2: float) -> np.ndarray:
    """(N,) bool: matches far from a field estimate whose residuals agree with their neighbours'.

    A match is *far* when its squared residual ``e2`` is at least 16 ``spread2`` (4 of the true matches'
    residual spreads, the estimators' candidate radius). A far match is marked when, among its 8 nearest
    matches in ``u``, at least 3 are far as well and have a residual vector within 3 spreads plus 0.5 times
    their distance of its own, and when those agreeing neighbours are at least twice as many as the neighbours
    the field explains (within 3 spreads): where the field already explains most matches, a far group agreeing
    with itself is a wrong one (a look-alike a texture period away), not a missed deformation.

    Parameters
    ----------
    u : (N, D) ndarray
        The matches' sources.
    residuals : (N, D) ndarray
        Their targets less the field's predictions.
    e2 : (N,) ndarray
        The squared norms of ``residuals``.
    spread2 : float
        The true matches' residual variance (per coordinate) under the field.
    """
    n = len(u)
    out = np.zeros(n, bool)
    far = e2 >= CANDIDATE_R2 * spread2
    rows = np.flatnonzero(far)
    if len(rows) <= _AGREE_MIN or n <= _AGREE_K:
        return out
    dist, idx = _knn(u, _AGREE_K, rows)
    gap = np.linalg.norm(residuals[idx] - residuals[rows][:, None, :], axis=2)
    agree = far[idx] & (gap <= 3.0 * np.sqrt(spread2) + _AGREE_GRADIENT * dist)
    n_agree = agree.sum(1)
    explained = (e2[idx] < EXPLAINED_R2 * spread2).sum(1)
    out[rows] = (n_agree >= _AGREE_MIN) & (n_agree >= 2 * explained)
    return out
