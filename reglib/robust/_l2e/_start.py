"""The first stage of the L2E fit: the work subset, the coarse basis, and the best of a few first estimates.

The annealing starts from the best of a few deterministic first estimates (``start="locality"``: the
identity, a fit weighted by neighbourhood consistency, one through the best similarity of pairs of
consistent matches; :mod:`reglib.robust._locality`, :mod:`reglib.robust._start`), so it needs no start
near the answer, and below ``max_work_points`` matches every choice is made from the data alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._core import Model, WeightedSolver, farthest_point_centers, identity_model
from .._locality import neighborhood_consistency
from .._options import L2EOptions
from .._start import best_similarity_weights
from ._reweight import phi
from ._scale import SIGMA2_MIN
from ._state import FixedDraws, Work, central, subset, volume

# Below this total prior weight (about two matches with consistent neighbourhoods) there is no
# locality evidence and the coarse level starts from the identity, as published.
_MIN_PRIOR_MASS = 2.0
# Matches the locality prior is computed on, at most (evenly spaced; its k-d tree queries are the cost).
_PRIOR_POINTS = 500
# Annealing step at whose width the first estimates are compared and from which a non-identity
# start anneals on: the last of the published schedule (0.05 halved 3 times).
CONSENSUS_STEP = 3


@dataclass(frozen=True)
class Start:
    """Where the annealing begins: the coarse level's solver on the rows ``pool`` of the work subset,
    the first estimate ``model``, the annealing step it goes on from, and (``first``) its predictions
    and phi at that step's width when the comparison computed them; ``n_iter``: solves made."""

    work: Work
    solver: WeightedSolver
    pool: np.ndarray
    model: Model
    first_step: int
    first: tuple[np.ndarray, np.ndarray] | None
    n_iter: int


def start(u: np.ndarray, y: np.ndarray, opts: L2EOptions, rng: np.random.Generator) -> Start:
    """The :class:`Start` of the fit of the normalized matches ``u -> y`` (both (N, D))."""
    n, d = u.shape
    # All levels work on a seeded subset of at most max_work_points matches; the coarse fit uses at
    # most max_fit_points of them. Below max_work_points every choice is made from the data alone
    # (subsets by a fixed internal seed, centres by farthest-point sampling from the most central
    # match): the same matches give the same answer whatever ``rng``.
    rows = subset(np.arange(n), opts.max_work_points, rng)
    fixed = FixedDraws()
    uw, yw = u[rows], y[rows]
    pool = subset(np.arange(len(rows)), opts.max_fit_points, fixed)
    probe = subset(np.arange(len(rows)), opts.max_fit_points, fixed)  # scales are scalars: a sample suffices
    work = Work(u=u, y=y, rows=rows, uw=uw, yw=yw, probe=probe, volume=volume(y), fixed=fixed)
    centers = farthest_point_centers(uw[pool], opts.n_centers, None, start=central(uw[pool]))
    solver = WeightedSolver(uw[pool], yw[pool], centers, opts.beta, opts.linear)
    identity = Model(identity_model(d, opts.linear).linear, centers, opts.beta, np.zeros((len(centers), d)))
    if opts.start != "locality":
        return Start(work, solver, pool, identity, 0, None, 0)
    # Starts are compared at the width of annealing step CONSENSUS_STEP (the published schedule's
    # last), where a minority of true matches stands out from the false ones (at the first, a wide
    # kernel sums over many of those).
    step = min(opts.n_anneal, CONSENSUS_STEP)
    width = max(opts.sigma2_init * opts.anneal_rate**step, SIGMA2_MIN)
    model, n_solves, first = _consensus_start(solver, identity, _prior(uw[pool], yw[pool]), width,
                                               opts.regularization)
    # The wide annealing steps guard a start from the identity against the nearest wrong optimum;
    # a start the consensus chose at its width goes on from that width.
    if model is identity or not step:
        return Start(work, solver, pool, model, 0, None, n_solves)
    return Start(work, solver, pool, model, step, first, n_solves)


def _prior(u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The locality prior of the matches, computed on at most _PRIOR_POINTS of them (evenly spaced;
    the others get no weight in the start)."""
    prior = np.zeros(len(u))
    at = np.linspace(0, len(u) - 1, min(len(u), _PRIOR_POINTS)).astype(np.intp)
    prior[at] = neighborhood_consistency(u[at], y[at])
    return prior


def _consensus_start(solver: WeightedSolver, identity: Model, prior: np.ndarray, sigma2: float,
                     lam: float) -> tuple[Model, int, tuple[np.ndarray, np.ndarray]]:
    """The best of a few deterministic first estimates (:mod:`reglib.robust._start`) by the L2E
    criterion at width ``sigma2`` (the sum of phi), the number of solves made, and the best one's
    ``solver.fitted`` and phi (the first re-weighting step's, when it goes on at this width).

    Candidates: the identity; the solve weighted by the squared locality prior; the solve
    weighted by phi under the best similarity through the top-ranked matches.
    """
    y = solver.y
    candidates = [identity]
    weight = prior * prior
    if float(weight.sum()) >= _MIN_PRIOR_MASS:
        candidates.append(solver.solve(weight, identity, lam * float(weight.sum()) * sigma2))
    similar = best_similarity_weights(solver.u, y, prior, sigma2)
    if similar is not None and float(similar.sum()) >= _MIN_PRIOR_MASS:
        candidates.append(solver.solve(similar, identity, lam * float(similar.sum()) * sigma2))
    preds = [solver.fitted(c) for c in candidates]
    phis = [phi(y, pred, sigma2) for pred in preds]
    best = int(np.argmax([float(p.sum()) for p in phis]))
    return candidates[best], len(candidates) - 1, (preds[best], phis[best])
