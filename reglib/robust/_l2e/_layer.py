"""A secondary layer added to an L2E fit: the matches of a second, local motion (:mod:`reglib.robust._layers`)."""
from __future__ import annotations

import dataclasses

import numpy as np

from .._layers import LayerRule, secondary_layer
from .._options import L2EOptions
from ._state import Fit, subset, volume


def with_layer(fit: Fit, u: np.ndarray, y: np.ndarray, scale_ratio: float, opts: L2EOptions,
               rng: np.random.Generator) -> Fit:
    """``fit`` with the matches of a secondary layer (:mod:`reglib.robust._layers`) added as inliers.

    ``scale_ratio`` is src_scale / dst_scale of the normalization: ``y - scale_ratio * u`` is the
    displacement in the caller's units (divided by dst_scale, less a constant), which is nearly
    the same for the matches of a layer that moves by a translation over a small region.
    """
    rejected = np.flatnonzero(~fit.inliers)
    search = subset(rejected, opts.max_work_points, rng)
    extent = volume(y) if fit.volume is None else fit.volume
    rule = LayerRule(min_matches=opts.min_layer_matches, score_scale=opts.score_scale,
                     threshold=opts.inlier_threshold)
    layer = secondary_layer(u, y, y[search] - scale_ratio * u[search], search, rejected, fit.sigma**2, extent, rule)
    if layer is None:
        return fit
    inliers, scores = fit.inliers.copy(), fit.scores.copy()
    inliers[layer.members] = True
    scores[layer.members] = layer.scores
    return dataclasses.replace(fit, scores=scores, inliers=inliers)
