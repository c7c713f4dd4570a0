"""The robust ICP's choice among its starts, and more iterations for an ICP still climbing.

:func:`coarse_winner` runs every start of the coarse stage (:func:`reglib.registration._icp.refine_icp`) on
the small sample and keeps the one whose converged pose brings most of it within two target spacings. With
more than ``_SHORTLIST + 1`` starts each first runs ``_PROBE`` iterations and only the first start (the
best by the feature evidence or the search) and the ``_SHORTLIST`` best by the score go on converging (a
wrong start otherwise runs to ``max_iter``).

:func:`go_on`: an ICP that its iteration cap stopped while each round still raised that score is not
settled, it is slow. On a wide flat part of a scene (a table top) a robust ICP from a start 16 degrees
off moves a fraction of a degree an iteration; cut off at ``max_iter`` it scores below a wrong start that
settled nearby and loses to it, and the wrong pose, a well pinned one, is not said by any check. So a
capped finalist below the best goes on, a round of ``max_iter`` iterations at a time, while a round raises
the score by more than ``_GAIN`` (a share of the sample brought within reach), at most ``_ROUNDS`` more
rounds; then the winner does the same. A run that creeps without gaining stops after one more round.

A runner-up that climbed over the best takes the lead only when the sample says so clearly
(:func:`overtakes`): its per-point scores beat the best's on the same sample points by more than ``_Z``
standard errors of the mean paired difference. At low overlap a capped run can also be creeping along a
slide, gaining a little overlap each round; that gain stays within the sample's noise, a slow right start's
does not (benchmarks/README.md, issue 51's second pass).

The caller owns the sample, the loop and the score (callables).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from ._rigid import RigidFit

__all__ = ["coarse_winner", "go_on", "overtakes"]

_PROBE = 20     # coarse stage: iterations every start runs before the shortlist ...
_SHORTLIST = 2  # ... and the best by it that go on converging, with the first start
_ROUNDS = 3     # a capped ICP still climbing runs at most this many more rounds of max_iter iterations
# ... while a round raises the score (share of the sample within reach) by more than this: a fifth of a percent,
# well under what a slow run converging on a fit gains a round and over what one creeping far from any fit does
_GAIN = 0.002
_Z = 3.0        # a runner-up takes the lead only by this many standard errors of the paired difference (3 sigma)

Run = Callable[[np.ndarray, int], RigidFit]
Score = Callable[[np.ndarray], float]


def go_on(fit: RigidFit, run: Run, score: Score, current: float, max_iter: int) -> tuple[RigidFit, float]:
    """``fit`` continued while its cap stops it and a round gains (module docstring).

    Parameters
    ----------
    fit : RigidFit
        An ICP's answer; returned as it is when it converged.
    run : callable
        ``run(matrix, n)``: the same ICP from ``matrix`` for at most ``n`` iterations.
    score : callable
        ``score(matrix)``: the support of a pose (higher is better).
    current : float
        ``score(fit.matrix)``.
    max_iter : int
        Iterations of a round.

    Returns
    -------
    RigidFit, float
        The last round's answer (its ``n_iter`` counting every round) and its score.
    """
    for _ in range(_ROUNDS):
        if fit.converged:
            break
        more = run(fit.matrix, max_iter)
        gain = score(more.matrix) - current
        fit, current = replace(more, n_iter=fit.n_iter + more.n_iter), current + gain
        if gain <= _GAIN:
            break
    return fit, current


def coarse_winner(cands: Sequence[np.ndarray], run: Run, scores_of: Callable[[np.ndarray], np.ndarray],
                  allowed: Callable[[int, np.ndarray], bool], max_iter: int) -> RigidFit:
    """The coarse stage's answer: the best scored of the starts ``cands`` run to convergence (module docstring).

    Parameters
    ----------
    cands : sequence of (D, D + 1) ndarray
        The starts, the first ranked first by its evidence.
    run : callable
        As for :func:`go_on`.
    scores_of : callable
        ``scores_of(matrix)``: each sample point's term of the score (its mean is the score).
    allowed : callable
        ``allowed(i, matrix)``: whether start ``i``, run to ``matrix``, may win.
    max_iter : int
        The coarse ICP's iterations at most (before :func:`go_on`).

    Returns
    -------
    RigidFit
        The winner, ``n_iter`` counting its every iteration.
    """
    def score(m: np.ndarray) -> float:
        return float(scores_of(m).mean())

    probing = len(cands) > _SHORTLIST + 1 and max_iter > _PROBE
    fits = [run(c, _PROBE if probing else max_iter) for c in cands]
    scores = [score(f.matrix) for f in fits]
    finalists = [i for i in range(len(cands)) if allowed(i, fits[i].matrix)]
    if probing:
        # the start the evidence ranks first goes on whatever its early score (a true start
        # 100 degrees off can still be 50 degrees off after the probe), with the best of the probe
        finalists = sorted({0, *sorted(finalists, key=lambda i: -scores[i])[:_SHORTLIST]})
        for i in finalists:
            if not fits[i].converged:
                more = run(fits[i].matrix, max_iter - _PROBE)
                fits[i] = replace(more, n_iter=fits[i].n_iter + more.n_iter)
                scores[i] = score(more.matrix)
    # a capped finalist below the best goes on while it climbs; it takes the lead only when the sample says so
    # clearly (overtakes), then the winner goes on while it climbs
    top = max(finalists, key=lambda i: (scores[i], -i))
    for i in finalists:
        if scores[i] < scores[top] and not fits[i].converged:
            more, gained = go_on(fits[i], run, score, scores[i], max_iter)
            if gained <= scores[top] or overtakes(scores_of(more.matrix), scores_of(fits[top].matrix)):
                fits[i], scores[i] = more, gained
    best = max(finalists, key=lambda i: (scores[i], -i))
    return go_on(fits[best], run, score, scores[best], max_iter)[0]


def overtakes(new: np.ndarray, old: np.ndarray) -> bool:
    """Whether the per-point scores ``new`` beat ``old`` (the same sample points) by more than ``_Z`` standard
    errors of their mean paired difference: a run creeping along a slide at low overlap gains a little
    overlap at each round, within the sample's noise; a slow right start gains much more."""
    diff = new - old
    spread = float(diff.std()) / np.sqrt(max(len(diff), 1))
    return float(diff.mean()) > _Z * spread
