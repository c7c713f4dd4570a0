"""The sparse stage of :func:`reglib.match_images`: keypoints, putative matches and their robust fit.

SIFT keypoints with RootSIFT descriptors, or the multimodal features (:mod:`reglib.features`),
matched with a ratio test and filtered by the estimator; ``features="auto"`` runs SIFT, and the
multimodal path when SIFT's estimate has a reason or too few inliers.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .._parallel import run_both
from ..features import detect_multimodal, detect_sift, match_descriptors, match_multimodal, refine_matches
from ..robust import FilterResult, fit_matches
from ._inputs import Images, Run, ms
from ._multimodal import MULTIMODAL_KEYPOINTS, MULTIMODAL_SIDE, multimodal_fit

AUTO_MIN_INLIERS = 30  # features="auto": fewer SIFT inliers than this (or a reason) -> the multimodal path


@dataclass(frozen=True, eq=False)
class Sparse:
    """The sparse stage: the features that ran, keypoints of both images, putative matches and their fit."""

    features: Literal["sift", "multimodal"]
    keypoints_a: np.ndarray  # (Ka, 2)
    keypoints_b: np.ndarray  # (Kb, 2)
    src: np.ndarray  # (N, 2) putative matches in a ...
    dst: np.ndarray  # (N, 2) ... and in b
    fit: FilterResult


def sparse_stage(images: Images, run: Run, sift: Sparse | None = None) -> Sparse:
    """The sparse stage of ``run.features`` ("sift", "multimodal" or "auto"); ``sift``: SIFT's sparse stage on
    these images where it already ran (``auto``'s first step, :func:`sift_stage`)."""
    sparse = sift if sift is not None else _sparse("multimodal" if run.features == "multimodal" else "sift",
                                                   images, run)
    if run.features == "auto" and too_few(sparse):
        # SIFT found too little to trust: the sensors may differ; try the modality-robust path
        sparse = _sparse("multimodal", images, run)
    return sparse


def sift_stage(images: Images, run: Run) -> Sparse:
    """The sparse stage by SIFT, whatever ``run.features`` says."""
    return _sparse("sift", images, run)


def too_few(sparse: Sparse) -> bool:
    """Whether SIFT's sparse stage found too little for ``features="auto"`` to trust: a reason, or fewer than
    :data:`AUTO_MIN_INLIERS` inliers."""
    return sparse.fit.reason is not None or sparse.fit.n_inliers < AUTO_MIN_INLIERS


def _sparse(features: Literal["sift", "multimodal"], images: Images, run: Run) -> Sparse:
    """Keypoints, putative matches and their robust filtering, by SIFT or by the multimodal features."""
    opts, timings, m_a, m_b = run.options, run.timings, images.mask_a, images.mask_b
    t = time.perf_counter()
    if features == "multimodal":
        # the multimodal path works on the images as they are (16-bit and float included, normalized
        # once) at a working size of its own, and refines each match by correlating structure fields
        norm_a, norm_b = images.normalized
        kw: dict[str, Any] = {"max_keypoints": min(opts.max_keypoints, MULTIMODAL_KEYPOINTS),
                              "max_side": min(opts.max_side, MULTIMODAL_SIDE)}
        # (numpy and scipy.fft release the GIL: the two images' features are computed at once)
        feat_a, feat_b = run_both(lambda: detect_multimodal(norm_a, mask=m_a, **kw),
                                  lambda: detect_multimodal(norm_b, mask=m_b, **kw))
    else:
        feat_a, feat_b = run_both(
            lambda: detect_sift(images.gray_a, mask=m_a, max_keypoints=opts.max_keypoints, max_side=opts.max_side),
            lambda: detect_sift(images.gray_b, mask=m_b, max_keypoints=opts.max_keypoints, max_side=opts.max_side))
    timings["features"] = timings.get("features", 0.0) + ms(t)
    t = time.perf_counter()
    if features == "multimodal":
        ia, ib = match_multimodal(feat_a.descriptors, feat_b.descriptors, ratio=opts.multimodal_ratio, mutual=True)
        src, dst = feat_a.points[ia], feat_b.points[ib]
        if len(src):
            dst, _ = refine_matches(*images.normalized, src, dst)
    else:
        ia, ib = match_descriptors(feat_a.descriptors, feat_b.descriptors, ratio=opts.ratio, mutual=opts.mutual)
        src, dst = feat_a.points[ia], feat_b.points[ib]
    timings["matching"] = timings.get("matching", 0.0) + ms(t)
    t = time.perf_counter()
    if features == "multimodal" and run.method == "l2e" and opts.filter is None:
        fit = multimodal_fit(images.view_a, images.view_b, src, dst, run.rng,
                             has_keypoints=bool(len(feat_a.points) and len(feat_b.points)))
    else:
        fit = fit_matches(src, dst, method=run.method, options=run.filter, rng=run.rng)
    timings["filter"] = timings.get("filter", 0.0) + ms(t)
    return Sparse(features=features, keypoints_a=feat_a.points, keypoints_b=feat_b.points, src=src, dst=dst, fit=fit)
