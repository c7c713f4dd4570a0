"""What the stages of :func:`reglib.robust._l2e.l2e_fit` hand each other, and the estimator's result.

The stages (``_start`` -> ``_anneal`` -> ``_levels`` -> ``_decide``) are functions of a small frozen
state: :class:`Work` (the matches and the draws, fixed once the fit has started) and :class:`State`
(the current field and what it leaves). Normalized coordinates throughout.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._core import Model, WeightedSolver

_FIXED_SEED = 20130623  # seed of the internal subsets (coarse pool, scale probe, finer levels' fits)


@dataclass(frozen=True)
class Fit:
    """What an RKHS estimator returns in normalized coordinates (private to the package)."""

    model: Model
    scores: np.ndarray
    inliers: np.ndarray
    sigma: float
    n_iter: int
    converged: bool
    volume: float | None = None  # volume(y) of all the matches, when the estimator made it


class FixedDraws:
    """The generator of the internal subsets (seeded with :data:`_FIXED_SEED`), made on its first
    draw: below ``max_fit_points`` matches no subset is drawn, and making one is not free.

    Its draws are made in the stages' order (coarse pool, scale probe, finer levels, decision), so
    the same matches give the same subsets."""

    __slots__ = ("_rng",)

    def __init__(self) -> None:
        self._rng: np.random.Generator | None = None

    def choice(self, idx: np.ndarray, cap: int, replace: bool) -> np.ndarray:
        if self._rng is None:
            self._rng = np.random.default_rng(_FIXED_SEED)
        return self._rng.choice(idx, cap, replace=replace)


def subset(idx: np.ndarray, cap: int, rng: np.random.Generator | FixedDraws) -> np.ndarray:
    """At most ``cap`` of ``idx``, sorted (all of them when there are no more)."""
    return np.sort(rng.choice(idx, cap, replace=False)) if len(idx) > cap else idx


def central(points: np.ndarray) -> int:
    """Row of the point nearest the set's mean: a first centre that depends on the data alone."""
    return int(((points - points.mean(0)) ** 2).sum(1).argmin())


def volume(y: np.ndarray) -> float:
    """Extent of the dst points: the density of a false match's residual is about 1 / volume.

    In normalized units a non-degenerate set spans a volume of several units; a degenerate one
    (all on a line or a point) is held at 1 so exact fits still count as inliers.
    """
    return max(float(np.prod(y.max(0) - y.min(0))), 1.0)


@dataclass(frozen=True)
class Work:
    """The matches every stage works on, fixed by the start.

    ``u``, ``y``: all N matches; ``rows``: the seeded work subset (at most ``max_work_points`` of
    them; all N are evaluated once, at the decision) and ``uw``, ``yw`` its matches; ``probe``:
    rows of the work subset the scales are measured on; ``volume``: :func:`volume` of all of ``y``;
    ``fixed``: the internal subsets' generator.
    """

    u: np.ndarray
    y: np.ndarray
    rows: np.ndarray
    uw: np.ndarray
    yw: np.ndarray
    probe: np.ndarray
    volume: float
    fixed: FixedDraws


@dataclass(frozen=True)
class State:
    """The current field and what it leaves on the work matches.

    ``model`` has ``m`` centres; ``r`` and ``e2`` are the work matches' residual vectors and squared
    norms under it; ``sharp2`` and ``spread2`` their sharp (L2E) and spread (mixture) scales;
    ``level``: the accepted finer level's solver and the rows (of the work subset) it fits, None
    while the coarse level stands; ``n_iter``: solves and re-weightings made so far; ``converged``:
    whether the last annealing step settled.
    """

    work: Work
    model: Model
    m: int
    r: np.ndarray
    e2: np.ndarray
    sharp2: float
    spread2: float
    level: tuple[WeightedSolver, np.ndarray] | None
    n_iter: int
    converged: bool
