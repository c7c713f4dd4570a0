"""Robust estimators of a smooth transformation from putative matches (L2E, VFC).

Besides :func:`filter_matches`, the package offers the building blocks its estimators are made
of, for other loops of the library (the shape-context registration): the normalization, the model
(linear part + Gaussian kernel field in normalized coordinates), the weighted kernel solver, one
L2E re-weighted fit at a fixed scale, L2E's scale estimate, farthest-point centres, and running a
block on one BLAS thread. They take trusted arrays (validated upstream).
"""
from ._core import (
    Model,
    Normalization,
    WeightedSolver,
    farthest_point_centers,
    identity_model,
    ridge_epsilon,
    single_thread_blas,
)
from ._filter import METHODS, filter_matches, fit_matches
from ._l2e import l2e_scale, reweighted_fit
from ._options import L2EOptions, VFCOptions
from ._result import FilterResult

__all__ = ["METHODS", "FilterResult", "L2EOptions", "Model", "Normalization", "VFCOptions", "WeightedSolver",
           "farthest_point_centers", "filter_matches", "fit_matches", "identity_model", "l2e_scale",
           "reweighted_fit", "ridge_epsilon", "single_thread_blas"]
