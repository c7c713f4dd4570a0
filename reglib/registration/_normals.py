"""Surface normals of point sets from their k nearest neighbors (PCA), computed lazily.

The normal at a point is the eigenvector of the smallest eigenvalue of the covariance of its
k nearest neighbors (the point included), as in Hoppe et al. [1]; its sign is arbitrary (no
viewpoint is assumed), which point-to-plane residuals do not care about. Memory is O(k M): the
neighbors of at most ``_BLOCK`` points are held at once.

References
----------
.. [1] H. Hoppe, T. DeRose, T. Duchamp, J. McDonald, W. Stuetzle, "Surface reconstruction from
       unorganized points", SIGGRAPH 1992. :doi:`10.1145/133994.134011`
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["LazyNormals", "estimate_normals"]

_BLOCK = 32768


def _pca_normals(points: np.ndarray, tree: cKDTree, query: np.ndarray, k: int) -> np.ndarray:
    """Normals (Q, D) at ``query`` (points of ``points``) from their ``k`` nearest neighbors."""
    n, d = points.shape
    k = max(min(k, n), d)
    out = np.empty((len(query), d))
    for start in range(0, len(query), _BLOCK):
        q = query[start:start + _BLOCK]
        _, idx = tree.query(q, k=k)
        idx = np.asarray(idx).reshape(len(q), k)
        nb = points[idx]                                  # (B, k, D)
        nb = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("bki,bkj->bij", nb, nb)
        _, vecs = np.linalg.eigh(cov)                     # ascending eigenvalues
        out[start:start + _BLOCK] = vecs[:, :, 0]
    return out


def estimate_normals(points: np.ndarray, k: int = 10, *, tree: cKDTree | None = None) -> np.ndarray:
    """Unit normals of every point from the PCA of its ``k`` nearest neighbors.

    Parameters
    ----------
    points : (N, D) ndarray
        Points as (x, y[, z]) rows, D in {2, 3}, N >= D.
    k : int
        Neighbors per point (the point itself included); raised to D and capped at N.
    tree : scipy.spatial.cKDTree, optional
        A tree already built on ``points``.

    Returns
    -------
    (N, D) ndarray
        Unit normals, sign arbitrary (in 2-D, the normal of the local line).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> plane = np.c_[rng.uniform(size=(200, 2)), np.zeros(200)]
    >>> bool(np.allclose(np.abs(estimate_normals(plane, 8)[:, 2]), 1.0))
    True
    """
    pts = np.asarray(points, dtype=np.float64)
    t = cKDTree(pts) if tree is None else tree
    return _pca_normals(pts, t, pts, k)


class LazyNormals:
    """Normals of a point set computed on first use, point by point, and cached.

    ICP only ever needs the normals of the target points that are some model point's nearest
    neighbor; on a 300k-point frame that is a small part of the set.
    """

    __slots__ = ("_k", "_known", "_normals", "_points", "_tree")

    def __init__(self, points: np.ndarray, tree: cKDTree, k: int, normals: np.ndarray | None = None) -> None:
        self._points = points
        self._tree = tree
        self._k = k
        if normals is not None:
            nrm = np.linalg.norm(normals, axis=1, keepdims=True)
            self._normals = normals / np.where(nrm > 0, nrm, 1.0)
            self._known = np.ones(len(points), dtype=bool)
        else:
            self._normals = np.zeros_like(points)
            self._known = np.zeros(len(points), dtype=bool)

    def __getitem__(self, index: np.ndarray) -> np.ndarray:
        """Normals (K, D) of the points at ``index`` (K,), computing the missing ones."""
        missing = index[~self._known[index]]
        if len(missing):
            missing = np.unique(missing)
            self._normals[missing] = _pca_normals(self._points, self._tree, self._points[missing], self._k)
            self._known[missing] = True
        return self._normals[index]
