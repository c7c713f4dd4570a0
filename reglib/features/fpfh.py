"""Fast Point Feature Histograms (FPFH) of 3-D point sets, and their putative matches.

The FPFH of Rusu, Blodow and Beetz [1]_ describes the surface around a point by the angles
between its normal and those of its neighbours within ``radius``:

1. For every pair (s, t) of points closer than ``radius`` (one k-d tree ``query_pairs``), the
   source s is the one whose normal makes the smaller angle with the line to the other; with
   u = n_s, d = (p_t - p_s) / |p_t - p_s|, v = u x d / |u x d| and w = u x v, the pair gives
   alpha = v . n_t, phi = u . d and theta = atan2(w . n_t, u . n_t). The three angles are
   rotation invariant.
2. The simplified histogram SPFH(p) puts the pairs of p into 11 bins per angle (33 in all),
   as a share of p's neighbours.
3. FPFH(p) = SPFH(p) + (1 / k) sum_k SPFH(p_k) / |p - p_k| over the k neighbours, and each of
   the three 11-bin blocks is then scaled to sum to 100.

Normals come from :func:`reglib.registration.normals.estimate_normals` (PCA of the nearest
neighbours) and are oriented away from the set's centroid, so that two views of one surface give
them the same sign where their centroids are near each other.

Matching (:func:`match_features`) is :func:`reglib.features.matching.match_descriptors`'s
Euclidean nearest neighbour with the mutual check and an optional ratio test.

Points are (N, 3) float64 rows (x, y, z) in the caller's units; lengths (``voxel``, ``radius``)
are in those units too.

References
----------
.. [1] R. B. Rusu, N. Blodow, M. Beetz, "Fast Point Feature Histograms (FPFH) for 3D
       Registration", ICRA 2009. :doi:`10.1109/ROBOT.2009.5152473`
"""
from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from .._validation import as_points
from ..errors import InputError
from .matching import match_descriptors

__all__ = ["FPFH_BINS", "fpfh", "match_features", "oriented_normals", "voxel_downsample"]

FPFH_BINS = 11
"""Bins per angle; an FPFH descriptor has 3 x 11 = 33 entries."""


def _check_length(value: float, name: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise InputError(f"`{name}` must be a positive finite length, got {value!r}")
    return v


def voxel_downsample(points: np.ndarray, voxel: float, *, min_count: int = 1) -> np.ndarray:
    """The centroid of the points in each occupied cube of side ``voxel`` (rows in cell order).

    Parameters
    ----------
    points : (N, D) array_like
        Points as (x, y[, z]) rows, in the caller's units.
    voxel : float
        Side of the cubes (caller's units), > 0.
    min_count : int
        Cubes holding fewer points are dropped (2 drops isolated points, such as scattered
        outliers, from a densely sampled surface).

    Returns
    -------
    (K, D) float64 ndarray
        One point per cube with at least ``min_count`` points; empty input gives an empty
        (0, D) array.

    Examples
    --------
    >>> voxel_downsample([[0.1, 0.1, 0.0], [0.3, 0.3, 0.0], [1.5, 0.2, 0.0]], 1.0)
    array([[0.2, 0.2, 0. ],
           [1.5, 0.2, 0. ]])
    """
    pts = as_points(points, "points")
    size = _check_length(voxel, "voxel")
    if not len(pts):
        return pts.copy()
    cells = np.floor((pts - pts.min(0)) / size).astype(np.int64)
    _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    out = np.zeros((len(counts), pts.shape[1]))
    np.add.at(out, inverse, pts)
    return (out / counts[:, None])[counts >= max(int(min_count), 1)]


def oriented_normals(points: np.ndarray, k: int = 30) -> np.ndarray:
    """PCA normals of ``points`` (N, 3) from ``k`` neighbours, each pointing away from the centroid.

    The orientation is a convention, not a fact about the surface: it makes two views of one
    scene agree on the sign of most normals, which the FPFH angles need.
    """
    # imported here: reglib.registration imports this module (its feature start), not the reverse
    from ..registration.normals import estimate_normals

    pts = as_points(points, "points", dims=(3,))
    nrm = estimate_normals(pts, k)
    flip = ((pts - pts.mean(0)) * nrm).sum(1) < 0.0
    nrm[flip] *= -1.0
    return nrm


def _pair_features(p: np.ndarray, n: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Bins (P, 3) of (alpha, phi, theta) for the pairs (i, j) (module docstring, step 1)."""
    d = p[j] - p[i]
    dist = np.linalg.norm(d, axis=1)
    d = d / np.maximum(dist, 1e-300)[:, None]
    ni, nj = n[i], n[j]
    # the source is the end whose normal is closer to the line between them
    swap = np.abs((ni * d).sum(1)) < np.abs((nj * d).sum(1))
    u = np.where(swap[:, None], nj, ni)
    nt = np.where(swap[:, None], ni, nj)
    d = np.where(swap[:, None], -d, d)
    v = np.cross(u, d)
    v /= np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]
    w = np.cross(u, v)
    alpha = (v * nt).sum(1)
    phi = (u * d).sum(1)
    theta = np.arctan2((w * nt).sum(1), (u * nt).sum(1))
    b = FPFH_BINS
    bins = np.stack([np.floor((alpha + 1.0) * 0.5 * b), np.floor((phi + 1.0) * 0.5 * b),
                     np.floor((theta + np.pi) / (2.0 * np.pi) * b)], 1)
    return np.clip(bins, 0, b - 1).astype(np.int64)


def fpfh(points: np.ndarray, normals: np.ndarray, radius: float) -> np.ndarray:
    """FPFH descriptors (N, 33) of ``points`` with unit ``normals``, neighbours within ``radius``.

    Parameters
    ----------
    points : (N, 3) array_like
        Points as (x, y, z) rows (usually voxel-downsampled: :func:`voxel_downsample`).
    normals : (N, 3) array_like
        Their normals (:func:`oriented_normals`); rescaled to unit length.
    radius : float
        Neighbourhood radius (caller's units), typically 5 voxels.

    Returns
    -------
    (N, 33) float64 ndarray
        Three 11-bin histograms (alpha, phi, theta), each summing to 100; all zeros for a point
        without neighbours.

    Raises
    ------
    InputError
        Points that are not 3-D, normals of another shape, a radius that is not positive.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> pts = rng.normal(size=(300, 3))
    >>> pts /= np.linalg.norm(pts, axis=1, keepdims=True)        # a sphere
    >>> desc = fpfh(pts, pts, 0.5)                                # its normals are the points
    >>> desc.shape, bool(np.allclose(desc[:, :11].sum(1), 100.0))
    ((300, 33), True)
    """
    pts = as_points(points, "points", dims=(3,))
    nrm = np.asarray(normals, dtype=np.float64)
    if nrm.shape != pts.shape or not np.isfinite(nrm).all():
        raise InputError(f"`normals` must be finite with shape {pts.shape}, got {nrm.shape}")
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    r = _check_length(radius, "radius")
    n_pts, b = len(pts), FPFH_BINS
    if not n_pts:
        return np.zeros((0, 3 * b))
    pairs = cKDTree(pts).query_pairs(r, output_type="ndarray")
    i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
    bins = _pair_features(pts, nrm, i, j) + np.arange(3) * b           # (P, 3) into 33 columns
    # a pair's angles count for both of its ends (they do not depend on which end is asked)
    rows = np.concatenate([np.repeat(i, 3), np.repeat(j, 3)])
    cols = np.concatenate([bins.reshape(-1), bins.reshape(-1)])
    spfh = np.bincount(rows * (3 * b) + cols, minlength=n_pts * 3 * b).reshape(n_pts, 3 * b).astype(np.float64)
    k = np.bincount(np.concatenate([i, j]), minlength=n_pts).astype(np.float64)
    spfh /= np.maximum(k, 1.0)[:, None]
    dist = np.linalg.norm(pts[i] - pts[j], axis=1)
    wgt = 1.0 / np.maximum(dist, 1e-12 * r)
    w = sparse.coo_matrix((np.concatenate([wgt, wgt]), (np.concatenate([i, j]), np.concatenate([j, i]))),
                          shape=(n_pts, n_pts)).tocsr()
    desc = spfh + (w @ spfh) / np.maximum(k, 1.0)[:, None]
    blocks = desc.reshape(n_pts, 3, b)
    total = blocks.sum(2, keepdims=True)
    blocks = np.where(total > 0, 100.0 * blocks / np.where(total > 0, total, 1.0), 0.0)
    return blocks.reshape(n_pts, 3 * b)


def match_features(desc_a: np.ndarray, desc_b: np.ndarray, *, mutual: bool = True,
                   ratio: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Putative matches between two FPFH (or any float) descriptor sets, a to b.

    Parameters
    ----------
    desc_a, desc_b : (Ka, F), (Kb, F) array_like
        Descriptors, one row per point.
    mutual : bool
        Keep only pairs that are each other's nearest neighbour (the default, as in Open3D's
        global registration with its mutual filter).
    ratio : float
        Lowe's ratio test (1.0, the default, skips it: FPFH neighbours are rarely distinct).

    Returns
    -------
    idx_a, idx_b : (N,) intp ndarray
        Matched rows, ``idx_a`` ascending.

    Examples
    --------
    >>> import numpy as np
    >>> a = np.eye(4)
    >>> match_features(a, a[[2, 0, 1, 3]])
    (array([0, 1, 2, 3]), array([1, 2, 0, 3]))
    """
    a = np.asarray(desc_a, dtype=np.float32)
    b = np.asarray(desc_b, dtype=np.float32)
    return match_descriptors(a, b, ratio=float(ratio), mutual=bool(mutual))
