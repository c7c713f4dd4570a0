"""Shape-context description and one-to-one matching for :mod:`reglib.registration._sc_l2e`.

The describer bins a (sub)set in 2-D or 3-D with the options' binning, optionally counting only
a support mask of points; the assignment matches descriptors one to one with dummy partners; the
Hellinger cost is the cheap screen used while many rotation hypotheses compete.
"""
from __future__ import annotations

import numpy as np

from ..features import match_shape_contexts as match_descriptors
from ..features import shape_context, shape_context_3d
from ._sc_options import RegistrationOptions


class _Describer:
    """Shape context of a (sub)set in 2-D or 3-D with the options' binning."""

    def __init__(self, opts: RegistrationOptions, dim: int):
        self.opts, self.dim = opts, dim

    def __call__(self, pts: np.ndarray, support: np.ndarray | None = None) -> np.ndarray:
        o = self.opts
        if self.dim == 2:
            return shape_context(pts, n_angle=o.n_angle, n_radius=o.n_radius, support=support)
        return shape_context_3d(pts, n_radius=o.n_radius, support=support)


def _assign(cost: np.ndarray, dummy: float) -> tuple[np.ndarray, np.ndarray]:
    # raised to the median best cost so that at least about half the points can always match
    return match_descriptors(cost, max(dummy, float(np.median(cost.min(1)))))


def _hellinger_cost(ha: np.ndarray, hb: np.ndarray) -> np.ndarray:
    """Squared Hellinger distance sum_k (sqrt(a_k) - sqrt(b_k))^2 of normalized histograms: one matrix product.

    It agrees with chi^2 to first order for similar histograms and lies within a factor 2 of it
    elsewhere; used where many hypotheses are screened, chi^2 where the final matches are made.
    """
    return np.maximum(2.0 - 2.0 * (np.sqrt(ha) @ np.sqrt(hb).T), 0.0)
