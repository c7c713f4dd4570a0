"""The coarse level of the L2E fit: deterministic annealing of sigma^2, as in the published code.

Each step re-weights and re-solves at a fixed width (:func:`reweighted_fit`), from the previous
step's answer; only the last step's answer is used, the earlier ones seed the next, narrower one.
"""
from __future__ import annotations

from .._options import L2EOptions
from ._reweight import predict_with, reweighted_fit
from ._scale import SIGMA2_MIN, scales
from ._start import Start
from ._state import State

# Re-weighting iterations of the annealing steps before the last: more changed no decision on the
# benchmarks (bench_filter), and each one is a solve.
_SEED_STEP_ITER = 3


def anneal(begin: Start, opts: L2EOptions) -> State:
    """Anneal from ``begin``'s first estimate through the schedule sigma2_init * anneal_rate**k to its last
    step; the :class:`State` holds the coarse field and the residual scales it leaves on the work matches."""
    model, solver, converged = begin.model, begin.solver, False
    n_iter, sigma2 = begin.n_iter, opts.sigma2_init
    for k in range(begin.first_step, opts.n_anneal + 1):
        sigma2 = max(opts.sigma2_init * opts.anneal_rate**k, SIGMA2_MIN)
        cap = opts.max_iter if k == opts.n_anneal else min(opts.max_iter, _SEED_STEP_ITER)
        # (the comparison's phi of the start is the first step's when it goes on at that width)
        reuse = begin.first if k == begin.first_step else None
        model, it, converged = reweighted_fit(solver, model, sigma2, opts, opts.regularization, cap, first=reuse)
        n_iter += it
    work = begin.work
    r = work.yw - predict_with(solver, model, begin.pool, work.uw)
    e2 = (r ** 2).sum(1)
    sharp2, spread2 = scales(e2[work.probe], sigma2, work.uw.shape[1], work.volume)
    return State(work=work, model=model, m=opts.n_centers, r=r, e2=e2, sharp2=sharp2, spread2=spread2,
                 level=None, n_iter=n_iter, converged=converged)
