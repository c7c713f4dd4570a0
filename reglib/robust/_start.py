"""Deterministic first estimates for the coarse L2E level: a consensus over a few starts.

L2E anneals sigma from a wide start, but it still descends to the optimum nearest its first
estimate; from the identity (the published start) that fails for a large rotation, and when the
true matches are a minority, from a fit dominated by false ones. Here a few candidate starts are
made from the data alone and the one with the best L2E criterion (the sum of phi) at the
annealing's last width is kept (at the first width, a wide kernel sums over many false matches,
which swamp a minority of true ones):

* the identity (the published start);
* a solve weighted by the locality prior (:mod:`reglib.robust._locality`), good when most
  consistent neighbourhoods are true matches;
* the best of the similarities through pairs (2-D) or triples (3-D) of the matches with the
  most consistent neighbourhoods, scored by the same criterion, good when the prior is weak
  (a threefold zoom, where the dst neighbourhoods of the true matches are mostly false matches)
  but some of its best matches are true: a RANSAC whose hypotheses are drawn, in a fixed order,
  from the locality ranking instead of at random.

Everything is in normalized coordinates on trusted arrays (validated upstream).
"""
from __future__ import annotations

from functools import cache
from itertools import combinations

import numpy as np

from .._geometry import signed_svd

__all__ = ["best_similarity_weights"]

# Top-ranked matches the hypotheses are drawn from: all pairs of 16 (120) in 2-D, all triples of
# 10 (120) in 3-D.
_TOP = {2: 16, 3: 10}
# Matches each hypothesis is scored on, at most.
_PROBE = 128


def _similarities(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares similarities q ~ s R p + t for a batch of small point sets (Umeyama 1991).

    p, q: (H, k, D). Returns (H, D, D) matrices s R and (H, D) translations; a degenerate set
    (coincident points) gives a zero matrix.
    """
    pm, qm = p.mean(1, keepdims=True), q.mean(1, keepdims=True)
    pc, qc = p - pm, q - qm
    cov = np.einsum("hki,hkj->hij", qc, pc)  # sum_k q_k p_k^T
    u, sv, vt = signed_svd(cov)  # a proper rotation (no reflection), signed singular values
    rot = u @ vt
    var = (pc * pc).sum((1, 2))
    scale = np.where(var > 1e-24, sv.sum(1) / np.where(var > 1e-24, var, 1.0), 0.0)
    mat = scale[:, None, None] * rot
    t = qm[:, 0] - np.einsum("hij,hj->hi", mat, pm[:, 0])
    return mat, t


def _similarities_2d(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The similarities through pairs of 2-D matches in closed form: as complex numbers,
    q = a p + b with a = (q1 - q0) / (p1 - p0) (a rotation and a scale), b = q0 - a p0.
    p, q: (H, 2, 2). A pair of coincident src points gives a zero matrix."""
    pc = p[:, :, 0] + 1j * p[:, :, 1]
    qc = q[:, :, 0] + 1j * q[:, :, 1]
    dp = pc[:, 1] - pc[:, 0]
    ok = np.abs(dp) > 1e-12
    a = np.where(ok, (qc[:, 1] - qc[:, 0]) / np.where(ok, dp, 1.0), 0.0)
    b = qc[:, 0] - a * pc[:, 0]
    mat = np.empty((len(a), 2, 2))
    mat[:, 0, 0] = mat[:, 1, 1] = a.real
    mat[:, 0, 1] = -a.imag
    mat[:, 1, 0] = a.imag
    return mat, np.stack([b.real, b.imag], 1)


@cache
def _index_sets(count: int, k: int) -> np.ndarray:
    """(H, k) all k-subsets of range(count) in the order of itertools.combinations (read-only)."""
    sets = np.array(list(combinations(range(count), k)), dtype=np.intp).reshape(-1, k)
    sets.flags.writeable = False
    return sets


@cache
def _probe_rows(n: int) -> np.ndarray:
    """At most _PROBE evenly spaced rows of n (read-only)."""
    rows = np.linspace(0, n - 1, min(n, _PROBE)).astype(np.intp)
    rows.flags.writeable = False
    return rows


def best_similarity_weights(u: np.ndarray, y: np.ndarray, prior: np.ndarray, sigma2: float) -> np.ndarray | None:
    """phi_i = exp(-|y_i - S(u_i)|^2 / 2 sigma2) under the best similarity S through the top-ranked
    matches (the one with the largest sum of phi), or None when there are too few of them."""
    n, d = u.shape
    top = _TOP.get(d, 10)
    k = 2 if d == 2 else 3
    ranked = np.argsort(-prior, kind="stable")[:top]
    ranked = ranked[prior[ranked] > 0]
    if len(ranked) < k:
        return None
    sets = ranked[_index_sets(len(ranked), k)]  # (H, k), a fixed order
    if d == 2:
        mat, t = _similarities_2d(u[sets], y[sets])
    else:
        mat, t = _similarities(u[sets], y[sets])
    # Hypotheses are ranked on an evenly spaced subset of the matches (a scalar criterion needs
    # no more), then the best one's phi is computed for all of them. One (H, P) plane per
    # coordinate: e_j = sum_i mat_ji u_i + t_j - y_j.
    probe = _probe_rows(n)
    up, yp = u[probe].T, y[probe].T  # (D, P)
    e2 = np.zeros((len(mat), len(probe)))
    for j in range(d):
        e = np.multiply.outer(mat[:, j, 0], up[0])
        for i in range(1, d):
            e += np.multiply.outer(mat[:, j, i], up[i])
        e += t[:, j, None]
        e -= yp[j]
        e *= e
        e2 += e
    e2 *= -0.5 / sigma2
    best = int(np.argmax(np.exp(e2, out=e2).sum(1)))
    e2_best = ((u @ mat[best].T + t[best] - y) ** 2).sum(1)
    e2_best /= -2.0 * sigma2
    return np.exp(e2_best, out=e2_best)
