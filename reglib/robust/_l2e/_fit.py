"""``l2e_fit``: the L2E estimate of a non-rigid transformation from normalized putative matches, as its stages."""
from __future__ import annotations

import numpy as np

from .._options import L2EOptions
from ._anneal import anneal
from ._decide import decide
from ._levels import refine_levels, regrow
from ._start import start
from ._state import Fit


def l2e_fit(u: np.ndarray, y: np.ndarray, opts: L2EOptions, rng: np.random.Generator) -> Fit:
    """Estimate the transformation from normalized putative matches ``u -> y`` (both (N, D)).

    The stages (:mod:`reglib.robust._l2e`): the start (the work subset and the best first estimate),
    the annealing of the coarse level, the finer levels, the regrown level, the decision.
    ``rng`` draws the work subset when N exceeds ``opts.max_work_points``; nothing else is random.
    """
    state = anneal(start(u, y, opts, rng), opts)
    state = refine_levels(state, opts)
    state = regrow(state, opts)
    return decide(state, opts)
