"""The finer levels of the L2E fit, and the regrown level.

Finer levels: the matches that may be true under the current estimate (within :data:`CANDIDATE_R2`
spreads) select a richer basis, as many centres as they support (at most 4x the previous level),
the kernel narrowed in proportion, fitted by the same criterion with a fixed small number of
re-weighting steps, at the spread of the true matches' residuals (the mixture's sigma), wide enough
to take in the ones the coarser field missed. Cost and memory stay O(N M): a level fits a few
candidates per centre and the work matches are evaluated in blocks of rows.

Regrowing: candidates are chosen near the field, so a steep local deformation that the smoother
levels missed stays missed; its matches are far from the field but agree with their neighbours
(:func:`reglib.robust._locality.agreeing_far`), and one more fit takes them in when it keeps what the
field explained.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .._core import Model, WeightedSolver, farthest_point_centers
from .._locality import CANDIDATE_R2, EXPLAINED_R2, agreeing_far
from .._options import L2EOptions
from ._reweight import predict_with, reweighted_fit
from ._scale import scales
from ._state import State, central, subset

# A regrown fit is kept when it loses at most this share of the matches the field explained ...
_REGROW_LOST = 0.1
# ... and explains at least this many times as many new ones as it lost ...
_REGROW_GAIN = 1.0
# ... and at least this many agreeing far matches (of the probe rows), before and after.
_REGROW_GROUP = 4
# A finer level is kept when it explains at least this share of what the smoother one explained.
_KEEP_EXPLAINED = 0.99


def refine_levels(state: State, opts: L2EOptions) -> State:
    """Up to ``opts.max_levels`` finer levels over ``state``; each kept one replaces the field.

    Without a coarse kernel (``n_centers=0``: the linear part alone) there are no finer levels."""
    work = state.work
    for _ in range(opts.max_levels if opts.n_centers else 0):
        cand = np.flatnonzero(state.e2 < CANDIDATE_R2 * state.spread2)
        m_next = int(min(opts.max_centers, len(cand) / opts.matches_per_center, 4 * state.m))
        if m_next < 1.5 * state.m:
            break
        fine, solver, fit_idx, it = _level_fit(state, cand, m_next, opts)
        r = work.yw - predict_with(solver, fine, fit_idx, work.uw)
        e2 = (r ** 2).sum(1)
        # A richer basis must keep every match the smoother one explained (within EXPLAINED_R2
        # spreads); losing some means it has begun to follow noise or outliers somewhere.
        radius2 = EXPLAINED_R2 * state.spread2
        if np.count_nonzero(e2 < radius2) < _KEEP_EXPLAINED * np.count_nonzero(state.e2 < radius2):
            break
        state = _replaced(state, fine, m_next, (r, e2), (solver, fit_idx), it + 1)
    return state


def regrow(state: State, opts: L2EOptions) -> State:
    """Up to ``opts.regrow`` regrown levels over ``state`` (:func:`_regrown`), while one is kept."""
    on = opts.n_centers and opts.max_centers and opts.linear != "none"
    for _ in range(opts.regrow if on else 0):
        grown = _regrown(state, opts)
        if grown is None:
            break
        state = grown
    return state


def _replaced(state: State, model: Model, m: int, residuals: tuple[np.ndarray, np.ndarray],
              level: tuple[WeightedSolver, np.ndarray], n_solves: int) -> State:
    """``state`` with the field ``model`` (``m`` centres; ``residuals``: the work matches' residual vectors and
    squared norms under it) of the level ``level`` in place, its scales re-estimated from the previous spread,
    and ``n_solves`` more solves counted."""
    r, e2 = residuals
    work = state.work
    sharp2, spread2 = scales(e2[work.probe], state.spread2, work.uw.shape[1], work.volume)
    return dataclasses.replace(state, model=model, m=m, r=r, e2=e2, sharp2=sharp2, spread2=spread2, level=level,
                               n_iter=state.n_iter + n_solves)


def _level_fit(state: State, cand: np.ndarray, m_next: int, opts: L2EOptions, *, full: np.ndarray | None = None,
               n_iter: int | None = None) -> tuple[Model, WeightedSolver, np.ndarray, int]:
    """A finer level on the candidate rows ``cand``: ``m_next`` centres, the state's linear part, one solve
    weighted by its residuals at its spread (rows ``full`` at weight 1), ``n_iter`` (default
    ``opts.fine_iter``) re-weightings. Returns (model, solver, the rows it fits, re-weightings made)."""
    uw, yw, spread2 = state.work.uw, state.work.yw, state.spread2
    # A narrower kernel needs larger weights for the same field, so its RKHS norm grows with M;
    # the ridge is scaled down to keep the same trade-off between fit and smoothness.
    lam = opts.regularization * (opts.n_centers / m_next)
    fit_idx = subset(cand, max(opts.max_fit_points, int(1.5 * opts.matches_per_center * m_next)), state.work.fixed)
    # Without a linear part the kernel carries the global motion too, which narrow kernels
    # cannot: there the width stays and only the number of centres grows.
    beta = opts.beta * m_next / opts.n_centers if opts.linear != "none" else opts.beta
    centers = farthest_point_centers(uw[fit_idx], m_next, None, start=central(uw[fit_idx]))
    solver = WeightedSolver(uw[fit_idx], yw[fit_idx], centers, beta, opts.linear)
    first = Model(state.model.linear, centers, beta, np.zeros((len(centers), uw.shape[1])))
    phi0 = np.exp(-state.e2[fit_idx] / (2.0 * spread2))
    if full is not None:
        phi0[np.isin(fit_idx, full)] = 1.0
    first = solver.solve(phi0, first, lam * float(phi0.sum()) * spread2)
    fine, it, _ = reweighted_fit(solver, first, spread2, opts, lam, opts.fine_iter if n_iter is None else n_iter)
    return fine, solver, fit_idx, it


def _regrown(state: State, opts: L2EOptions) -> State | None:
    """One more level (:func:`_level_fit`, from the state's centres to ``opts.max_centers``) on the candidates
    and the far probe rows that agree with their neighbours (at full weight), or None.

    Kept when, on the probe rows, it loses at most _REGROW_LOST of what the field explained (within
    EXPLAINED_R2 spreads) and explains max(_REGROW_GROUP, _REGROW_GAIN x lost) others."""
    work, e2, spread2 = state.work, state.e2, state.spread2
    probe = work.probe
    # agreement among the probe rows only (at most max_fit_points: the k-NN of all far matches is costly)
    agree = agreeing_far(work.uw[probe], state.r[probe], e2[probe], spread2)
    if np.count_nonzero(agree) < _REGROW_GROUP:
        return None
    cand = np.union1d(np.flatnonzero(e2 < CANDIDATE_R2 * spread2), probe[agree])
    m_next = int(min(opts.max_centers, max(len(cand) / opts.matches_per_center, state.m)))
    grown, solver, fit_idx, it = _level_fit(state, cand, m_next, opts, full=probe[agree],
                                            n_iter=max(opts.fine_iter, 2))
    # decided on the probe rows; the other rows are evaluated for a kept fit only
    radius2 = EXPLAINED_R2 * spread2
    before = e2[probe] < radius2
    after = ((work.yw[probe] - grown.predict(work.uw[probe])) ** 2).sum(1) < radius2
    lost = int(np.count_nonzero(before & ~after))
    gained = int(np.count_nonzero(after & ~before))
    if lost > _REGROW_LOST * np.count_nonzero(before) or gained < max(_REGROW_GROUP, _REGROW_GAIN * lost):
        return None
    r = work.yw - predict_with(solver, grown, fit_idx, work.uw)
    return _replaced(state, grown, len(grown.centers), (r, (r ** 2).sum(1)), (solver, fit_idx), it + 1)
