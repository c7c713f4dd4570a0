"""``match_images(features="shape_context")``: edge points of both images registered, the correspondences filtered.

For silhouettes, drawings and edge maps: points sampled evenly along the edges of each image are
registered by :func:`reglib.register_points` (shape context + L2E); the putatives are the final
correspondences, their inliers decided by the estimator, and the transform is the registration's map.
"""
from __future__ import annotations

import time

import numpy as np

from .._transforms import KernelWarp
from .._verdict import TOO_FEW_MATCHES
from ..dense import fold_fraction
from ..features import edge_points
from ..robust import fit_matches
from ._inputs import Images, Run, ms
from ._result import ImageMatch

FOLD_SAMPLES = 2_000_000  # pixels of a at most on which the fold share is measured
_MIN_POINTS = 10  # edge points of each image at least, for a registration


def match_contours(images: Images, run: Run) -> ImageMatch:
    """The :class:`ImageMatch` of the shape-context path (no dense stage: edge maps have no texture)."""
    from ..registration import register_points

    opts, timings, method = run.options, run.timings, run.method
    t = time.perf_counter()
    pts_a = edge_points(images.gray_a, opts.contour_points, images.mask_a)
    pts_b = edge_points(images.gray_b, opts.contour_points, images.mask_b)
    timings["features"] = ms(t)
    shape_a, shape_b = images.shape_a, images.shape_b
    if len(pts_a) < _MIN_POINTS or len(pts_b) < _MIN_POINTS:
        empty = np.zeros((0, 2))
        timings["total"] = ms(run.t_start)
        return ImageMatch(keypoints_a=pts_a, keypoints_b=pts_b, src=empty, dst=empty.copy(),
                          inliers=np.zeros(0, bool), scores=np.zeros(0), transform=KernelWarp.identity(2),
                          converged=False, reason=TOO_FEW_MATCHES, seed=run.seed, timings_ms=timings,
                          shape_a=shape_a, shape_b=shape_b, features="shape_context", method=method)
    t = time.perf_counter()
    reg = register_points(pts_a, pts_b, method="l2e", rng=run.rng)
    timings["matching"] = ms(t)
    keep = reg.correspondence >= 0
    src, dst = pts_a[keep], pts_b[reg.correspondence[keep]]
    t = time.perf_counter()
    res = fit_matches(src, dst, method=method, options=run.filter, rng=run.rng)
    timings["filter"] = ms(t)
    t = time.perf_counter()
    folds = fold_fraction(reg.transform, shape_a, max_samples=FOLD_SAMPLES)
    timings["folds"] = ms(t)
    timings["total"] = ms(run.t_start)
    return ImageMatch(keypoints_a=pts_a, keypoints_b=pts_b, src=src, dst=dst, inliers=res.inliers, scores=res.scores,
                      transform=reg.transform, converged=bool(reg.converged and res.reason is None),
                      reason=res.reason or reg.reason, seed=run.seed, timings_ms=timings, shape_a=shape_a,
                      shape_b=shape_b, fold_fraction=folds, features="shape_context", method=method)
