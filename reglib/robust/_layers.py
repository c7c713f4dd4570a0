"""A second, independently moving layer among the matches one smooth field rejected.

A smooth field cannot follow a scene part that moves differently from its surroundings (an
object in front of a far background, a depth discontinuity in a wide-baseline pair): its true
matches are rejected along with the false ones. Such a layer shows up among the rejected matches
as a tight cluster of displacement vectors (a region moving by a translation relative to the
camera), which uniformly scattered false matches only form by chance.
The densest cluster is found by hashing the displacement vectors on a grid. A part that turns as it
moves has no common displacement; in 2-D, when the hashing finds no layer, pairs of rejected matches
that are near neighbours in the source each propose a similarity, and the one most matches agree
with is the seed instead. The seed is refined by an affine fit
to its members, and kept only when it has more members than chance would give many times over,
and when it occupies a region of its own in the source: a separately moving part is a patch of
the image that the primary field does not cover, not points scattered among its inliers.

Everything is in normalized coordinates on trusted arrays (validated upstream).
"""
from __future__ import annotations

from dataclasses import dataclass
from math import gamma as gamma_fn
from math import log, pi, sqrt

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from ._core import mixture_posterior

__all__ = ["Layer", "LayerRule", "secondary_layer"]


@dataclass(frozen=True)
class Layer:
    """Members (indices into the matches) of a secondary layer, their scores and its affine map."""

    members: np.ndarray
    scores: np.ndarray
    affine: np.ndarray  # (D, D+1) = [A | t]


def _ball_volume(radius: float, d: int) -> float:
    return pi ** (d / 2) / gamma_fn(d / 2 + 1) * radius**d


def _densest_cell(vectors: np.ndarray, cell: float) -> np.ndarray:
    """Indices of the vectors in the most populated grid cell, over two grids shifted by half a cell
    (of equally populated cells, the first in the order of their keys)."""
    best = np.zeros(0, dtype=np.intp)
    for shift in (0.0, 0.5):
        keys = np.floor(vectors / cell + shift).astype(np.int64)
        keys -= keys.min(0)
        span = keys.max(0) + 1
        if np.prod(span.astype(float)) < 2**62:  # every cell numbered by one int64: runs of sorted ids
            ids = np.ravel_multi_index(tuple(keys.T), tuple(span))
            ordered = np.sort(ids)
            bounds = np.concatenate(([0], np.flatnonzero(ordered[1:] != ordered[:-1]) + 1, [len(ordered)]))
            runs = np.diff(bounds)
            top = int(np.argmax(runs))
            if runs[top] > len(best):
                best = np.flatnonzero(ids == ordered[bounds[top]])
        else:  # absurdly spread displacements: unique rows
            _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
            top = int(np.argmax(counts))
            if counts[top] > len(best):
                best = np.flatnonzero(inverse.ravel() == top)
    return best


def _affine_fit(u: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    design = np.c_[u, np.ones(len(u))]
    if np.linalg.matrix_rank(design) < design.shape[1]:
        return None
    theta = np.linalg.lstsq(design, y, rcond=None)[0]  # (D+1, D)
    if not np.isfinite(theta).all() or np.linalg.det(theta[:-1]) <= 0:
        return None  # an orientation-reversing layer is not a plausible motion
    return np.ascontiguousarray(theta.T)


# Largest share of primary inliers among the inliers inside a layer's hull (in the source): a
# separately moving region is where the layer's motion holds the majority; look-alikes scattered
# among the primary inliers span a hull that the primary fills.
_REGION_SHARE = 0.5


def _own_region(members: np.ndarray, primary: np.ndarray) -> bool:
    """Whether the source points ``members`` (K, D) hold the majority of their hull against ``primary`` (P, D)."""
    if len(primary) == 0:
        return True
    hull = Delaunay(members, qhull_options="QJ")  # joggled: a flat layer still gets a (thin) hull
    inside = np.count_nonzero(hull.find_simplex(primary) >= 0)
    return bool(inside <= _REGION_SHARE * (inside + len(members)))


@dataclass(frozen=True, slots=True, kw_only=True)
class LayerRule:
    """What a secondary layer must satisfy: the primary decision's rules, and its refinement steps.

    Attributes
    ----------
    min_matches : int
        Fewest members a layer may have.
    score_scale, threshold : float
        As for the primary decision: the posterior widens sigma by ``score_scale`` and a member's
        score must exceed ``threshold``.
    n_refine : int
        Re-fits of the layer's affine map to its members.
    """

    min_matches: int
    score_scale: float
    threshold: float
    n_refine: int = 3


def secondary_layer(u: np.ndarray, y: np.ndarray, vectors: np.ndarray, search: np.ndarray, rejected: np.ndarray,
                    sigma2: float, volume: float, rule: LayerRule) -> Layer | None:
    """Find one more coherent layer among the ``rejected`` matches, or None.

    Parameters
    ----------
    u, y : (N, D) ndarray
        Normalized matches.
    vectors : (S, D) ndarray
        Displacements of the matches in ``search``, in the units of ``y``.
    search : (S,) ndarray of int
        Rejected matches the seed cluster is looked for in (a bounded subset of ``rejected``).
    rejected : (K,) ndarray of int
        Indices of all the matches the primary fit rejected; the layer's members are drawn from these.
    sigma2 : float
        Residual variance of the primary fit's true matches; the layer's matches must agree with
        its affine map as tightly (radius 3 sigma).
    volume : float
        Extent of the dst points (the false matches' residuals spread over about this volume).
    rule : LayerRule
        Fewest members, score scale and threshold, refinement steps.

    Returns
    -------
    Layer or None
        None when no layer stands out from chance, or when it lies among the primary inliers
        (the matches not ``rejected``) rather than in a region of its own.
    """
    d = u.shape[1]
    if len(search) < max(rule.min_matches, d + 2):
        return None
    radius = 3.0 * sqrt(sigma2)
    # Cells as wide as the layer's matches may be apart (2 radii): a cluster of them lies whole in
    # one of the shifted grids; chance members of such a cell are counted with its volume.
    cell = 2.0 * radius
    seed = _densest_cell(vectors, cell)
    chance = len(search) * cell**d / volume
    layer = None
    if len(seed) >= max(rule.min_matches, chance + 5.0 * sqrt(chance) + 1.0):
        layer = _grown(u, y, search[seed], rejected, sigma2, volume, rule)
    if layer is None and d == 2:
        # A part that turns as it moves has no common displacement to hash: its matches agree on
        # a similarity instead.
        turned = _similarity_seed(u, y, search, rejected, radius, volume, rule.min_matches)
        if turned is not None:
            layer = _grown(u, y, turned, rejected, sigma2, volume, rule)
    return layer


# Source neighbours each match is paired with to propose a similarity: the matches of one part lie
# close together, so a match and one of its nearest neighbours are often of the same part.
_PAIR_NEIGHBOURS = 4
# Source neighbours a proposal is first scored on: a part is a region, so its support is local
# (only the best proposal is checked against all the rejected matches).
_SUPPORT_NEIGHBOURS = 32
# Most matches that propose (evenly spaced among the searched ones): bounds the work on large sets.
_MAX_PROPOSERS = 2000


def _similarity_seed(u: np.ndarray, y: np.ndarray, search: np.ndarray, rejected: np.ndarray, radius: float,
                     volume: float, min_matches: int) -> np.ndarray | None:
    """The ``rejected`` matches (2-D) within ``radius`` of the best similarity proposed by pairs of
    near neighbours among ``search``, or None when it has no more of them than chance would give
    over all the proposals tried."""
    us, ys = u[search], y[search]
    support = min(_SUPPORT_NEIGHBOURS, len(search))
    rows = np.linspace(0, len(search) - 1, min(len(search), _MAX_PROPOSERS)).astype(np.intp)
    near = np.asarray(cKDTree(us).query(us[rows], k=support)[1], dtype=np.intp).reshape(len(rows), support)
    a = us[:, 0] + 1j * us[:, 1]
    b = ys[:, 0] + 1j * ys[:, 1]
    per_row = min(_PAIR_NEIGHBOURS, support - 1)
    which = np.repeat(np.arange(len(rows)), per_row)  # the proposing row of each pair
    first, second = rows[which], near[:, 1:per_row + 1].ravel()
    apart = a[second] - a[first]
    # A pair fixes a turn only when its dst points lie further apart than noise could put them
    # (two matches of one dst point, a common false pattern, would propose a collapse to a point).
    ok = (np.abs(apart) > 0) & (np.abs(b[second] - b[first]) > 2.0 * radius)
    which, first, second, apart = which[ok], first[ok], second[ok], apart[ok]
    if len(first) == 0:
        return None
    turn = (b[second] - b[first]) / apart  # scale times rotation, as one complex number
    shift = b[first] - turn * a[first]
    local = near[which]
    miss = b[local] - turn[:, None] * a[local] - shift[:, None]
    agree = miss.real**2 + miss.imag**2 < radius * radius
    best = int(np.argmax(agree.sum(1)))
    va = u[rejected, 0] + 1j * u[rejected, 1]
    vb = y[rejected, 0] + 1j * y[rejected, 1]
    members = rejected[np.abs(vb - turn[best] * va - shift[best]) < radius]
    # Chance members of one proposal, beyond the pair that made it; the margin grows with the
    # number of proposals tried (a Gaussian tail bound times their number).
    chance = (len(rejected) - 2) * _ball_volume(radius, 2) / volume
    margin = sqrt(25.0 + 2.0 * log(len(first)))
    if len(members) - 2 < max(min_matches, chance + margin * sqrt(chance) + 1.0):
        return None
    return members


def _grown(u: np.ndarray, y: np.ndarray, members: np.ndarray, rejected: np.ndarray, sigma2: float,
           volume: float, rule: LayerRule) -> Layer | None:
    """The layer grown from the seed ``members`` by re-fitting its affine map, or None when it does
    not stand out from chance or lies among the primary inliers."""
    min_matches, score_scale, threshold, n_refine = rule.min_matches, rule.score_scale, rule.threshold, rule.n_refine
    d = u.shape[1]
    k = len(rejected)
    radius = 3.0 * sqrt(sigma2)

    def needed(count: int) -> float:
        # Matches whose residual would land within `radius` of a given one by chance, among `count`.
        chance = count * _ball_volume(radius, d) / volume
        return max(min_matches, chance + 5.0 * sqrt(chance) + 1.0)

    affine = None
    e2 = np.zeros(k)
    for _ in range(n_refine):
        fitted = _affine_fit(u[members], y[members])
        if fitted is None:
            return None
        affine = fitted
        e2 = ((y[rejected] - u[rejected] @ affine[:, :d].T - affine[:, d]) ** 2).sum(1)
        now = rejected[e2 < radius * radius]
        if len(now) < needed(k):
            return None
        if np.array_equal(now, members):
            break
        members = now
    assert affine is not None
    share = float(np.clip(len(members) / k, 1e-3, 1.0 - 1e-3))
    scores = mixture_posterior(e2, sigma2 * score_scale**2, share, d, volume)
    keep = scores > threshold
    if np.count_nonzero(keep) < needed(k):
        return None
    primary = np.ones(len(u), dtype=bool)
    primary[rejected] = False
    if not _own_region(u[rejected[keep]], u[primary]):
        return None
    return Layer(members=rejected[keep], scores=scores[keep], affine=affine)
