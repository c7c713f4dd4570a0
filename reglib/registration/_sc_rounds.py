"""The describe-match-estimate rounds of one rotation hypothesis, and the EM refinement after them.

A :class:`_Track` follows one hypothesis: :func:`_rounds` describes the warped model and the
target, matches them, and fits an affine + kernel map by L2E (:func:`_fit`), with the support
mask shrinking each round; :func:`_refine` then runs EM steps of a Gaussian mixture with a uniform
outlier term on the result. The loop that runs the hypotheses is
:func:`reglib.registration._sc_l2e.sc_l2e_register`.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.spatial import cKDTree

from .._transforms import LinearPart
from ..features import chi2_cost
from ..robust import L2EOptions, Model, WeightedSolver, farthest_point_centers, l2e_scale, reweighted_fit
from ._cpd import cpd_posterior
from ._sc_match import _assign, _Describer
from ._sc_options import RegistrationOptions


@dataclass
class _Track:
    """One rotation hypothesis followed through the rounds.

    The fits run in the rotated frame ``ur = us R^T``; ``x`` is the warped model subset.
    """

    rot: np.ndarray
    ur: np.ndarray
    x: np.ndarray
    hx0: np.ndarray | None = None  # descriptors of x before the first round, when known
    model: Model | None = None
    resid2: np.ndarray | None = None  # squared residuals of the last fit's matches
    sigma2_fit: float = np.inf  # the last annealing scale of that fit
    scale: float | None = None  # residual scale, once asked for (set by the EM refinement)
    rounds: int = 0
    moved: float = np.inf

    @property
    def sigma(self) -> float:
        """Residual scale of the last fit: partial-L2E estimate, computed on first use."""
        if self.scale is None:
            self.scale = (float(np.sqrt(l2e_scale(self.resid2, self.sigma2_fit, self.x.shape[1])))
                          if self.resid2 is not None else np.inf)
        return self.scale


def _fit(u: np.ndarray, y: np.ndarray, opts: L2EOptions,
         rng: np.random.Generator) -> tuple[Model, np.ndarray, float]:
    """L2E estimate of an affine + kernel map from the matches ``u -> y``, its squared residuals and last scale.

    The coarse level of :func:`reglib.robust._l2e.l2e_fit` (the published annealing, by the same
    re-weighted solver), without its finer levels and inlier classification, which a round of the
    loop does not use.
    """
    centers = farthest_point_centers(u, opts.n_centers, rng)
    solver = WeightedSolver(u, y, centers, opts.beta, "affine")
    model = Model(LinearPart("affine", np.c_[np.eye(u.shape[1]), np.zeros(u.shape[1])]), centers, opts.beta,
                  np.zeros((len(centers), u.shape[1])))
    sigma2 = opts.sigma2_init
    for k in range(opts.n_anneal + 1):
        sigma2 = opts.sigma2_init * opts.anneal_rate**k
        model, _, _ = reweighted_fit(solver, model, sigma2, opts, opts.lam if opts.lam is not None else 0.0)
    e2 = ((y - model.predict(u, solver.basis)) ** 2).sum(1)
    return model, e2, sigma2


@dataclass(frozen=True, eq=False)
class _Loop:
    """What every round of one registration shares: the descriptor, the options, a round's L2E options, the rng."""

    describe: _Describer
    opts: RegistrationOptions
    l2e_opts: L2EOptions
    rng: np.random.Generator


@dataclass(frozen=True, eq=False)
class _Target:
    """The target of one pass: its (sub)sampled points, their descriptors (of the first round) and k-d tree."""

    points: np.ndarray
    descriptors: np.ndarray
    tree: cKDTree


def _rounds(track: _Track, n: int, target: _Target, loop: _Loop,
            cost: Callable[[np.ndarray, np.ndarray], np.ndarray] = chi2_cost, restrict: bool = False) -> _Track:
    """``n`` more describe-match-estimate rounds of one hypothesis, matching descriptors by ``cost``.

    From the second round, points the current warp leaves far from the other set do not count in
    the descriptors (support); with ``restrict`` such target points cannot be matched either.
    """
    ys, hy_all, y_tree = target.points, target.descriptors, target.tree
    describe, opts, l2e_opts, rng = loop.describe, loop.opts, loop.l2e_opts, loop.rng
    d = ys.shape[1]
    for r in range(track.rounds, track.rounds + n):
        hy, sx = hy_all, None
        if r > 0:
            # support: only points the current warp puts near the other set count in descriptors
            radius = max(opts.support_min, opts.support_radius * opts.support_decay ** (r - 1))
            sx = cast(np.ndarray, y_tree.query(track.x)[0]) < radius  # (N, D) queries: arrays
            to_x = cast(np.ndarray, cKDTree(track.x).query(ys)[0])
            sy = to_x < radius
            if sy.sum() >= 3:
                hy = describe(ys, sy)
            if sx.sum() < 3:
                sx = None
            if restrict and sy.sum() >= 3:  # only supported target points may be matched
                ia, ib = _assign(cost(describe(track.x, sx), hy[sy]), opts.dummy_cost)
                ib = np.flatnonzero(sy)[ib]
            else:
                ia, ib = _assign(cost(describe(track.x, sx), hy), opts.dummy_cost)
        elif track.hx0 is not None:
            ia, ib = _assign(cost(track.hx0, hy), opts.dummy_cost)
        else:
            ia, ib = _assign(cost(describe(track.x, sx), hy), opts.dummy_cost)
        track.rounds = r + 1
        if len(ia) < max(d + 2, 5):  # nothing to estimate from: keep the current map
            continue
        model, track.resid2, track.sigma2_fit = _fit(track.ur[ia], ys[ib], l2e_opts, rng)
        new = model.predict(track.ur)
        track.moved = float(np.abs(new - track.x).max(initial=0.0))
        track.x, track.model, track.scale = new, model, None
    return track


def _refine(track: _Track, ys: np.ndarray, opts: RegistrationOptions, sigma2_floor: float) -> _Track:
    """EM steps of a Gaussian mixture with a uniform outlier term, seeded by the L2E result.

    The registered model points are the mixture's centroids (as in CPD [2]);
    each target point spreads its responsibility over the centroids near it, or over the outlier
    term (weight ``outlier_weight``), so target outliers and model parts the target lacks pull on
    nothing. The M-step is the weighted kernel regression of the L2E solver with each centroid's
    total responsibility as its weight and the responsibility-weighted mean of the targets as its
    goal. This uses every target point rather than one assigned partner, which the
    one-to-one shape-context assignment cannot offer once outliers crowd the target.
    """
    if track.model is None or opts.n_refine == 0:
        return track
    ur, model = track.ur, track.model
    d = ur.shape[1]
    sigma2 = max(track.sigma**2, sigma2_floor)
    w = opts.outlier_weight
    x = track.x
    y2 = (ys * ys).sum(1)
    for _ in range(opts.n_refine):
        p = cpd_posterior(ys, x, sigma2, w)  # (model, target): the CPD E-step, the model as centroids
        p1 = p.sum(1)
        sp = float(p1.sum())
        if sp <= 1e-12:
            break
        py = p @ ys
        goal = py / np.maximum(p1, 1e-300)[:, None]
        solver = WeightedSolver(ur, goal, model.centers, model.beta, "affine")
        old = x
        model = solver.solve(p1, model, opts.lam * sigma2 * sp)
        new = model.predict(ur, solver.basis)
        track.moved = float(np.abs(new - x).max(initial=0.0))
        x = new
        # the scale only shrinks: grown, the Gaussians would start to take in the outliers
        # sum_mn p_mn |y_n - x_m|^2 (with the pre-step centroids x), without an (N, M) distance array
        spread = float(p.sum(0) @ y2 - 2.0 * np.einsum("md,md->", old, py) + p1 @ (old * old).sum(1))
        sigma2 = max(min(spread / (d * sp), sigma2), sigma2_floor)
    track.x, track.model, track.scale = x, model, float(np.sqrt(sigma2))
    return track
