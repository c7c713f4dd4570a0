"""3-D shape context: log-radius x elevation x azimuth histograms of the other points.

The 3-D analogue of Belongie et al.'s descriptor (Frome et al. [1] use the same binning for range
data): for point p_i, the other points' offsets q - p_i are binned by log radius (outer edges
spaced evenly in log r from ``r_inner`` to ``r_outer`` times the mean pairwise distance), by
elevation (cosine of the angle to +z, so the bins have equal solid angle) and by azimuth in the
x-y plane. Why this descriptor for :func:`reglib.register_points`: it needs no surface normals
(so it works on scattered landmarks as well as on surfaces), it is exactly the 2-D descriptor the
registration loop already uses with one more angle, and its dependence on orientation is handled
by the loop's rotation hypotheses (principal-axes frames), so no local reference frame, which is
fragile on noisy or sparse data, is needed.

Points are (x, y, z). Histogram layout: radius-major, index
``(r * n_elevation + e) * n_azimuth + a``, each row normalized to sum 1 (or all zero).

References
----------
.. [1] A. Frome, D. Huber, R. Kolluri, T. Buelow, J. Malik, "Recognizing Objects in Range Data
       Using Regional Point Descriptors", ECCV 2004. :doi:`10.1007/978-3-540-24672-5_18`
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.distance import cdist, pdist

from .._validation import as_points, check_int, check_range
from ..errors import InputError

__all__ = ["shape_context_3d"]

_BLOCK = 512  # rows per block: temporaries are (block, N)


def shape_context_3d(points: Any, *, n_azimuth: int = 8, n_elevation: int = 4, n_radius: int = 5,
                     r_inner: float = 0.125, r_outer: float = 2.0, support: Any = None) -> np.ndarray:
    """3-D shape context of every point of a (N, 3) point set.

    Parameters
    ----------
    points : (N, 3) array_like
        Points (x, y, z).
    n_azimuth, n_elevation, n_radius : int
        Number of bins in azimuth (x-y plane), in elevation (equal steps of cos, from +z to -z)
        and in log radius.
    r_inner, r_outer : float
        Outer edge of the innermost and outermost radius bins, in units of the mean pairwise
        distance of the counted points.
    support : (N,) bool array_like, optional
        Only these points are counted (every point still gets a histogram). Default: all.

    Returns
    -------
    (N, n_radius * n_elevation * n_azimuth) ndarray
        Normalized histograms. Memory is O(N * block), never (N, N, 3).

    Raises
    ------
    InputError
        When ``points`` is not (N, 3) finite numbers or a parameter is out of range.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.random.default_rng(0).normal(size=(50, 3))
    >>> shape_context_3d(pts).shape
    (50, 160)
    """
    pts = as_points(points, "points", dims=(3,))
    for name, value in (("n_azimuth", n_azimuth), ("n_elevation", n_elevation), ("n_radius", n_radius)):
        check_int(name, value)
    check_range("r_inner", r_inner, 0, low_open=True)
    check_range("r_outer", r_outer, 0, low_open=True)
    if r_outer <= r_inner:
        raise InputError(f"`r_outer` must be > `r_inner` ({r_inner!r}), got {r_outer!r}")
    mask = None
    if support is not None:
        mask = np.asarray(support)
        if mask.dtype != bool or mask.shape != (len(pts),):
            raise InputError(f"`support` must be a bool array of shape ({len(pts)},), got {mask.dtype} {mask.shape}")
    return _shape_context_3d(pts, int(n_azimuth), int(n_elevation), int(n_radius), r_inner, r_outer, mask)


def _shape_context_3d(pts: np.ndarray, n_azimuth: int, n_elevation: int, n_radius: int,
                      r_inner: float, r_outer: float, support: np.ndarray | None) -> np.ndarray:
    n = len(pts)
    n_bins = n_azimuth * n_elevation * n_radius
    if n == 0:
        return np.zeros((0, n_bins))
    others = pts if support is None else pts[support]
    unit = float(pdist(others).mean()) if len(others) > 1 else 1.0
    if unit <= 0:
        unit = 1.0
    edges = np.geomspace(r_inner, r_outer, n_radius)
    hist = np.zeros((n, n_bins))
    for s in range(0, n, _BLOCK):
        p = pts[s:s + _BLOCK]
        dist = cdist(p, others)
        rel = dist / unit
        r_bin = np.searchsorted(edges, rel, side="right")
        keep = (r_bin < n_radius) & (dist > 0)
        rows, cols = np.nonzero(keep)
        off = others[cols] - p[rows]  # (K, 3), K = pairs in range
        cos_el = off[:, 2] / dist[rows, cols]
        e_bin = np.minimum(((1.0 - cos_el) * 0.5 * n_elevation).astype(np.intp), n_elevation - 1)
        az = np.mod(np.arctan2(off[:, 1], off[:, 0]), 2 * np.pi)
        a_bin = np.minimum((az * (n_azimuth / (2 * np.pi))).astype(np.intp), n_azimuth - 1)
        flat = (rows * n_bins + (r_bin[rows, cols] * n_elevation + e_bin) * n_azimuth + a_bin)
        hist[s:s + _BLOCK] = np.bincount(flat, minlength=len(p) * n_bins).reshape(len(p), n_bins)
    total = hist.sum(1, keepdims=True)
    np.divide(hist, total, out=hist, where=total > 0)
    return hist
