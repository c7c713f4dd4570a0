"""Machinery shared by the registration methods, in normalized coordinates on trusted arrays.

Kept here rather than borrowed from ``reglib.robust._core`` so the registration loop does not
depend on the filter's private internals, which are tuned independently.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..transforms import KernelWarp, LinearPart, kernel_matrix


@dataclass(frozen=True)
class Frame:
    """Mean and RMS radius of the model and of the target (ALGORITHMS.md section 1)."""

    src_mean: np.ndarray
    src_scale: float
    dst_mean: np.ndarray
    dst_scale: float

    @classmethod
    def of(cls, model: np.ndarray, target: np.ndarray) -> "Frame":
        sm, tm = model.mean(0), target.mean(0)
        return cls(sm, rms_radius(model - sm), tm, rms_radius(target - tm))

    def normalize(self, model: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (model - self.src_mean) / self.src_scale, (target - self.dst_mean) / self.dst_scale


def rms_radius(centred: np.ndarray) -> float:
    r = float(np.sqrt((centred * centred).sum(1).mean())) if len(centred) else 0.0
    size = max(float(np.abs(centred).max(initial=0.0)), 1.0)
    return r if r > 1e-12 * size else 1.0  # all points equal: any positive scale is right


@dataclass(frozen=True)
class AffineKernel:
    """g(u) = A u + t + sum_m exp(-beta |u - c_m|^2) w_m in normalized coordinates."""

    matrix: np.ndarray  # (D, D+1) = [A | t]
    centers: np.ndarray  # (M, D)
    beta: float
    weights: np.ndarray  # (M, D)

    @classmethod
    def identity(cls, dim: int) -> "AffineKernel":
        return cls(np.c_[np.eye(dim), np.zeros(dim)], np.zeros((0, dim)), 1.0, np.zeros((0, dim)))

    def __call__(self, u: np.ndarray, chunk: int = 1 << 14) -> np.ndarray:
        out = u @ self.matrix[:, :-1].T + self.matrix[:, -1]
        if len(self.centers):
            for s in range(0, len(u), chunk):
                out[s:s + chunk] += kernel_matrix(u[s:s + chunk], self.centers, self.beta) @ self.weights
        return out

    def to_warp(self, frame: Frame) -> KernelWarp:
        return KernelWarp(dim=self.matrix.shape[0], src_mean=frame.src_mean, src_scale=frame.src_scale,
                          dst_mean=frame.dst_mean, dst_scale=frame.dst_scale,
                          linear=LinearPart("affine", self.matrix.copy()), beta=self.beta,
                          centers=self.centers, weights=self.weights)


def farthest_points(points: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``m`` rows spread over ``points`` by farthest-point sampling, O(N m); random start.

    Duplicates are skipped, so fewer than ``m`` come back when there are fewer distinct points.
    """
    n = len(points)
    if n == 0 or m <= 0:
        return np.zeros(0, dtype=np.intp)
    chosen = [int(rng.integers(n))]
    d2 = ((points - points[chosen[0]]) ** 2).sum(1)
    for _ in range(1, min(m, n)):
        i = int(np.argmax(d2))
        if d2[i] <= 1e-24:
            break
        chosen.append(i)
        np.minimum(d2, ((points - points[i]) ** 2).sum(1), out=d2)
    return np.asarray(chosen, dtype=np.intp)


def l2e_irls(u: np.ndarray, y: np.ndarray, centers: np.ndarray, beta: float, lam: float,
             sigma2s: list[float], max_iter: int, tol: float) -> tuple[AffineKernel, int]:
    """L2E estimate of an affine + kernel map from matches ``u -> y`` by annealed IRLS.

    At each scale sigma^2 of ``sigma2s`` the stationarity condition of the L2E criterion with the
    weights phi_i = exp(-|e_i|^2 / 2 sigma^2) held fixed is a weighted ridge regression
    (ALGORITHMS.md section 2), solved jointly for the affine part and the kernel weights; the
    weights are re-computed until no prediction moves by more than ``tol``. ``lam`` is relative to
    sum_i phi_i. Returns the model and the number of solves.
    """
    n, d = u.shape
    basis = kernel_matrix(u, centers, beta)
    design = np.hstack([u, np.ones((n, 1)), basis])
    k = design.shape[1]
    reg = np.zeros((k, k))
    reg[d + 1:, d + 1:] = kernel_matrix(centers, centers, beta)
    target = y - u
    pred = u.copy()
    theta = np.zeros((k, d))
    n_solve = 0
    for sigma2 in sigma2s:
        for _ in range(max_iter):
            p = np.exp(-((y - pred) ** 2).sum(1) / (2.0 * sigma2))
            sp = float(p.sum())
            if sp <= 1e-300:  # nothing within reach at this scale: keep the last estimate
                break
            wd = design * p[:, None]
            a = design.T @ wd + lam * sp * reg
            # a tiny ridge keeps the system definite with few effective matches, and shrinks an
            # undetermined affine part towards the identity
            a[np.diag_indices(k)] += 1e-8 * sp + 1e-12
            try:
                theta = np.linalg.solve(a, wd.T @ target)  # small system: numpy's call overhead is lower
            except np.linalg.LinAlgError:
                theta = np.linalg.lstsq(a, wd.T @ target, rcond=None)[0]
            n_solve += 1
            new = u + design @ theta
            moved = float(np.abs(new - pred).max(initial=0.0))
            pred = new
            if moved < tol:
                break
    matrix = np.c_[np.eye(d) + theta[:d].T, theta[d]]
    return AffineKernel(matrix, centers, beta, theta[d + 1:]), n_solve
