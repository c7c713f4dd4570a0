"""The multimodal path's estimate from its putatives: a two-stage L2E fit, and a rigid fallback.

Cross-sensor putatives (``features="multimodal"`` of :func:`reglib.match_images`) have many
near misses: :func:`two_stage_fit` fits an affine map first and the field on the matches close
to it. Where even that finds too little (blurred functional images against anatomy),
:func:`rigid_fallback` takes the rigid map of highest normalized mutual information
(:func:`reglib.dense._align.align_rigid`). :func:`multimodal_fit` is the two together.

Coordinates: (x, y) pixels, x the column; the maps take pixels of image a to pixels of image b.
These functions take the library's own putatives (trusted input): they do not validate.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .._validation import as_options
from .._verdict import TOO_FEW_INLIERS
from ..dense import align_rigid
from ..registration import rigid_warp
from ..robust import FilterResult, L2EOptions, fit_matches

__all__ = ["MULTIMODAL_AFFINE", "MULTIMODAL_FIELD", "MULTIMODAL_GATE_PX", "MULTIMODAL_KEYPOINTS",
           "MULTIMODAL_MIN_INLIERS", "MULTIMODAL_NMI_MARGIN", "MULTIMODAL_SIDE", "multimodal_fit", "rigid_fallback",
           "two_stage_fit"]

MULTIMODAL_KEYPOINTS = 1500  # the multimodal path's keypoints per image at most (MatchOptions.max_keypoints caps it)
MULTIMODAL_SIDE = 512  # and its working size (MatchOptions.max_side caps it)
MULTIMODAL_AFFINE: dict[str, Any] = {"n_centers": 0, "max_centers": 0, "max_layers": 1, "n_anneal": 9}
MULTIMODAL_FIELD: dict[str, Any] = {"n_anneal": 9, "max_layers": 1}
MULTIMODAL_GATE_PX = 10.0
MULTIMODAL_MIN_INLIERS = 12  # fewer inliers than this: also try the rigid NMI alignment (align_rigid)
MULTIMODAL_NMI_MARGIN = 1.05  # ... and keep the weak fit only where its mutual information is 5 % higher


def two_stage_fit(src: np.ndarray, dst: np.ndarray, rng: np.random.Generator) -> FilterResult:
    """Cross-sensor putatives: an affine L2E fit with a longer annealing first, then the field near it.

    The putatives' near misses, 5-20 px off, would widen the default fit's scale: the affine fit
    (``MULTIMODAL_AFFINE``) comes first, then the default field (``MULTIMODAL_FIELD``) on the
    matches within ``MULTIMODAL_GATE_PX`` of it.

    Parameters
    ----------
    src, dst : (N, 2) float64 ndarray
        Putative matches, pixels of a and of b (trusted input: not validated).
    rng : numpy.random.Generator
        Passed to both fits.

    Returns
    -------
    FilterResult
        The second fit's inliers and transform over all N putatives; the first fit's answer when
        the second has a ``reason``.
    """
    first = fit_matches(src, dst, method="l2e", options=as_options(MULTIMODAL_AFFINE, L2EOptions), rng=rng)
    if first.reason is not None:
        return first
    keep = np.linalg.norm(first.transform(src) - dst, axis=1) < MULTIMODAL_GATE_PX
    second = fit_matches(src[keep], dst[keep], method="l2e", options=as_options(MULTIMODAL_FIELD, L2EOptions),
                         rng=rng)
    if second.reason is not None:
        return first
    inliers = np.zeros(len(src), dtype=bool)
    inliers[np.flatnonzero(keep)[second.inliers]] = True
    scores = np.zeros(len(src))
    scores[keep] = second.scores
    return FilterResult(inliers=inliers, scores=scores, transform=second.transform, sigma=second.sigma,
                        n_iter=first.n_iter + second.n_iter, converged=second.converged, reason=None,
                        method="l2e", seed=second.seed, stopped=second.stopped)


def multimodal_fit(img_a: np.ndarray, img_b: np.ndarray, src: np.ndarray, dst: np.ndarray,
                   rng: np.random.Generator, *, has_keypoints: bool = True) -> FilterResult:
    """The multimodal path's estimate: :func:`two_stage_fit`, and :func:`rigid_fallback` when it found too little.

    The fallback runs when the two-stage fit has a ``reason`` or fewer than
    ``MULTIMODAL_MIN_INLIERS`` inliers, in images that have keypoints (``has_keypoints``; images
    without any structure stay the "too few matches" answer).

    Parameters
    ----------
    img_a, img_b : (H, W) or (H, W, 3) ndarray
        The images as read.
    src, dst : (N, 2) float64 ndarray
        Putative matches, pixels of a and of b (trusted input: not validated).
    rng : numpy.random.Generator
        Passed to the fits.
    has_keypoints : bool
        Whether both images had keypoints.

    Returns
    -------
    FilterResult
    """
    sparse = two_stage_fit(src, dst, rng)
    if has_keypoints and (sparse.reason is not None or sparse.n_inliers < MULTIMODAL_MIN_INLIERS):
        sparse = rigid_fallback(img_a, img_b, src, dst, sparse)
    return sparse


def rigid_fallback(img_a: np.ndarray, img_b: np.ndarray, src: np.ndarray, dst: np.ndarray,
                   sparse: FilterResult) -> FilterResult:
    """The rigid map of highest normalized mutual information when the features found too little.

    Blurred functional images (PET, SPECT) against anatomy (MR, CT) share hardly a corner: the
    features give a handful of matches, mostly false. :func:`~reglib.dense._align.align_rigid`
    searches rotations within 15 degrees and shifts within a fifth of the image, and its map
    replaces the fit ``sparse`` unless the fit's mutual information (NMI - 1) is
    ``MULTIMODAL_NMI_MARGIN`` times the map's or more: a kernel fit on a few matches bends freely
    and NMI rewards that a little even where the fit is wrong. The inliers are then the putatives
    within ``MULTIMODAL_GATE_PX`` of the map; with fewer than ``MULTIMODAL_MIN_INLIERS`` of them
    the result keeps the map but says ``converged=False`` with the reason ``too_few_inliers`` (only the
    mutual information supports it; unrelated textured images get a map as well). Masks are not
    used here.

    Parameters
    ----------
    img_a, img_b : (H, W) or (H, W, 3) ndarray
        The images as read.
    src, dst : (N, 2) float64 ndarray
        Putative matches, pixels of a and of b.
    sparse : FilterResult
        The fit the map competes with.

    Returns
    -------
    FilterResult
        ``sparse`` itself, or the rigid map's.
    """
    rigid = align_rigid(img_a, img_b, compare=sparse.transform)
    if rigid.nmi_compare - 1.0 > MULTIMODAL_NMI_MARGIN * (rigid.nmi - 1.0):
        return sparse
    warp = rigid_warp(rigid.matrix)
    resid = np.linalg.norm(warp(src) - dst, axis=1) if len(src) else np.zeros(0)
    inliers = resid < MULTIMODAL_GATE_PX
    sigma = float(np.sqrt(np.mean(resid[inliers] ** 2))) if inliers.any() else 0.0
    # The map is the best estimate there is, but unless enough matches agree with it nothing but the
    # mutual information backs it (two unrelated images get a map too): that is said, not hidden.
    backed = int(inliers.sum()) >= MULTIMODAL_MIN_INLIERS
    return FilterResult(inliers=inliers, scores=inliers.astype(float), transform=warp, sigma=sigma,
                        n_iter=sparse.n_iter, converged=backed, reason=None if backed else TOO_FEW_INLIERS,
                        method="l2e", seed=sparse.seed)
