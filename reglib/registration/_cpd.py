"""Coherent Point Drift (Myronenko & Song [1]): non-rigid (optionally low-rank), rigid and affine.

CPD fits the model points as the centroids of a Gaussian mixture to the target by EM. CPD's own
papers call the moving set Y (our ``model``) and the fixed set X (our ``target``); this module
follows that naming inside. Everything works in normalized coordinates (mean 0, RMS radius 1)
on trusted arrays; :func:`reglib.register_points` validates and maps back.

Large sets: EM runs on at most ``max_points`` farthest-point samples of each set, so the
(M, N) posterior matrix is bounded by ``max_points**2``; the fitted map (a Gaussian-kernel
field with the samples as centers, or an affine map) is then evaluated on every point.

References
----------
.. [1] A. Myronenko, X. Song, "Point Set Registration: Coherent Point Drift", IEEE TPAMI 32(12),
       2010. :doi:`10.1109/TPAMI.2010.46`
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.linalg
import scipy.sparse.linalg
from scipy.spatial.distance import cdist

from .._geometry import nearest_rotation
from .._transforms import LinearPart
from ..options import check_declared, declared, option
from ..robust import Model, farthest_point_centers
from ._result import WarpFit

__all__ = ["CPDOptions", "cpd_affine_register", "cpd_posterior", "cpd_register", "cpd_rigid_register"]

_SIGMA2_MIN = 1e-10


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class CPDOptions:
    """Options of ``register_points(method="cpd" | "cpd-rigid" | "cpd-affine")``.

    Lengths are in normalized units (each set centered, RMS radius 1).

    Parameters
    ----------
    beta : float
        Width of CPD's Gaussian kernel exp(-|y_i - y_j|^2 / (2 beta^2)) (beta in [1]; pycpd 2).
        Note that this is a width, unlike ``RegistrationOptions.beta``; the fitted warp carries
        the equivalent 1 / (2 beta^2).
    lam : float
        Smoothness weight (lambda in [1]; pycpd 2).
    outlier_weight : float
        Weight of the uniform outlier component, the paper's w, in [0, 1). Formerly ``w``.
    max_iter : int
        EM iterations at most (at most 10000).
    tol : float
        EM stops when the objective changes by less than ``tol`` relative to its value.
    low_rank : bool
        Non-rigid only: replace the Gram matrix by its ``n_eig`` leading eigenpairs (the paper's
        fast CPD), solving each M-step with the Woodbury identity in O(M K^2).
    n_eig : int
        Eigenpairs kept with ``low_rank`` (at most 1000).
    scale : bool
        Rigid only: estimate a global scale as well as rotation and translation.
    max_points : int
        Points of each set used by EM at most (farthest-point samples beyond it); 10 to 5000,
        as EM holds max_points^2 responsibilities.
    """

    beta: float = option(2.0, kind="float", low=0, low_open=True, doc="width of the Gaussian kernel (beta)")
    lam: float = option(2.0, kind="float", low=0, low_open=True, doc="smoothness weight (lambda)")
    outlier_weight: float = option(0.0, kind="float", low=0, high=1, high_open=True,
                                   doc="weight w of the uniform outlier component, in [0, 1)")
    max_iter: int = option(150, kind="int", low=1, high=10000, doc="EM iterations at most")
    tol: float = option(1e-5, kind="float", low=0, low_open=True,
                        doc="EM stops when the objective changes by less, relative to its value")
    low_rank: bool = option(False, kind="bool", doc="non-rigid: low-rank Gram matrix (fast CPD)")
    n_eig: int = option(64, kind="int", low=1, high=1000, doc="eigenpairs kept with low_rank")
    scale: bool = option(True, kind="bool", doc="rigid: estimate a global scale too")
    # Upper bound keeps every request finite: EM holds (max_points)^2 responsibilities.
    max_points: int = option(1000, kind="int", low=10, high=5000, doc="points of each set used by EM at most")

    RENAMED_FIELDS: ClassVar[dict[str, str]] = {"w": "outlier_weight"}

    def __post_init__(self) -> None:
        check_declared(self)


def _initial_sigma2(x: np.ndarray, y: np.ndarray) -> float:
    n, d = x.shape
    m = len(y)
    s = (m * (x * x).sum() + n * (y * y).sum() - 2.0 * x.sum(0) @ y.sum(0)) / (d * n * m)
    return max(float(s), _SIGMA2_MIN)


def cpd_posterior(x: np.ndarray, ty: np.ndarray, sigma2: float, w: float) -> np.ndarray:
    """CPD's E-step: posterior P (M, N) of centroid ``ty[m]`` having generated point ``x[n]``.

    Gaussians of variance ``sigma2`` on the M centroids plus a uniform outlier term of weight ``w``
    ([1]); each column sums to at most 1.
    """
    n, d = x.shape
    m = len(ty)
    p = cdist(ty, x, "sqeuclidean")
    p *= -1.0 / (2.0 * sigma2)
    np.exp(p, out=p)
    c = (2.0 * np.pi * sigma2) ** (d / 2.0) * w / (1.0 - w) * m / n
    den = p.sum(0) + c
    den[den <= 0] = np.finfo(float).tiny
    p /= den
    return p


def _samples(u: np.ndarray, y: np.ndarray, opts: CPDOptions,
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_points`` farthest-point samples of each set (the model's drawn first)."""
    moving = farthest_point_centers(u, opts.max_points, rng) if len(u) > opts.max_points else u
    fixed = farthest_point_centers(y, opts.max_points, rng) if len(y) > opts.max_points else y
    return moving, fixed


def _warp_fit(model: Model, n_iter: int, converged: bool, sigma2: float) -> WarpFit:
    """The fit, its reach for correspondences three times the final sigma (at least 0.05)."""
    return WarpFit(model=model, n_iter=n_iter, converged=converged, reach=max(3.0 * float(np.sqrt(sigma2)), 0.05))


def cpd_register(u: np.ndarray, y: np.ndarray, opts: CPDOptions, rng: np.random.Generator) -> WarpFit:
    """Non-rigid CPD [1] of the normalized model ``u`` onto the normalized target ``y``.

    The map is the model plus a Gaussian-kernel field centered on the model (samples).
    """
    moving, fixed = _samples(u, y, opts, rng)
    return _warp_fit(*_nonrigid(moving, fixed, opts))


def cpd_rigid_register(u: np.ndarray, y: np.ndarray, opts: CPDOptions, rng: np.random.Generator) -> WarpFit:
    """Rigid CPD [1]: rotation, translation and (with ``opts.scale``) a global scale."""
    moving, fixed = _samples(u, y, opts, rng)
    return _warp_fit(*_linear(moving, fixed, opts, rigid=True))


def cpd_affine_register(u: np.ndarray, y: np.ndarray, opts: CPDOptions, rng: np.random.Generator) -> WarpFit:
    """Affine CPD [1] of the normalized model ``u`` onto the normalized target ``y``."""
    moving, fixed = _samples(u, y, opts, rng)
    return _warp_fit(*_linear(moving, fixed, opts, rigid=False))


def _nonrigid(yy: np.ndarray, x: np.ndarray, opts: CPDOptions) -> tuple[Model, int, bool, float]:
    m, d = yy.shape
    kbeta = 1.0 / (2.0 * opts.beta**2)
    gram = np.exp(-kbeta * cdist(yy, yy, "sqeuclidean"))
    low_rank = opts.low_rank and opts.n_eig < m
    if low_rank:
        vals, vecs = scipy.sparse.linalg.eigsh(gram, k=opts.n_eig, which="LM", v0=np.ones(m))
        keep = vals > 1e-12 * vals.max()
        vals, vecs = vals[keep], vecs[:, keep]
    w = np.zeros((m, d))
    ty = yy.copy()
    sigma2 = _initial_sigma2(x, yy)
    q_prev = np.inf
    it = 0
    converged = False
    while it < opts.max_iter:
        it += 1
        p = cpd_posterior(x, ty, sigma2, opts.outlier_weight)
        p1 = p.sum(1)
        pt1 = p.sum(0)
        px = p @ x
        n_p = float(p1.sum())
        if n_p <= 1e-12:
            break
        if low_rank:
            # (G + A) W = B with G = Q S Q^T, A = lam sigma^2 diag(P1)^-1 (Woodbury)
            a_inv = p1 / (opts.lam * sigma2)
            b = px / np.maximum(p1, 1e-300)[:, None] - yy
            aib = a_inv[:, None] * b
            inner = np.diag(1.0 / vals) + vecs.T @ (a_inv[:, None] * vecs)
            w = aib - a_inv[:, None] * (vecs @ scipy.linalg.solve(inner, vecs.T @ aib, assume_a="sym"))
            gw = vecs @ (vals[:, None] * (vecs.T @ w))
        else:
            lhs = p1[:, None] * gram
            lhs[np.diag_indices(m)] += opts.lam * sigma2
            w = scipy.linalg.solve(lhs, px - p1[:, None] * yy, check_finite=False)
            gw = gram @ w
        ty = yy + gw
        new_sigma2 = ((pt1 * (x * x).sum(1)).sum() - 2.0 * (px * ty).sum() + (p1 * (ty * ty).sum(1)).sum()) / (n_p * d)
        sigma2 = max(float(new_sigma2), _SIGMA2_MIN)
        q = n_p * d / 2.0 * np.log(sigma2) + opts.lam / 2.0 * float((w * gw).sum())
        if np.isfinite(q_prev) and abs(q - q_prev) <= opts.tol * max(abs(q), 1.0):
            converged = True
            break
        q_prev = q
    # With the low-rank Gram the coefficients W still define the field anywhere through the full
    # kernel, sum_m k(z, y_m) w_m, which agrees with the low-rank fit on the model points up to the
    # discarded part of the spectrum.
    g = Model(LinearPart("affine", np.c_[np.eye(d), np.zeros(d)]), yy.copy(), kbeta, w)
    return g, it, converged, sigma2


def _linear(yy: np.ndarray, x: np.ndarray, opts: CPDOptions, *, rigid: bool) -> tuple[Model, int, bool, float]:
    m, d = yy.shape
    rot, s, t = np.eye(d), 1.0, np.zeros(d)
    b = np.eye(d)
    ty = yy.copy()
    sigma2 = _initial_sigma2(x, yy)
    it = 0
    converged = False
    q_prev = np.inf
    while it < opts.max_iter:
        it += 1
        p = cpd_posterior(x, ty, sigma2, opts.outlier_weight)
        p1 = p.sum(1)
        pt1 = p.sum(0)
        n_p = float(p1.sum())
        if n_p <= 1e-12:
            break
        mu_x = pt1 @ x / n_p
        mu_y = p1 @ yy / n_p
        xh = x - mu_x
        yh = yy - mu_y
        a = (p @ xh).T @ yh  # (D, D): sum_mn P_mn xh_n yh_m^T
        xx = float((pt1 * (xh * xh).sum(1)).sum())
        if rigid:
            rot = nearest_rotation(a)
            yy_w = float((p1 * (yh * yh).sum(1)).sum())
            tr = float(np.trace(a.T @ rot))
            s = tr / yy_w if opts.scale and yy_w > 0 else 1.0
            b = s * rot
            sigma2 = (xx - s * tr) / (n_p * d)
        else:
            yy_w = (p1[:, None] * yh).T @ yh
            b = scipy.linalg.solve(yy_w + 1e-12 * np.eye(d), a.T, assume_a="sym").T
            sigma2 = (xx - float(np.trace(a @ b.T))) / (n_p * d)
        t = mu_x - b @ mu_y
        sigma2 = max(float(sigma2), _SIGMA2_MIN)
        ty = yy @ b.T + t
        q = sigma2
        if np.isfinite(q_prev) and abs(q - q_prev) <= opts.tol * max(abs(q), 1e-12):
            converged = True
            break
        q_prev = q
    return Model(LinearPart("affine", np.c_[b, t]), np.zeros((0, d)), 1.0, np.zeros((0, d))), it, converged, sigma2
