"""Shape context descriptors for 2-D point sets, their chi^2 cost and one-to-one matching.

For a point p_i the descriptor is the histogram of the other points' positions relative to p_i
in log-polar bins (Belongie, Malik & Puzicha [1]): ``n_angle`` angle bins times ``n_radius``
radius bins whose outer edges are spaced evenly in log r from ``r_inner`` to ``r_outer`` times
the mean pairwise distance (the innermost bin is the disc r < r_inner; points beyond r_outer are
not counted). Dividing by the mean distance makes the descriptor scale invariant.

Points are (x, y); angles are measured from the +x axis towards +y.

Histogram layout: a row of length ``n_radius * n_angle``, radius-major (bin index
``r * n_angle + a``), normalized to sum 1 (a point with no neighbour in range keeps all zeros).
Rotating the point set by ``2 pi k / n_angle`` shifts the angle bins by k: use
:func:`rotate_bins` to compare descriptors under rotation hypotheses without recomputing them.

References
----------
.. [1] S. Belongie, J. Malik, J. Puzicha, "Shape Matching and Object Recognition Using Shape
       Contexts", IEEE TPAMI 24(4), 2002. :doi:`10.1109/34.993558`
"""
from __future__ import annotations

from typing import Any

import numpy as np
import scipy.optimize
from scipy.spatial.distance import cdist, pdist

from .._validation import as_points, check_int, check_range
from ..errors import InputError

__all__ = ["chi2_cost", "match_shape_contexts", "rotate_bins", "shape_context"]



def shape_context(points: Any, *, n_angle: int = 12, n_radius: int = 5, r_inner: float = 0.125,
                  r_outer: float = 2.0, rotation_invariant: bool = False,
                  mean_distance: float | None = None, support: Any = None) -> np.ndarray:
    """Log-polar shape context histogram of every point of a 2-D point set.

    Parameters
    ----------
    points : (N, 2) array_like
        Points (x, y).
    n_angle, n_radius : int
        Number of angle and radius bins (12 and 5 in [1]).
    r_inner, r_outer : float
        Outer edge of the innermost and of the outermost radius bin, in units of the mean
        pairwise distance (1/8 and 2 in [1]).
    rotation_invariant : bool
        Measure each point's angles from its own reference direction, the direction to the
        centroid of the set, instead of the +x axis. The descriptors then do not change when the
        set is rotated (they do change when parts are missing or outliers move the centroid).
    mean_distance : float, optional
        Length unit for the radius bins; by default the mean pairwise distance of ``points``.
        Pass the same value for two sets to compare them at a common scale.
    support : (N,) bool array_like, optional
        Only these points are counted in the histograms (every point still gets one); e.g. the
        points believed not to be outliers. Default: all points.

    Returns
    -------
    (N, n_radius * n_angle) ndarray
        Normalized histograms, radius-major. N = 0 gives a (0, n_radius * n_angle) array.

    Raises
    ------
    InputError
        When ``points`` is not (N, 2) finite numbers or a parameter is out of range.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    >>> h = shape_context(np.c_[np.cos(t), np.sin(t)])
    >>> h.shape, bool(np.allclose(h.sum(1), 1.0))
    ((30, 60), True)
    """
    pts = as_points(points, "points", dims=(2,))
    n_angle = check_int("n_angle", n_angle)
    n_radius = check_int("n_radius", n_radius)
    check_range("r_inner", r_inner, 0, low_open=True)
    check_range("r_outer", r_outer, 0, low_open=True)
    if r_outer <= r_inner:
        raise InputError(f"`r_outer` must be > `r_inner` ({r_inner!r}), got {r_outer!r}")
    if mean_distance is not None:
        check_range("mean_distance", mean_distance, 0, low_open=True)
    mask = None
    if support is not None:
        mask = np.asarray(support)
        if mask.dtype != bool or mask.shape != (len(pts),):
            raise InputError(f"`support` must be a bool array of shape ({len(pts)},), got {mask.dtype} {mask.shape}")
    return _shape_context(pts, n_angle, n_radius, r_inner, r_outer, rotation_invariant, mean_distance, mask)


def _shape_context(pts: np.ndarray, n_angle: int, n_radius: int, r_inner: float, r_outer: float,
                   rotation_invariant: bool, mean_distance: float | None,
                   support: np.ndarray | None = None) -> np.ndarray:
    """:func:`shape_context` on trusted input (private; used by the registration loop)."""
    n = len(pts)
    n_bins = n_angle * n_radius
    if n == 0:
        return np.zeros((0, n_bins))
    others = pts if support is None else pts[support]
    if mean_distance is None:
        mean_distance = float(pdist(others).mean()) if len(others) > 1 else 1.0
        if mean_distance <= 0:  # all points coincide: any unit will do
            mean_distance = 1.0
    dist = cdist(pts, others) / mean_distance
    dx = others[None, :, 0] - pts[:, None, 0]  # row i: offsets of every counted point from point i
    dy = others[None, :, 1] - pts[:, None, 1]
    theta = np.arctan2(dy, dx)
    if rotation_invariant:
        to_centroid = (others.mean(0) if len(others) else pts.mean(0)) - pts
        theta -= np.arctan2(to_centroid[:, 1], to_centroid[:, 0])[:, None]
    a_bin = np.floor(np.mod(theta, 2 * np.pi) * (n_angle / (2 * np.pi))).astype(np.intp)
    np.minimum(a_bin, n_angle - 1, out=a_bin)  # mod can round up to exactly 2 pi
    edges = np.geomspace(r_inner, r_outer, n_radius)
    r_bin = np.searchsorted(edges, dist, side="right")
    keep = (r_bin < n_radius) & (dist > 0)  # coincident points (self included) carry no direction
    rows = np.broadcast_to(np.arange(n)[:, None], keep.shape)[keep]
    flat = rows * n_bins + r_bin[keep] * n_angle + a_bin[keep]
    hist = np.bincount(flat, minlength=n * n_bins).reshape(n, n_bins).astype(np.float64)
    total = hist.sum(1, keepdims=True)
    np.divide(hist, total, out=hist, where=total > 0)
    return hist


def rotate_bins(hist: Any, steps: int, *, n_angle: int = 12) -> np.ndarray:
    """Descriptors of the set rotated by ``2 pi steps / n_angle`` (counter-clockwise, +x to +y).

    Parameters
    ----------
    hist : (N, n_radius * n_angle) array_like
        Histograms from :func:`shape_context` with ``rotation_invariant=False``.
    steps : int
        Rotation in angle bins.
    n_angle : int
        The ``n_angle`` the histograms were computed with.

    Returns
    -------
    (N, n_radius * n_angle) ndarray
    """
    h = np.asarray(hist, dtype=np.float64)
    n_angle = check_int("n_angle", n_angle)
    if h.ndim != 2 or h.shape[1] % n_angle:
        raise InputError(f"`hist` must have shape (N, n_radius * {n_angle}), got {h.shape}")
    n, k = h.shape
    return np.roll(h.reshape(n, k // n_angle, n_angle), int(steps), axis=2).reshape(n, k)


def chi2_cost(h1: Any, h2: Any) -> np.ndarray:
    """chi^2 distance between every pair of histograms, C_ij = 1/2 sum_k (a-b)^2 / (a+b), 0/0 = 0.

    Parameters
    ----------
    h1 : (N, K) array_like
    h2 : (M, K) array_like
        Non-negative histograms (rows summing to 1 give costs in [0, 1]).

    Returns
    -------
    (N, M) ndarray
        Computed bin by bin over the rows and columns where the bin is non-zero, so no
        (N, M, K) temporary is made.

    Examples
    --------
    >>> chi2_cost([[1.0, 0.0]], [[1.0, 0.0], [0.0, 1.0]])
    array([[0., 1.]])
    """
    a = np.asarray(h1, dtype=np.float64)
    b = np.asarray(h2, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InputError(f"`h1` (N, K) and `h2` (M, K) must share K, got {a.shape} and {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()) or (a < 0).any() or (b < 0).any():
        raise InputError("`h1` and `h2` must hold finite, non-negative numbers")
    return _chi2_cost(a, b)


def _chi2_cost(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # (x - y)^2 / (x + y) = x + y - 4 x y / (x + y): only bins where both histograms are non-zero
    # need the pairwise term, so loop over bins and touch just those rows and columns.
    out = 0.5 * (a.sum(1)[:, None] + b.sum(1)[None, :])
    for k in range(a.shape[1]):
        ia = np.flatnonzero(a[:, k])
        ib = np.flatnonzero(b[:, k])
        if len(ia) == 0 or len(ib) == 0:
            continue
        x = a[ia, k][:, None]
        y = b[ib, k][None, :]
        out[np.ix_(ia, ib)] -= 2.0 * x * y / (x + y)
    np.maximum(out, 0.0, out=out)  # rounding can leave -1e-17 for identical histograms
    return out


def match_shape_contexts(cost: Any, dummy_cost: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching by minimum total cost, where any point may stay unmatched.

    Solves the assignment problem on ``cost`` padded with dummy partners (the "dummy nodes" of
    [1]): leaving a point of either set unmatched costs ``dummy_cost``, so a pair (i, j)
    is only kept when matching it beats leaving both alone. Solved exactly by
    :func:`scipy.optimize.linear_sum_assignment` on the equivalent N x (M + N) problem.

    Parameters
    ----------
    cost : (N, M) array_like
        Matching cost between point i of set a and point j of set b (e.g. :func:`chi2_cost`).
    dummy_cost : float
        Cost of leaving one point unmatched (0.15 - 0.25 suits chi^2 of normalized histograms).

    Returns
    -------
    idx_a, idx_b : (K,) int ndarrays
        Matched pairs (idx_a[k], idx_b[k]), idx_a ascending. Empty input gives empty arrays.

    Examples
    --------
    >>> match_shape_contexts([[0.0, 1.0], [1.0, 0.05], [0.9, 0.9]], dummy_cost=0.2)
    (array([0, 1]), array([0, 1]))
    """
    c = np.asarray(cost, dtype=np.float64)
    if c.ndim != 2:
        raise InputError(f"`cost` must be a 2-D (N, M) array, got shape {c.shape}")
    if not np.isfinite(c).all():
        raise InputError("`cost` must hold only finite numbers")
    check_range("dummy_cost", dummy_cost, 0)
    return _match(c, float(dummy_cost))


def _match(c: np.ndarray, dummy_cost: float) -> tuple[np.ndarray, np.ndarray]:
    n, m = c.shape
    if n == 0 or m == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    # Square (N + M) form: pair (i, j) costs C_ij, an unmatched point of either set costs d, dummy
    # to dummy 0. With k pairs that totals sum C + d (N - k) + d (M - k); the N x (M + N) problem
    # below, whose dummy columns cost 2 d and whose columns may stay unused, has the same minimizer.
    padded = np.full((n, m + n), 2.0 * dummy_cost)
    padded[:, :m] = c
    rows, cols = scipy.optimize.linear_sum_assignment(padded)
    real = cols < m
    return rows[real].astype(np.intp), cols[real].astype(np.intp)
