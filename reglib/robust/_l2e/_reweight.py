"""One L2E fit at a fixed scale: re-weight by phi at the current estimate and re-solve until it settles.

The building block of every stage of :func:`reglib.robust._l2e.l2e_fit` and of the shape-context
registration's rounds (:mod:`reglib.registration`). Normalized, trusted arrays.
"""
from __future__ import annotations

import numpy as np

from .._core import Model, WeightedSolver
from .._options import L2EOptions


def phi(y: np.ndarray, pred: np.ndarray, sigma2: float) -> np.ndarray:
    """phi_i = exp(-|y_i - pred_i|^2 / 2 sigma2), with as few temporaries as the arithmetic allows."""
    e = y - pred
    e *= e
    e2 = e.sum(1)
    e2 /= -2.0 * sigma2
    return np.exp(e2, out=e2)


def reweighted_fit(solver: WeightedSolver, model: Model, sigma2: float, opts: L2EOptions,
                   lam: float, max_iter: int | None = None, *,
                   first: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[Model, int, bool]:
    """Re-weight with phi at the current estimate and re-solve, at fixed sigma, until predictions settle
    (at most ``max_iter`` times, default ``opts.max_iter``). ``first``: ``solver.fitted(model)``
    and its phi at ``sigma2`` when the caller has them (:func:`phi`).

    Returns the model, the re-weightings made and whether the predictions moved less than ``opts.tol``.
    """
    n_iter = opts.max_iter if max_iter is None else max_iter
    pred = solver.fitted(model) if first is None else first[0]
    for it in range(1, n_iter + 1):
        weights = phi(solver.y, pred, sigma2) if it > 1 or first is None else first[1]
        model = solver.solve(weights, model, lam * float(weights.sum()) * sigma2)
        new_pred = solver.fitted(model)
        moved = float(np.abs(new_pred - pred).max(initial=0.0))
        pred = new_pred
        if moved < opts.tol:
            return model, it, True
    return model, n_iter, False


def predict_with(solver: WeightedSolver, model: Model, rows: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``model.predict(points)``, where ``points[rows]`` are the solver's own (their kernel matrix
    is at hand): only the other rows are evaluated anew."""
    if len(rows) == len(points):
        return solver.fitted(model)
    out = np.empty_like(points)
    out[rows] = solver.fitted(model)
    rest = np.ones(len(points), dtype=bool)
    rest[rows] = False
    out[rest] = model.predict(points[rest])
    return out
