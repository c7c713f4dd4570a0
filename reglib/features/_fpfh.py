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

Normals come from :func:`reglib.registration.estimate_normals` (PCA of the nearest
neighbours) and are oriented away from the set's centroid, so that two views of one surface give
them the same sign where their centroids are near each other.

Matching (:func:`match_features`) is :func:`reglib.features._matching.match_descriptors`'s
Euclidean nearest neighbour with the mutual check and an optional ratio test.

Points are (N, 3) float64 rows (x, y, z) in the caller's units; lengths (``voxel``, ``radius``)
are in those units too.

References
----------
.. [1] R. B. Rusu, N. Blodow, M. Beetz, "Fast Point Feature Histograms (FPFH) for 3D
       Registration", ICRA 2009. :doi:`10.1109/ROBOT.2009.5152473`
"""
from __future__ import annotations

from typing import Literal, cast, overload

import numpy as np
from scipy import sparse, stats
from scipy.spatial import cKDTree

from .._validation import as_points
from ..errors import InputError
from ._matching import match_descriptors

__all__ = ["FPFH_BINS", "fpfh", "match_features", "oriented_normals", "voxel_downsample"]

FPFH_BINS = 11
"""Bins per angle; an FPFH descriptor has 3 x 11 = 33 entries."""

_BLOCK = 5       # drop_scatter: the side of the block of cubes a background rate is taken over
_QUIET = 0.6     # ... the share of its quietest cubes that rate is the mean of
_ALPHA = 1e-3    # ... and the chance of the count under it beyond which a cube is dropped,
_MIN_SCATTER = 0.2  # ... when at least this share of the cubes is (clean real scans: <= 0.1)
_ROWS = 8192     # cubes whose blocks are gathered at once
_DENSE_CELLS = 1 << 22  # up to this many cubes in the box, counts are looked up in a dense grid


def _check_length(value: float, name: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise InputError(f"`{name}` must be a positive finite length, got {value!r}")
    return v


def _cell_keys(cells: np.ndarray, extent: np.ndarray) -> np.ndarray:
    """One int64 per cell, in the lexicographic order of its indices (cells in [0, extent))."""
    key = np.zeros(len(cells), dtype=np.int64)
    for col, n in zip(cells.T, extent, strict=True):
        key = key * n + col
    return key


def _scattered(cells: np.ndarray, keys: np.ndarray, counts: np.ndarray, extent: np.ndarray,
               alpha: float) -> np.ndarray:
    """The occupied cubes a local Poisson background explains (True: scattered), see ``drop_scatter``.

    ``cells`` (K, D) are the occupied cubes' indices (offset by half a block from the border),
    ``keys`` their sorted keys, ``counts`` their points. Cubes of a block outside the set's
    bounding box are not counted (the border would look quiet otherwise).
    """
    k, dim = cells.shape
    half = _BLOCK // 2
    offsets = np.stack(np.meshgrid(*([np.arange(-half, half + 1)] * dim), indexing="ij"), -1).reshape(-1, dim)
    # the keys are mixed-radix numbers and the border is padded: a neighbour's key is the cube's
    # key plus the offset's
    offset_keys = _cell_keys(offsets, extent)
    n_cells = int(np.prod(extent))
    dense = np.zeros(n_cells, dtype=np.int64) if n_cells <= _DENSE_CELLS else None
    if dense is not None:
        dense[keys] = counts
    rate = np.empty(k)
    for s in range(0, k, _ROWS):
        c = cells[s:s + _ROWS]
        near_keys = keys[s:s + _ROWS, None] + offset_keys[None]
        inside = np.ones(near_keys.shape, dtype=bool)
        for i in range(dim):
            pos = c[:, i:i + 1] + offsets[None, :, i]
            inside &= (pos >= half) & (pos < extent[i] - half)
        if dense is not None:                                      # a look-up in the whole grid
            block = dense[near_keys]
        else:                                                      # or among the occupied cubes
            at = np.minimum(np.searchsorted(keys, near_keys), k - 1)
            block = np.where(keys[at] == near_keys, counts[at], 0)
        # the quietest share of the cubes inside the box (outside ones sort last and are not
        # taken), where at least half the block is inside; nearer the corners the cubes outside
        # count as empty up to half the block (a few of the box's cubes are too few to tell)
        n_in = inside.sum(1)
        n_out = np.maximum(len(offsets) // 2 - n_in, 0)
        block = np.sort(np.where(inside, block, np.iinfo(np.int64).max), axis=1)
        n_quiet = np.maximum(np.round(_QUIET * (n_in + n_out)), 1).astype(np.int64)
        taken = np.arange(len(offsets))[None] < (n_quiet - n_out)[:, None]
        rate[s:s + _ROWS] = np.where(taken, block, 0).sum(1) / n_quiet
    # P(a background cube holds at least this many points); a zero rate explains no point
    return cast(np.ndarray, stats.poisson.sf(counts - 1, rate) > alpha)  # arrays in, an array out


@overload
def voxel_downsample(points: np.ndarray, voxel: float, *, min_count: int = ..., drop_scatter: bool = ...,
                     return_mask: Literal[False] = ...) -> np.ndarray: ...
@overload
def voxel_downsample(points: np.ndarray, voxel: float, *, min_count: int = ..., drop_scatter: bool = ...,
                     return_mask: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def voxel_downsample(points: np.ndarray, voxel: float, *, min_count: int = ..., drop_scatter: bool = ...,
                     return_mask: bool = ...) -> np.ndarray | tuple[np.ndarray, np.ndarray]: ...
def voxel_downsample(points: np.ndarray, voxel: float, *, min_count: int = 1, drop_scatter: bool = False,
                     return_mask: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
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
    drop_scatter : bool
        Drop the cubes that points scattered through the volume explain: with the local
        background rate b of a cube (the mean count of the quietest 60 % of the 5 x 5 x 5 cubes
        around it inside the bounding box, empty ones included), a cube is scattered when a
        Poisson count of mean b would reach its count with probability above 1e-3. On a
        surface the quiet cubes are empty (b = 0); among outliers spread through the volume, b
        is their density and only cubes well above it (the surface) are not scattered. The
        scattered cubes are dropped when they are at least a fifth of all: below that they are
        sparse or crowded parts of a clean surface, and every cube is kept. Meant for surfaces in
        3-D (curves in 2-D): a set that fills the volume is scatter by this test. Below about
        one outlier in two cubes the quiet cubes are empty too, and such sparse outliers stay.
        Cubes too many to number in an int64 (a voxel tiny against the extent) are not tested.
    return_mask : bool
        Also return which of ``points`` lie in the cubes kept.

    Returns
    -------
    (K, D) float64 ndarray
        One point per cube kept; empty input gives an empty (0, D) array.
    (N,) bool ndarray
        With ``return_mask``: True for the points in a cube kept.

    Examples
    --------
    >>> voxel_downsample([[0.1, 0.1, 0.0], [0.3, 0.3, 0.0], [1.5, 0.2, 0.0]], 1.0)
    array([[0.2, 0.2, 0. ],
           [1.5, 0.2, 0. ]])
    """
    pts = as_points(points, "points")
    size = _check_length(voxel, "voxel")
    if not len(pts):
        return (pts.copy(), np.zeros(0, dtype=bool)) if return_mask else pts.copy()
    # cells offset from the border by half a block, so that a block never wraps around
    cells = np.floor((pts - pts.min(0)) / size).astype(np.int64) + _BLOCK // 2
    extent = cells.max(0) + 1 + _BLOCK // 2
    # a 1-D unique of the keys is much faster than a row-wise one; cells too many to number in an
    # int64 fall back to the rows
    if float(np.prod(extent.astype(np.float64))) < 2.0 ** 62:
        keys, first, inverse, counts = np.unique(_cell_keys(cells, extent), return_index=True,
                                                 return_inverse=True, return_counts=True)
    else:
        keys = None
        _, first, inverse, counts = np.unique(cells, axis=0, return_index=True, return_inverse=True,
                                              return_counts=True)
    inverse = inverse.reshape(-1)
    out = np.stack([np.bincount(inverse, weights=col, minlength=len(counts)) for col in pts.T], 1)
    keep = counts >= max(int(min_count), 1)
    if drop_scatter and keys is not None:
        scattered = _scattered(cells[first], keys, counts, extent, _ALPHA)
        if scattered.mean() >= _MIN_SCATTER:
            keep &= ~scattered
    centroids = (out / counts[:, None])[keep]
    return (centroids, keep[inverse]) if return_mask else centroids


def oriented_normals(points: np.ndarray, k: int = 30) -> np.ndarray:
    """PCA normals of ``points`` (N, 3) from ``k`` neighbours, each pointing away from the centroid.

    The orientation is a convention, not a fact about the surface: it makes two views of one
    scene agree on the sign of most normals, which the FPFH angles need.
    """
    # imported here: reglib.registration imports this module (its feature start), not the reverse
    from ..registration import estimate_normals

    pts = as_points(points, "points", dims=(3,))
    nrm = estimate_normals(pts, k)
    flip = ((pts - pts.mean(0)) * nrm).sum(1) < 0.0
    nrm[flip] *= -1.0
    return nrm


def _dot(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _pair_features(p: np.ndarray, n: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Bins (P, 3) of (alpha, phi, theta) for the pairs (i, j) (module docstring, step 1).

    Vectors are kept as three coordinate columns: on millions of pairs that is several times
    faster than (P, 3) rows, with the same arithmetic.
    """
    pc = [np.ascontiguousarray(c) for c in p.T]
    nc = [np.ascontiguousarray(c) for c in n.T]
    d = tuple(c[j] - c[i] for c in pc)
    inv = 1.0 / np.maximum(np.sqrt(_dot(d, d)), 1e-300)
    d = tuple(c * inv for c in d)
    ni, nj = tuple(c[i] for c in nc), tuple(c[j] for c in nc)
    # the source is the end whose normal is closer to the line between them
    swap = np.abs(_dot(ni, d)) < np.abs(_dot(nj, d))
    u = tuple(np.where(swap, b, a) for a, b in zip(ni, nj, strict=True))
    nt = tuple(np.where(swap, a, b) for a, b in zip(ni, nj, strict=True))
    sign = np.where(swap, -1.0, 1.0)
    d = tuple(c * sign for c in d)
    v = _cross(u, d)
    inv = 1.0 / np.maximum(np.sqrt(_dot(v, v)), 1e-300)
    v = tuple(c * inv for c in v)
    w = _cross(u, v)
    alpha = _dot(v, nt)
    phi = _dot(u, d)
    theta = np.arctan2(_dot(w, nt), _dot(u, nt))
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
