"""``match_images``: two images in; putative matches, the inlier set and the transform out.

Stages (the L2E paper's image pipeline [1]_): SIFT keypoints with RootSIFT descriptors ->
nearest-neighbour matching with Lowe's ratio test -> robust filtering (L2E or VFC) giving a first
transform f0 -> optionally, guided dense matching around f0 and a final transform with a richer
kernel basis from those dense matches (:mod:`reglib.dense`). The multimodal path's estimate is
:mod:`reglib.matching.multimodal`'s.

Coordinates: (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0); the transform
maps image a into image b.

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of
       Transformation for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .._parallel import run_both
from .._validation import as_choice, as_options, as_rng, seed_of
from ..dense import EVIDENCE_Z, DenseOptions, confidence_map, evidence_over_no_motion, fold_fraction, refine_dense
from ..features import (
    NormalizedImage,
    check_mask,
    detect_multimodal,
    detect_sift,
    edge_points,
    match_descriptors,
    match_multimodal,
    refine_matches,
    structure_image,
    to_gray_uint8,
)
from ..io import read_image
from ..robust import METHODS, FilterResult, L2EOptions, VFCOptions, fit_matches
from ..transforms import KernelWarp
from .multimodal import MULTIMODAL_KEYPOINTS, MULTIMODAL_SIDE, multimodal_fit
from .options import FEATURES, MatchOptions
from .result import ImageMatch

__all__ = ["AUTO_MIN_INLIERS", "dense_options", "match_images"]

_FOLD_SAMPLES = 2_000_000  # pixels of a at most on which the fold share is measured
AUTO_MIN_INLIERS = 30  # features="auto": fewer SIFT inliers than this (or a reason) -> the multimodal path
_DENSE_MIN_INLIERS = 6  # the dense stage runs from a first estimate with at least this many inliers
_DENSE_STARTS = (None, "too_few_inliers")  # ... and one of these reasons
# the multimodal dense stage's structure fields: smoothed over 2 px (1 px: its matches across stains are noisier;
# median rTRE 0.0063 -> 0.0034 on six stain-like training pairs, 3 px: 0.0037)
_STRUCTURE_SIGMA = 2.0


def match_images(image_a: Any, image_b: Any, *,
                 features: Literal["sift", "shape_context", "multimodal", "auto"] = "sift",
                 method: Literal["l2e", "vfc"] = "l2e", options: MatchOptions | dict[str, Any] | None = None,
                 rng: int | np.random.Generator | None = None, mask_a: Any = None,
                 mask_b: Any = None) -> ImageMatch:
    """Find which feature matches between two images are real, and the smooth map between them.

    Parameters
    ----------
    image_a, image_b : ndarray, path or bytes
        (H, W) or (H, W, 3) arrays of any real dtype (RGB; an alpha channel is dropped), paths to
        PNG / JPEG / TIFF / BMP / WebP files, or their encoded bytes.
    features : {"sift", "shape_context", "multimodal", "auto"}
        "sift": SIFT keypoints with RootSIFT descriptors (photographs).
        "multimodal": for images from different sensors (infrared, SAR, depth, maps, MR / PET /
        CT, fundus / angiogram): phase-congruency corners described by RIFT-style maximum-index
        maps of log-Gabor responses (rotation by the index ring), matched under one global
        rotation, each match refined by correlating structure fields, then a two-stage L2E fit
        (affine, then the field on matches within 10 px); where that fit has fewer than 12
        inliers, the rigid map (rotation within 15 degrees, shift within a fifth of the image) of
        highest normalized mutual information replaces it unless the fit's is clearly higher
        (blurred PET / SPECT against MR / CT); the dense stage correlates structure
        fields (:func:`reglib.features.structure_image`) instead of intensities. At most
        1500 keypoints and a 512 px working size; ``multimodal_ratio`` is its ratio test.
        "auto": SIFT, and the multimodal path when SIFT's estimate has a ``reason`` or fewer than
        30 inliers (``ImageMatch.features`` says which ran).
        "shape_context": for silhouettes, drawings and edge maps: ``contour_points`` points sampled
        evenly along the edges (Canny) of each image, registered by :func:`reglib.register_points`
        (shape context, assignment with dummies, L2E, re-description for several rounds). The
        putatives are the final correspondences, their inliers decided by ``filter_matches``;
        ``transform`` is the registration's map. Dense refinement does not apply (no texture).
    method : {"l2e", "vfc"}
        Robust estimator (see :func:`reglib.filter_matches`).
    options : MatchOptions or dict, optional
        See :class:`MatchOptions`; a misspelled field is an ``InputError``.
    rng : int or numpy.random.Generator, optional
        Seed of the estimator; the same seed gives the same answer.
    mask_a, mask_b : (H, W) array_like, optional
        Regions of interest (nonzero = use); keypoints and dense matches stay inside.

    Returns
    -------
    ImageMatch
        With no keypoints or too few matches: all-False inliers, zero scores, the identity
        transform, ``converged=False``, ``reason="too_few_matches"``.

    Raises
    ------
    InputError
        Undecodable / empty / zero-size images, masks of the wrong shape, bad options
        (``ImageTooLarge`` and ``UnsupportedFormat`` are InputErrors too).

    Examples
    --------
    >>> import numpy as np, cv2
    >>> from skimage.data import camera
    >>> a = camera()
    >>> b = cv2.warpAffine(a, np.float32([[1, 0, 8], [0, 1, -5]]), (512, 512))
    >>> m = match_images(a, b, rng=0, options={"dense": False})
    >>> np.round(np.median(m.transform(m.src[m.inliers]) - m.src[m.inliers], axis=0))
    array([ 8., -5.])
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    features = as_choice(features, "features", FEATURES)
    method = as_choice(method, "method", METHODS)
    opts = as_options(options, MatchOptions)
    estimator_options = L2EOptions if method == "l2e" else VFCOptions
    # a misspelled field fails now, not after SIFT
    filter_options = as_options(opts.filter, estimator_options, "filter")
    if opts.dense_filter is not None:
        as_options(opts.dense_filter, estimator_options, "dense_filter")
    run = _Run(method=method, filter=filter_options, rng=as_rng(rng), seed=seed_of(rng), timings=timings,
               t_start=t_start)

    t = time.perf_counter()
    img_a = read_image(image_a, max_pixels=opts.max_pixels, name="image_a")
    img_b = read_image(image_b, max_pixels=opts.max_pixels, name="image_b")
    shape_a, shape_b = img_a.shape[:2], img_b.shape[:2]
    images = _Images(img_a=img_a, img_b=img_b, gray_a=to_gray_uint8(img_a), gray_b=to_gray_uint8(img_b),
                     mask_a=check_mask(mask_a, shape_a, "mask_a"), mask_b=check_mask(mask_b, shape_b, "mask_b"))
    timings["read"] = _ms(t)

    if features == "shape_context":
        return _match_contours(images, opts, run)

    ran = "multimodal" if features == "multimodal" else "sift"
    sparse = _sparse(ran, images, opts, run)
    if features == "auto" and (sparse.fit.reason is not None or sparse.fit.n_inliers < AUTO_MIN_INLIERS):
        # SIFT found too little to trust: the sensors may differ; try the modality-robust path
        ran = "multimodal"
        sparse = _sparse(ran, images, opts, run)
    fit = sparse.fit
    gray_a, gray_b = images.gray_a, images.gray_b
    if ran == "multimodal":  # the dense stage correlates structure fields, not intensities
        t = time.perf_counter()
        norm_a, norm_b = images.normalized
        gray_a, gray_b = run_both(lambda: structure_image(norm_a, sigma=_STRUCTURE_SIGMA),
                                  lambda: structure_image(norm_b, sigma=_STRUCTURE_SIGMA))
        timings["structure"] = _ms(t)

    transform, converged, n_dense, confidence, dense = fit.transform, fit.converged, 0, None, "not_run"
    reason = fit.reason
    d_opts = dense_options(opts, method)
    # the dense stage also starts from a fit its few inliers do not back (e.g. the multimodal rigid map):
    # its guard and the images' evidence then judge the result
    if opts.dense and fit.reason in _DENSE_STARTS and (fit.n_inliers >= _DENSE_MIN_INLIERS or fit.reason is not None):
        t = time.perf_counter()
        refined = refine_dense(gray_a, gray_b, fit.transform, d_opts, run.rng, images.mask_a, images.mask_b)
        if refined.fitted:
            transform, converged, n_dense = refined.transform, refined.converged, refined.n_dense
        confidence, dense = refined.confidence, refined.outcome  # f0's own map when no dense fit was made
        timings["dense"] = _ms(t)
    if reason in _DENSE_STARTS:
        # an answer the images themselves rate worse than no motion is not passed off as converged; one
        # from too few inliers that the dense stage kept and the images clearly rate over no motion is
        t = time.perf_counter()
        z = evidence_over_no_motion(gray_a, gray_b, transform, d_opts)
        if z <= -EVIDENCE_Z:
            converged, reason = False, "unsupported"
        elif reason is not None and dense == "kept" and z >= EVIDENCE_Z:
            reason = None
        timings["evidence"] = _ms(t)
    converged = converged and reason is None
    if confidence is None:
        t = time.perf_counter()
        confidence = confidence_map(gray_a, gray_b, transform, step=opts.dense_step, half_patch=opts.dense_patch,
                                    mask_a=images.mask_a, max_side=opts.max_side)
        timings["confidence"] = _ms(t)

    t = time.perf_counter()
    folds = 0.0 if fit.reason not in _DENSE_STARTS else fold_fraction(transform, shape_a, max_samples=_FOLD_SAMPLES)
    timings["folds"] = _ms(t)
    timings["total"] = _ms(t_start)
    return ImageMatch(keypoints_a=sparse.keypoints_a, keypoints_b=sparse.keypoints_b, src=sparse.src, dst=sparse.dst,
                      inliers=fit.inliers, scores=fit.scores, transform=transform,
                      converged=bool(converged), reason=reason, seed=run.seed, timings_ms=timings,
                      shape_a=(int(shape_a[0]), int(shape_a[1])), shape_b=(int(shape_b[0]), int(shape_b[1])),
                      fold_fraction=folds, n_dense=n_dense, features=ran, method=method,
                      confidence=confidence, dense=dense)


def dense_options(opts: MatchOptions, method: Literal["l2e", "vfc"]) -> DenseOptions:
    """The dense stage's options (:class:`~reglib.dense.DenseOptions`) from ``match_images``' options."""
    return DenseOptions(method=method, step=opts.dense_step, radius=opts.dense_radius, rounds=opts.dense_rounds,
                        patch=opts.dense_patch, max_side=opts.max_side, filter=opts.dense_filter,
                        sparse_filter=opts.filter, detail=opts.dense_detail)


@dataclass(frozen=True, eq=False)
class _Images:
    """The two images as read, their grey uint8 copies and their masks (checked)."""

    img_a: np.ndarray
    img_b: np.ndarray
    gray_a: np.ndarray
    gray_b: np.ndarray
    mask_a: np.ndarray | None
    mask_b: np.ndarray | None

    @functools.cached_property
    def normalized(self) -> tuple[NormalizedImage, NormalizedImage]:
        """Both images normalized once for the multimodal path (features, refinement, structure fields)."""
        return run_both(lambda: NormalizedImage.of(self.img_a), lambda: NormalizedImage.of(self.img_b))


@dataclass(frozen=True, eq=False)
class _Run:
    """What one call runs with: the estimator and its options, the random state, and the stage timings."""

    method: Literal["l2e", "vfc"]
    filter: L2EOptions | VFCOptions  # the estimator's options (``MatchOptions.filter``, checked)
    rng: np.random.Generator
    seed: int | None  # recorded in the result
    timings: dict[str, float]  # stage -> ms, filled in as the stages run
    t_start: float


@dataclass(frozen=True, eq=False)
class _Sparse:
    """The sparse stage: keypoints of both images, putative matches and their robust fit."""

    keypoints_a: np.ndarray  # (Ka, 2)
    keypoints_b: np.ndarray  # (Kb, 2)
    src: np.ndarray  # (N, 2) putative matches in a ...
    dst: np.ndarray  # (N, 2) ... and in b
    fit: FilterResult


def _sparse(features: str, images: _Images, opts: MatchOptions, run: _Run) -> _Sparse:
    """Keypoints, putative matches and their robust filtering, by SIFT or by the multimodal features."""
    img_a, img_b, m_a, m_b = images.img_a, images.img_b, images.mask_a, images.mask_b
    timings = run.timings
    t = time.perf_counter()
    if features == "multimodal":
        # the multimodal path works on the images as they are (16-bit and float included, normalized
        # once) at a working size of its own, and refines each match by correlating structure fields
        norm_a, norm_b = images.normalized
        kw = {"max_keypoints": min(opts.max_keypoints, MULTIMODAL_KEYPOINTS), "max_side": min(opts.max_side,
                                                                                               MULTIMODAL_SIDE)}
        # (numpy and scipy.fft release the GIL: the two images' features are computed at once)
        feat_a, feat_b = run_both(lambda: detect_multimodal(norm_a, mask=m_a, **kw),
                                  lambda: detect_multimodal(norm_b, mask=m_b, **kw))
    else:
        feat_a, feat_b = run_both(
            lambda: detect_sift(images.gray_a, mask=m_a, max_keypoints=opts.max_keypoints, max_side=opts.max_side),
            lambda: detect_sift(images.gray_b, mask=m_b, max_keypoints=opts.max_keypoints, max_side=opts.max_side))
    timings["features"] = timings.get("features", 0.0) + _ms(t)
    t = time.perf_counter()
    if features == "multimodal":
        ia, ib = match_multimodal(feat_a.descriptors, feat_b.descriptors, ratio=opts.multimodal_ratio, mutual=True)
        src, dst = feat_a.points[ia], feat_b.points[ib]
        if len(src):
            dst, _ = refine_matches(*images.normalized, src, dst)
    else:
        ia, ib = match_descriptors(feat_a.descriptors, feat_b.descriptors, ratio=opts.ratio, mutual=opts.mutual)
        src, dst = feat_a.points[ia], feat_b.points[ib]
    timings["matching"] = timings.get("matching", 0.0) + _ms(t)
    t = time.perf_counter()
    if features == "multimodal" and run.method == "l2e" and opts.filter is None:
        fit = multimodal_fit(img_a, img_b, src, dst, run.rng, has_keypoints=bool(len(feat_a.points)
                                                                                 and len(feat_b.points)))
    else:
        fit = fit_matches(src, dst, method=run.method, options=run.filter, rng=run.rng)
    timings["filter"] = timings.get("filter", 0.0) + _ms(t)
    return _Sparse(keypoints_a=feat_a.points, keypoints_b=feat_b.points, src=src, dst=dst, fit=fit)


def _match_contours(images: _Images, opts: MatchOptions, run: _Run) -> ImageMatch:
    """``features="shape_context"``: edge points of both images registered, the correspondences filtered."""
    from ..registration import register_points

    gray_a, gray_b, timings, method = images.gray_a, images.gray_b, run.timings, run.method
    t = time.perf_counter()
    pts_a = edge_points(gray_a, opts.contour_points, images.mask_a)
    pts_b = edge_points(gray_b, opts.contour_points, images.mask_b)
    timings["features"] = _ms(t)
    shape_a, shape_b = (int(gray_a.shape[0]), int(gray_a.shape[1])), (int(gray_b.shape[0]), int(gray_b.shape[1]))
    if len(pts_a) < 10 or len(pts_b) < 10:
        empty = np.zeros((0, 2))
        timings["total"] = _ms(run.t_start)
        return ImageMatch(keypoints_a=pts_a, keypoints_b=pts_b, src=empty, dst=empty.copy(),
                          inliers=np.zeros(0, bool), scores=np.zeros(0), transform=KernelWarp.identity(2),
                          converged=False, reason="too_few_matches", seed=run.seed, timings_ms=timings,
                          shape_a=shape_a, shape_b=shape_b, features="shape_context", method=method)
    t = time.perf_counter()
    reg = register_points(pts_a, pts_b, method="l2e", rng=run.rng)
    timings["matching"] = _ms(t)
    keep = reg.correspondence >= 0
    src, dst = pts_a[keep], pts_b[reg.correspondence[keep]]
    t = time.perf_counter()
    res = fit_matches(src, dst, method=method, options=run.filter, rng=run.rng)
    timings["filter"] = _ms(t)
    t = time.perf_counter()
    folds = fold_fraction(reg.transform, shape_a, max_samples=_FOLD_SAMPLES)
    timings["folds"] = _ms(t)
    timings["total"] = _ms(run.t_start)
    return ImageMatch(keypoints_a=pts_a, keypoints_b=pts_b, src=src, dst=dst, inliers=res.inliers, scores=res.scores,
                      transform=reg.transform, converged=bool(reg.converged and res.reason is None),
                      reason=res.reason, seed=run.seed, timings_ms=timings, shape_a=shape_a, shape_b=shape_b,
                      fold_fraction=folds, features="shape_context", method=method)


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0
