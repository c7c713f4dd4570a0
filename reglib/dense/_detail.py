"""Detail of the dense field: a narrow-kernel fit on a lattice to the matches a smooth fit kept.

The dense fits' kernel is wide (:data:`reglib.dense._options.FINAL_BETA`, about a quarter of the
image) so that the field carries across untextured areas; a strongly bent field (a bump a tenth of
the image wide moving by a twentieth of it) is then out of its reach: even fed exact grid matches,
the smooth fit stays pixels off where an interpolation of the same matches is not, and the dense
search, centred on the smooth fit, misses the bent part.
:func:`detailed` keeps the smooth fit's linear part and replaces its
kernel part by Gaussians of one narrow width on a regular lattice over image a, fitted by
regularized least squares to the matches (weighted by the smooth fit's inlier scores) and to the
smooth fit itself at the lattice nodes (fully where no match is near, so the field is the smooth one
across untextured areas; with weight ``PRIOR`` elsewhere). With its ``detail`` option (off by
default: slower) the dense stage uses it on its coarser pyramid levels (:mod:`reglib.dense._refine`),
where it brings a strongly bent part of the field within the finer levels' search; on the
working level the smooth fit averages the matches' noise better. Each
lattice centre only sees points within four kernel widths (the truncated part is below 3e-4 of a
Gaussian's peak), so the design matrix is sparse (the normal equations, one unknown per lattice node, are
solved densely: faster at these sizes than a sparse factorization); a few re-weightings (Cauchy
weights of the residuals) keep a stray match from pulling a spike into the field.

The result is an ordinary :class:`~reglib._transforms.KernelWarp` (one kernel width, more centres),
so its JSON form, warps and flows are those of every other transform.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import scipy.linalg
from scipy import sparse
from scipy.spatial import cKDTree

from .._transforms import KernelWarp

__all__ = ["DETAIL_LAM", "DETAIL_SIGMA", "LATTICE", "MAX_DETAIL_CENTERS", "PRIOR", "detailed"]

DETAIL_SIGMA = 1.5  # the kernel's standard deviation, in grid steps
# the lattice spacing, in grid steps: a coarser lattice loses the bent field's detail, a finer one is no more
# accurate and costs time (the dense normal equations cost (spacing)^-6)
LATTICE = 1.5
DETAIL_LAM = 0.01  # weight of the RKHS norm, relative to the data term's mean diagonal
MAX_DETAIL_CENTERS = 2500  # lattice centres at most (the spacing grows with the image beyond it)
PRIOR = 0.3  # weight of the smooth fit at lattice nodes near matches
_REACH = 4.0  # kernel widths a centre sees
_EMPTY = 1.5  # a lattice node farther than this (in spacings) from every match gets the smooth fit's value
_CAUCHY = 1.5  # scale of the re-weighting, in pixels of the level the matches were found on
_REWEIGHT = 3  # re-weighted solves after the first


def _lattice(shape: tuple[int, int], spacing: float) -> tuple[np.ndarray, tuple[int, int]]:
    """(M, 2) centres (x, y) of a lattice covering an (H, W) frame with a one-spacing margin, and its (rows, cols)."""
    h, w = shape
    nx = int(math.ceil((w - 1) / spacing)) + 3
    ny = int(math.ceil((h - 1) / spacing)) + 3
    xs = (np.arange(nx) - 1) * spacing
    ys = (np.arange(ny) - 1) * spacing
    gx, gy = np.meshgrid(xs, ys)
    return np.c_[gx.ravel(), gy.ravel()], (ny, nx)


def _near_centres(points: np.ndarray, dims: tuple[int, int], spacing: float, sigma: float) -> sparse.csr_matrix:
    """Sparse (K, M) Gaussian kernel of ``points`` against the lattice, truncated at ``_REACH`` widths."""
    ny, nx = dims
    reach = int(math.ceil(_REACH * sigma / spacing))
    off = np.arange(-reach, reach + 1)
    ox, oy = (g.ravel() for g in np.meshgrid(off, off))
    # the lattice node nearest each point (lattice index i is at (i - 1) * spacing)
    ix = np.rint(points[:, 0] / spacing).astype(np.int64)[:, None] + 1 + ox[None, :]
    iy = np.rint(points[:, 1] / spacing).astype(np.int64)[:, None] + 1 + oy[None, :]
    ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    dx = points[:, 0:1] - (ix - 1) * spacing
    dy = points[:, 1:2] - (iy - 1) * spacing
    d2 = dx * dx + dy * dy
    ok &= d2 <= (_REACH * sigma) ** 2
    # row by row, the offsets run over y, then x: a row's columns come out sorted and distinct (CSR as it is)
    indptr = np.concatenate([[0], np.cumsum(ok.sum(axis=1))])
    vals = np.exp(-d2[ok] / (2.0 * sigma * sigma))
    return sparse.csr_matrix((vals, (iy * nx + ix)[ok], indptr), shape=(len(points), ny * nx))


@functools.lru_cache(maxsize=8)
def _lattice_kernel(shape: tuple[int, int], spacing: float, sigma: float) -> np.ndarray:
    """The dense (M, M) truncated Gaussian kernel of :func:`_lattice` against itself (read-only: rounds share it)."""
    centres, dims = _lattice(shape, spacing)
    kcc = _near_centres(centres, dims, spacing, sigma).toarray()
    kcc.flags.writeable = False
    return kcc


def detailed(smooth: KernelWarp, src: np.ndarray, dst: np.ndarray, shape_a: tuple[int, int], step: float,
             pixel: float = 1.0, scores: np.ndarray | None = None) -> KernelWarp:
    """The smooth fit with a narrow-kernel field on a lattice over image a fitted to the matches.

    Parameters
    ----------
    smooth : KernelWarp
        The smooth fit (a -> b) whose linear part is kept and which holds the field where no match is.
    src, dst : (N, 2) float64 ndarray
        The matches the smooth fit kept, pixels of a and b.
    shape_a : (H, W)
        Image a's frame, pixels.
    step : float
        The matches' grid spacing, pixels of a (more where a lattice of that spacing would have more than
        ``MAX_DETAIL_CENTERS`` nodes): the kernel's width is ``DETAIL_SIGMA`` and the lattice's spacing
        ``LATTICE`` times it.
    pixel : float
        Pixels of b per pixel of the level the matches were found on (the re-weighting's unit).
    scores : (N,) float ndarray, optional
        The matches' weights in [0, 1] (the smooth fit's inlier scores); all 1 when omitted.

    Returns
    -------
    KernelWarp
        ``smooth``'s linear part and normalization, the lattice as centres.
    """
    h, w = shape_a
    base_spacing = max(float(step), math.sqrt(h * w / MAX_DETAIL_CENTERS))
    spacing = LATTICE * base_spacing
    sigma = DETAIL_SIGMA * base_spacing
    centres, dims = _lattice((h, w), spacing)
    # lattice nodes inside a with no match near: they hold the smooth fit's value
    inside = (centres[:, 0] >= 0) & (centres[:, 0] <= w - 1) & (centres[:, 1] >= 0) & (centres[:, 1] <= h - 1)
    nodes = centres[inside]
    prior = np.full(len(nodes), PRIOR)
    if len(src):
        far = cKDTree(src).query(nodes, distance_upper_bound=_EMPTY * spacing)[0] > _EMPTY * spacing
        prior[far] = 1.0
    pts = np.vstack([src, nodes])
    targets = np.vstack([dst, smooth(nodes)]) if len(nodes) else dst
    u = (pts - smooth.src_mean) / smooth.src_scale
    lin = u if smooth.linear is None else smooth.linear.apply(u)
    resid = (targets - smooth.dst_mean) / smooth.dst_scale - lin  # what the kernel part must give, normalized
    a = _near_centres(pts, dims, spacing, sigma)
    kcc = _lattice_kernel((h, w), spacing, sigma)
    m = centres.shape[0]
    base = np.concatenate([np.ones(len(src)) if scores is None else np.asarray(scores, float), prior])
    weights = base.copy()
    unit = _CAUCHY * pixel / smooth.dst_scale
    a_t = a.T.tocsr()
    per_row = np.diff(a.indptr)
    for it in range(_REWEIGHT + 1):
        # the normal equations are small and dense-ish (a centre couples to every centre within 2 reaches): a dense
        # Cholesky factorization is faster than a sparse one of them
        weighted = sparse.csr_matrix((a.data * np.repeat(weights, per_row), a.indices, a.indptr), shape=a.shape)
        system = (a_t @ weighted).toarray()
        lam = DETAIL_LAM * float(np.diag(system).mean())
        system += lam * kcc
        system.flat[:: m + 1] += 1e-9 * lam
        rhs = a_t @ (weights[:, None] * resid)
        try:  # positive definite: the lattice's truncated kernel is (its smallest eigenvalue about 2e-3)
            coef = scipy.linalg.cho_solve(scipy.linalg.cho_factor(system, check_finite=False), rhs,
                                          check_finite=False)
        except np.linalg.LinAlgError:
            coef = scipy.linalg.lu_solve(scipy.linalg.lu_factor(system, check_finite=False), rhs, check_finite=False)
        if it < _REWEIGHT:
            r = np.linalg.norm(a @ coef - resid, axis=1)
            weights = base / (1.0 + (r / unit) ** 2)
    beta = smooth.src_scale ** 2 / (2.0 * sigma * sigma)
    return KernelWarp(dim=2, src_mean=smooth.src_mean, src_scale=smooth.src_scale, dst_mean=smooth.dst_mean,
                      dst_scale=smooth.dst_scale, linear=smooth.linear, beta=beta,
                      centers=(centres - smooth.src_mean) / smooth.src_scale, weights=coef)
