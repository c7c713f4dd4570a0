"""A plain port of the published sparse Vector Field Consensus (SparseVFC.m), a speed and accuracy peer.

Ma, Zhao, Tian, Yuille, Tu, "Robust Point Matching via Vector Field Consensus", IEEE TIP 23(4), 2014,
sparse approximation of Section V. Written here from the paper's algorithm and its published defaults
(beta 0.1, lambda 3, theta 0.75, a 10, gamma 0.9 at the start, 16 random control points, EM until the
relative change of the energy falls below 1e-5 or 500 iterations, posteriors floored at 1e-5): each set
normalized to zero mean and unit RMS radius, the motion field ``v = y - x`` of the normalized sets
fitted as a Gaussian-kernel field on the control points. Not part of the library (benchmarks only).
"""
from __future__ import annotations

import numpy as np


def _normalize(p: np.ndarray) -> np.ndarray:
    c = p - p.mean(0)
    return c / np.sqrt((c * c).sum(1).mean())


def _kernel(a: np.ndarray, b: np.ndarray, beta: float) -> np.ndarray:
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
    return np.exp(-beta * np.maximum(d2, 0.0))


def sparse_vfc(src: np.ndarray, dst: np.ndarray, seed: int = 0, *, beta: float = 0.1, lam: float = 3.0,
               theta: float = 0.75, a: float = 10.0, gamma: float = 0.9, n_ctrl: int = 16, max_iter: int = 500,
               ecr: float = 1e-5, min_p: float = 1e-5) -> np.ndarray:
    """Inlier mask (N,) of the putative matches ``src -> dst`` (both (N, D)) by SparseVFC."""
    x, y = _normalize(np.asarray(src, float)), _normalize(np.asarray(dst, float))
    n, d = x.shape
    v_obs = y - x
    rng = np.random.default_rng(seed)
    ctrl = x[rng.choice(n, min(n_ctrl, n), replace=False)]
    k = _kernel(ctrl, ctrl, beta)
    u = _kernel(x, ctrl, beta)
    v = np.zeros_like(v_obs)
    sigma2 = float((v_obs * v_obs).sum()) / (n * d)
    energy_old, p = 1.0, np.ones(n)
    coef = np.zeros((len(ctrl), d))
    for _ in range(max_iter):
        r2 = ((v_obs - v) ** 2).sum(1)
        inl = np.exp(-r2 / (2.0 * sigma2))
        p = inl / (inl + (2.0 * np.pi * sigma2) ** (d / 2.0) * (1.0 - gamma) / (gamma * a))
        energy = float(p @ r2) / (2.0 * sigma2) + float(p.sum()) * np.log(sigma2) * d / 2.0
        energy += lam / 2.0 * float(np.trace(coef.T @ k @ coef))  # the field's RKHS norm
        change = abs((energy - energy_old) / energy)
        energy_old = energy
        pw = np.maximum(p, min_p)
        up = u * pw[:, None]
        coef = np.linalg.solve(up.T @ u + lam * sigma2 * k, up.T @ v_obs)
        v = u @ coef
        r2 = ((v_obs - v) ** 2).sum(1)
        sigma2 = float(pw @ r2) / (float(pw.sum()) * d)
        gamma = min(max(float(np.count_nonzero(p > theta)) / n, 0.05), 0.95)
        if change <= ecr or sigma2 <= 1e-8:
            break
    return p > theta
