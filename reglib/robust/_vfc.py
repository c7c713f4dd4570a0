"""Vector Field Consensus (Ma, Zhao, Tian, Yuille, Tu, IEEE TIP 23(4), 2014), sparse version.

The EM sibling of L2E in the same RKHS: residuals of true matches are N(0, sigma^2 I) with mixing
weight gamma, false matches are uniform with density 1/a ([1]). E-step: the
posterior p_i that match i is true; M-step: the weighted ridge of the shared solver with
regularization lambda sigma^2 K, then sigma^2 and gamma in closed form.

References
----------
.. [1] J. Ma, J. Zhao, J. Tian, A. L. Yuille, Z. Tu, "Robust Point Matching via Vector Field
       Consensus", IEEE Trans. Image Processing 23(4), 2014. :doi:`10.1109/TIP.2014.2307478`
"""
from __future__ import annotations

import numpy as np

from ._core import (
    Model,
    WeightedSolver,
    farthest_point_centers,
    identity_model,
    mixture_posterior,
)
from ._l2e import Fit
from ._options import VFCOptions

__all__ = ["vfc_fit"]


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
    for it in range(1, opts.max_iter + 1):  # noqa: B007 (the count is returned)
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
