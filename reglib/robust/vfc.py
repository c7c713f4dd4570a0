"""Vector Field Consensus (Ma, Zhao, Tian, Yuille, Tu, IEEE TIP 23(4), 2014), sparse version.

The EM sibling of L2E in the same RKHS: residuals of true matches are N(0, sigma^2 I) with mixing
weight gamma, false matches are uniform with density 1/a (ALGORITHMS.md section 3). E-step: the
posterior p_i that match i is true; M-step: the weighted ridge of the shared solver with
regularization lambda sigma^2 K, then sigma^2 and gamma in closed form.

References
----------
.. [1] J. Ma, J. Zhao, J. Tian, A. L. Yuille, Z. Tu, "Robust Point Matching via Vector Field
       Consensus", IEEE Trans. Image Processing 23(4), 2014. :doi:`10.1109/TIP.2014.2307478`
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from .._validation import check_int, check_range
from ..errors import InputError
from ._core import (
    LINEAR_KINDS,
    Model,
    WeightedSolver,
    farthest_point_centers,
    identity_model,
    mixture_posterior,
)
from .l2e import Fit

__all__ = ["VFCOptions", "vfc_fit"]


@dataclass(frozen=True, slots=True, kw_only=True)
class VFCOptions:
    """Options of VFC, published defaults (normalized units).

    Parameters
    ----------
    linear : {"none", "affine", "homography"}
        Global part fitted jointly (the published method has none).
    n_centers : int
        Sparse basis size (SparseVFC: 16).
    beta : float
        Kernel width, exp(-beta |x - c|^2) (published 0.1).
    lam : float
        Regularization lambda (published 3).
    theta : float
        Posterior above which a match is an inlier (published 0.75).
    outlier_volume : float
        Volume of the outliers' uniform density, the paper's a (published 10). Formerly ``a``.
    gamma : float
        Initial inlier share (published 0.9).
    max_iter : int
        EM iterations at most (published 500; at most 10000).
    tol : float
        Stop when the relative change of the energy is below this (published 1e-5).
    min_matches : int
        Fewer putative matches give the "too few matches" answer.
    """

    linear: Literal["none", "affine", "homography"] = "none"
    n_centers: int = 16
    beta: float = 0.1
    lam: float = 3.0
    theta: float = 0.75
    outlier_volume: float = 10.0

    RENAMED_FIELDS: ClassVar[dict[str, str]] = {"a": "outlier_volume"}
    gamma: float = 0.9
    max_iter: int = 500
    tol: float = 1e-5
    min_matches: int = 6

    def __post_init__(self) -> None:
        if self.linear not in LINEAR_KINDS:
            raise InputError(f"`linear` must be one of {list(LINEAR_KINDS)}, got {self.linear!r}")
        # max_iter's upper bound keeps a request finite.
        for name, high in (("n_centers", None), ("max_iter", 10000), ("min_matches", None)):
            check_int(name, getattr(self, name), 1, high)
        check_range("beta", self.beta, 0, low_open=True)
        check_range("lam", self.lam, 0)
        check_range("theta", self.theta, 0, 1, low_open=True, high_open=True)
        check_range("outlier_volume", self.outlier_volume, 0, low_open=True)
        check_range("gamma", self.gamma, 0, 1, low_open=True, high_open=True)
        check_range("tol", self.tol, 0, low_open=True)


def vfc_fit(u: np.ndarray, y: np.ndarray, opts: VFCOptions, rng: np.random.Generator) -> Fit:
    """EM estimate of the field from normalized putative matches ``u -> y`` (both (N, D))."""
    n, d = u.shape
    centers = farthest_point_centers(u, opts.n_centers, rng)
    solver = WeightedSolver(u, y, centers, opts.beta, opts.linear)
    model = identity_model(d, opts.linear)
    model = Model(model.linear, centers, opts.beta, np.zeros((len(centers), d)))
    e2 = ((y - model.predict(u, solver.basis)) ** 2).sum(1)
    sigma2 = max(float(e2.sum()) / (n * d), 1e-10)
    gamma = opts.gamma
    energy = np.inf
    converged = False
    p = np.ones(n)
    it = 0
    for it in range(1, opts.max_iter + 1):
        # E-step: posterior of being a true match.
        p = mixture_posterior(e2, sigma2, gamma, d, opts.outlier_volume)
        sp = float(p.sum())
        # M-step: weighted ridge with lambda sigma^2 K.
        model = solver.solve(p, model, opts.lam * sigma2)
        e2 = ((y - model.predict(u, solver.basis)) ** 2).sum(1)
        sigma2 = max(float((p * e2).sum()) / (d * max(sp, 1e-300)), 1e-10)
        gamma = float(np.clip(np.mean(p > opts.theta), 0.05, 0.95))
        w = model.weights
        reg = float(np.trace(w.T @ solver.gram @ w)) if len(w) else 0.0
        new_energy = float((p * e2).sum()) / (2.0 * sigma2) + 0.5 * d * sp * np.log(sigma2) + 0.5 * opts.lam * reg
        if np.isfinite(energy) and abs(new_energy - energy) <= opts.tol * max(abs(energy), 1e-12):
            converged = True
            break
        energy = new_energy
    p = mixture_posterior(e2, sigma2, gamma, d, opts.outlier_volume)
    return Fit(model, p, p > opts.theta, float(np.sqrt(sigma2)), it, converged)
