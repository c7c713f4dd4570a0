"""Machinery shared by the RKHS estimators (L2E, VFC): normalization, basis, weighted solves.

Everything here works in normalized coordinates on trusted arrays (validated upstream).
Model in normalized coordinates: g(u) = L(u) + U(u) W, U_im = exp(-beta |u_i - c_m|^2).
"""
from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import lapack
from threadpoolctl import ThreadpoolController

from .._geometry import umeyama_similarity
from .._transforms import KernelWarp, LinearPart, kernel_apply, kernel_matrix

LINEAR_KINDS = ("none", "affine", "homography", "rigid", "similarity")
"""The linear parts: "rigid" and "similarity" are stored as affine matrices [s R | t] (s = 1 for
"rigid", which needs both sets normalized by one common scale: :meth:`Normalization.common`)."""


@functools.cache
def _blas_libraries() -> tuple[Any, ...]:
    # found on first use, when the BLAS libraries in use are loaded
    return tuple(ThreadpoolController().select(user_api="blas").lib_controllers)


@contextlib.contextmanager
def single_thread_blas() -> Iterator[None]:
    """Run the block with one BLAS thread.

    The estimators' systems are small (at most a few hundred unknowns): threads cannot speed
    them up, and their synchronization costs a lot once the cores are busy with other work. Only
    a library not already on one thread is set, and restored after (threadpoolctl's ``limit``
    reads every library's whole description each time).
    """
    changed = []
    try:
        for lib in _blas_libraries():
            count = lib.get_num_threads()
            if count != 1:
                lib.set_num_threads(1)
                changed.append((lib, count))
        yield
    finally:
        for lib, count in reversed(changed):
            lib.set_num_threads(count)


@dataclass(frozen=True)
class Normalization:
    """Mean and RMS-radius scale of each point set (the normalization of the L2E and VFC papers)."""

    src_mean: np.ndarray
    src_scale: float
    dst_mean: np.ndarray
    dst_scale: float

    @classmethod
    def of(cls, src: np.ndarray, dst: np.ndarray) -> Normalization:
        sm, dm = src.mean(0), dst.mean(0)
        return cls(sm, _rms_radius(src - sm), dm, _rms_radius(dst - dm))

    @classmethod
    def common(cls, src: np.ndarray, dst: np.ndarray) -> Normalization:
        """Each set centered, both divided by the target's RMS radius (a rigid map stays rigid)."""
        sm, dm = src.mean(0), dst.mean(0)
        scale = _rms_radius(dst - dm)
        return cls(sm, scale, dm, scale)

    def apply(self, src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (src - self.src_mean) / self.src_scale, (dst - self.dst_mean) / self.dst_scale


def _rms_radius(centered: np.ndarray) -> float:
    r = float(np.sqrt((centered * centered).sum(1).mean())) if len(centered) else 0.0
    scale = max(float(np.abs(centered).max(initial=0.0)), 1.0)
    # All-identical points have no spread: any positive scale is right; avoid dividing by ~0.
    return r if r > 1e-12 * scale else 1.0


def mixture_posterior(e2: np.ndarray, sigma2: float, gamma: float, d: int, volume: float) -> np.ndarray:
    """Posterior that each residual (squared norms ``e2``) belongs to N(0, sigma^2 I) with weight
    ``gamma`` rather than to a uniform density 1 / ``volume`` (the outliers' model of L2E's final
    decision and of VFC's E-step)."""
    inlier = gamma * np.exp(-e2 / (2.0 * sigma2))
    return inlier / (inlier + (1.0 - gamma) * (2.0 * np.pi * sigma2) ** (d / 2.0) / volume)


def farthest_point_centers(points: np.ndarray, m: int, rng: np.random.Generator | None,
                           start: int | None = None) -> np.ndarray:
    """Pick ``m`` rows of ``points`` spread over the set by farthest-point sampling, O(N m).

    The first centre is row ``start`` when given, else a random point (``rng``); duplicates are
    skipped, so fewer than ``m`` centres come back when the set has fewer distinct points.
    """
    n, d = points.shape
    if n == 0 or m <= 0:
        return np.zeros((0, d))
    # One coordinate at a time in preallocated buffers: the loop runs m times over all n points.
    first, *rest = [np.ascontiguousarray(points[:, j]) for j in range(d)]
    d2, acc, tmp = np.empty(n), np.empty(n), np.empty(n)

    def dist2(i: int, into: np.ndarray) -> None:
        np.subtract(first, first[i], out=into)
        into *= into
        for col in rest:
            np.subtract(col, col[i], out=tmp)
            np.multiply(tmp, tmp, out=tmp)
            into += tmp

    if start is None:
        assert rng is not None, "a random first centre needs a generator"
        start = int(rng.integers(n))
    chosen = [int(start)]
    dist2(chosen[0], d2)
    for _ in range(1, min(m, n)):
        i = int(d2.argmax())
        if d2[i] <= 1e-24:
            break
        chosen.append(i)
        dist2(i, acc)
        np.minimum(d2, acc, out=d2)
    return points[chosen].copy()


@dataclass
class Model:
    """A model in normalized coordinates: linear part (or None) + kernel weights on ``centers``."""

    linear: LinearPart | None
    centers: np.ndarray
    beta: float
    weights: np.ndarray

    def predict(self, u: np.ndarray, basis: np.ndarray | None = None) -> np.ndarray:
        """g(u); ``basis`` is the kernel matrix at ``u`` when the caller has it, else it is made in blocks."""
        out = u.copy() if self.linear is None else self.linear.apply(u)
        if not len(self.centers):
            return out
        if basis is not None:
            out += basis @ self.weights
            return out
        return kernel_apply(u, self.centers, self.beta, self.weights, out, single_exp=True)

    def to_warp(self, norm: Normalization) -> KernelWarp:
        return KernelWarp(dim=self.centers.shape[1], src_mean=norm.src_mean, src_scale=norm.src_scale,
                          dst_mean=norm.dst_mean, dst_scale=norm.dst_scale, linear=self.linear,
                          beta=self.beta, centers=self.centers, weights=self.weights)


def identity_model(dim: int, linear: str) -> Model:
    lin = None
    if linear in ("affine", "rigid", "similarity"):
        lin = LinearPart("affine", np.eye(dim, dim + 1))
    elif linear == "homography":
        lin = LinearPart("homography", np.eye(3))
    return Model(lin, np.zeros((0, dim)), 1.0, np.zeros((0, dim)))


class WeightedSolver:
    """Solves the weighted, regularized least-squares step shared by L2E (IRLS) and VFC (M-step).

    For weights p_i and a ridge weight ``ridge`` it minimizes
        sum_i p_i |y_i - L(u_i) - U_i W|^2 + ridge * tr(W^T K W) + eps * |L - I|^2,
    where the linear part L is affine (solved jointly with W in closed form), a homography
    (alternating: weighted DLT for H on y - UW, then the ridge for W on y - H(u)), or rigid /
    similarity (alternating the same way, with Umeyama's weighted closed form for L).
    """

    def __init__(self, u: np.ndarray, y: np.ndarray, centers: np.ndarray, beta: float, linear: str):
        self.u, self.y, self.centers, self.beta, self.linear = u, y, centers, beta, linear
        n, d = u.shape
        self.n_lin = d + 1 if linear == "affine" else 0
        # The design [u, 1, basis] (affine) or basis is made in place; basis is a view of it.
        self.design = np.empty((n, self.n_lin + len(centers)))
        if self.n_lin:
            self.design[:, :d] = u
            self.design[:, d] = 1.0
        self.basis = self.design[:, self.n_lin:]
        if len(centers):
            kernel_matrix(u, centers, beta, out=self.basis, single_exp=True)
        self.gram = kernel_matrix(centers, centers, beta, single_exp=True) if len(centers) else np.zeros((0, 0))
        self._last: tuple[Model, np.ndarray] | None = None  # the model solve() returned last, its coefficients
        self._scratch: np.ndarray | None = None
        self._target: np.ndarray | None = None  # y - u, the affine and kernel-only solves' target
        # the last solve's Cholesky factor, weights, their sum, ridge and linear unknowns (leverage())
        self._hat: tuple[np.ndarray, np.ndarray, float, float, int] | None = None

    def solve(self, p: np.ndarray, previous: Model, ridge: float) -> Model:
        u, y, d = self.u, self.y, self.u.shape[1]
        m = len(self.centers)
        sp = float(p.sum())
        if sp <= 0:
            return previous
        lin: LinearPart | None
        if self.linear in ("rigid", "similarity"):
            w = previous.weights if previous.weights.shape[0] == m else np.zeros((m, d))
            mat = umeyama_similarity(u, y - self.basis @ w if m else y, p, scale=self.linear == "similarity")
            lin = LinearPart("affine", mat)
            w = self._ridge(self.basis, y - lin.apply(u), p, sp, ridge, n_lin=0)
            return Model(lin, self.centers, self.beta, w)
        if self.linear == "homography":
            lin = previous.linear
            w = previous.weights if previous.weights.shape[0] == m else np.zeros((m, d))
            h = _weighted_dlt(u, y - self.basis @ w, p)
            if h is not None:
                lin = LinearPart("homography", h)
            assert lin is not None  # a homography model always carries its linear part (identity_model)
            target = y - lin.apply(u)
            w = self._ridge(self.basis, target, p, sp, ridge, n_lin=0)
            return Model(lin, self.centers, self.beta, w)
        if self._target is None:
            self._target = y - u
        theta = self._ridge(self.design, self._target, p, sp, ridge, n_lin=self.n_lin)
        lin = None
        if self.linear == "affine":
            mat = np.empty((d, d + 1))
            mat[:, :d] = theta[:d].T
            mat[:, d] = theta[d]
            diagonal = mat.reshape(-1)[:: d + 2]  # a view: A = I + dA on the (D, D+1) block's diagonal
            diagonal += 1.0
            lin = LinearPart("affine", mat)
        model = Model(lin, self.centers, self.beta, theta[self.n_lin:])
        self._last = (model, theta)
        return model

    def fitted(self, model: Model) -> np.ndarray:
        """g(u) at the solver's points: one product with the design for the model solve() returned last."""
        if self._last is not None and self._last[0] is model:
            return self.u + self.design @ self._last[1]
        return model.predict(self.u, self.basis if model.centers is self.centers else None)

    def _ridge(self, design: np.ndarray, target: np.ndarray, p: np.ndarray, sp: float, ridge: float,
               n_lin: int) -> np.ndarray:
        if not design.shape[1]:  # no unknowns (no linear part, no centres)
            return np.zeros((0, target.shape[1]))
        # Rows whose weight is negligible (far outliers at a small sigma) change nothing: drop them.
        mask = p > 1e-12 * float(p.max(initial=0.0))
        n_keep = int(np.count_nonzero(mask))
        # The weighted design goes into one buffer reused across iterations (a fresh multi-MiB
        # array per step costs more in page faults than the product itself).
        if self._scratch is None or self._scratch.shape != design.shape:
            self._scratch = np.empty_like(design)
        scaled = self._scratch[:n_keep]
        if n_keep < len(p):
            keep = np.flatnonzero(mask)
            root = np.sqrt(p[keep])[:, None]
            np.take(design, keep, axis=0, out=scaled)
            scaled *= root
            weighted = target[keep]
            weighted *= root
        else:
            root = np.sqrt(p)[:, None]
            np.multiply(design, root, out=scaled)
            weighted = target * root
        a = scaled.T @ scaled
        b = scaled.T @ weighted
        a[n_lin:, n_lin:] += ridge * self.gram
        # A tiny ridge keeps the system positive definite when few weights are non-zero
        # (the published code's epsilon) and shrinks an undetermined linear part to identity.
        if a.flags.c_contiguous:  # (a product's result is): its diagonal as a view
            diagonal = a.reshape(-1)[:: a.shape[0] + 1]
            diagonal += ridge_epsilon(sp)
        else:
            a.flat[:: a.shape[0] + 1] += ridge_epsilon(sp)
        # The system is symmetric positive definite: Cholesky by LAPACK directly (the wrappers'
        # checks cost more than the solve for the coarse level's ~20 unknowns).
        factor, x, info = lapack.dposv(a, b)
        if info == 0 and np.isfinite(x).all():
            self._hat = (factor, p, sp, ridge, n_lin)
            return x
        self._hat = None
        return np.linalg.lstsq(a, b, rcond=None)[0]

    def leverage(self) -> np.ndarray | None:
        """Approximate hat-matrix diagonal of the last solve, one value per row (None if unknown).

        The trace of the hat matrix (the solve's effective degrees of freedom, df = k - tr(A^-1 R)
        for the k unknowns, A the normal matrix and R its regularization) is shared out in
        proportion to the weights: h_i = p_i df / sum(p). A row's fitted value is pulled toward
        its own target by about that share, so ``e_i / (1 - h_i)`` estimates the residual it would
        have had, had the solve left it out. (The exact diagonal costs one more pass over the
        design, as much as the solve; on the benchmarks the share decided the same.) A
        homography's 8 unknowns are not counted: its linear part is solved apart from the ridge.
        """
        if self._hat is None:
            return None
        factor, p, sp, ridge, n_lin = self._hat
        inverse, info = lapack.dpotri(factor)  # A^-1 from its Cholesky factor (upper triangle)
        if info != 0:
            return None
        k = len(inverse)
        upper = np.triu(inverse[n_lin:, n_lin:])  # tr(S G) for symmetric S, G from S's upper triangle
        diagonal = np.diagonal(inverse)
        reg_trace = ridge * (2.0 * float(np.vdot(upper, self.gram)) - float(upper.diagonal() @ self.gram.diagonal()))
        reg_trace += ridge_epsilon(sp) * float(diagonal.sum())
        df = min(max(k - reg_trace, 0.0), float(k))
        return p * (df / sp)


def ridge_epsilon(sp: float) -> float:
    """The tiny ridge on every unknown of a solve whose weights sum to ``sp``."""
    return 1e-8 * sp + 1e-12


def _weighted_dlt(u: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray | None:
    """Homography H (3, 3) minimizing the weighted algebraic error of y ~ H u (2-D, normalized)."""
    keep = p > 1e-6 * p.max(initial=0.0)
    if keep.sum() < 4:
        return None
    u, y, w = u[keep], y[keep], np.sqrt(p[keep])
    n = len(u)
    a = np.zeros((2 * n, 9))
    ones = np.ones(n)
    a[0::2, 0:3] = np.c_[u, ones]
    a[0::2, 6:9] = -y[:, :1] * np.c_[u, ones]
    a[1::2, 3:6] = np.c_[u, ones]
    a[1::2, 6:9] = -y[:, 1:2] * np.c_[u, ones]
    a *= np.repeat(w, 2)[:, None]
    try:
        _, s, vt = np.linalg.svd(a.T @ a)
    except np.linalg.LinAlgError:
        return None
    h = vt[-1].reshape(3, 3)
    if abs(h[2, 2]) < 1e-12 or not np.isfinite(h).all():
        return None
    h = h / h[2, 2]
    if np.linalg.det(h) <= 0:  # an orientation-reversing homography is not a plausible image motion
        return None
    return h
