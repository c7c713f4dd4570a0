"""``match_images``: two images in; putative matches, the inlier set and the transform out.

Stages (the L2E paper's image pipeline, IEEE TSP 2015): SIFT keypoints with RootSIFT descriptors
-> nearest-neighbour matching with Lowe's ratio test -> robust filtering (L2E or VFC) giving a first
transform f0 -> optionally, guided dense matching around f0 and a final transform with a richer
kernel basis from those dense matches.

Coordinates: (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0); the transform
maps image a into image b.
"""
from __future__ import annotations

import time
from typing import Any, Literal

import numpy as np

from ._parallel import run_both
from ._validation import as_choice, as_options, as_rng, seed_of
from .dense import fold_fraction
from .features.edges import edge_points
from .features.multimodal import align_rigid, detect_multimodal, match_multimodal, refine_matches, structure_image
from .features.sift import check_mask, detect_sift, match_descriptors, to_gray_uint8
from .image_match import ImageMatch
from .io import read_image
from .match_options import FEATURES, MatchOptions
from .refine import confidence_map, refine_dense
from .registration.rigid import rigid_warp
from .robust import METHODS, FilterResult, L2EOptions, VFCOptions, filter_matches
from .transforms import KernelWarp

__all__ = ["match_images"]

_FOLD_SAMPLES = 2_000_000  # pixels of a at most on which the fold share is measured
AUTO_MIN_INLIERS = 30  # features="auto": fewer SIFT inliers than this (or a reason) -> the multimodal path
MULTIMODAL_KEYPOINTS = 1500  # the multimodal path's keypoints per image at most (MatchOptions.max_keypoints caps it)
MULTIMODAL_SIDE = 512  # and its working size (MatchOptions.max_side caps it); 768 gained 1 of 17 pairs at 2.3x the time
MULTIMODAL_AFFINE: dict[str, Any] = {"n_centers": 0, "max_centers": 0, "max_layers": 1, "n_anneal": 9}
MULTIMODAL_FIELD: dict[str, Any] = {"n_anneal": 9, "max_layers": 1}
MULTIMODAL_GATE_PX = 10.0
MULTIMODAL_MIN_INLIERS = 12  # fewer inliers than this: also try the rigid NMI alignment (align_rigid)
MULTIMODAL_NMI_MARGIN = 1.05  # ... and keep the weak fit only where its mutual information is 5 % higher


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
        fields (:func:`reglib.features.multimodal.structure_image`) instead of intensities. At most
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
    as_options(opts.filter, estimator_options, "filter")  # a misspelled field fails now, not after SIFT
    if opts.dense_filter is not None:
        as_options(opts.dense_filter, estimator_options, "dense_filter")
    seed = seed_of(rng)
    generator = as_rng(rng)

    t = time.perf_counter()
    img_a = read_image(image_a, max_pixels=opts.max_pixels, name="image_a")
    img_b = read_image(image_b, max_pixels=opts.max_pixels, name="image_b")
    shape_a, shape_b = img_a.shape[:2], img_b.shape[:2]
    m_a = check_mask(mask_a, shape_a, "mask_a")
    m_b = check_mask(mask_b, shape_b, "mask_b")
    gray_a, gray_b = to_gray_uint8(img_a), to_gray_uint8(img_b)
    timings["read"] = _ms(t)

    if features == "shape_context":
        return _match_contours(gray_a, gray_b, m_a, m_b, opts, method, generator, seed, timings, t_start)

    ran = "multimodal" if features == "multimodal" else "sift"
    kp_a, kp_b, src, dst, sparse = _sparse(ran, img_a, img_b, gray_a, gray_b, m_a, m_b, opts, method, generator,
                                           timings)
    if features == "auto" and (sparse.reason is not None or sparse.n_inliers < AUTO_MIN_INLIERS):
        # SIFT found too little to trust: the sensors may differ; try the modality-robust path
        ran = "multimodal"
        kp_a, kp_b, src, dst, sparse = _sparse(ran, img_a, img_b, gray_a, gray_b, m_a, m_b, opts, method,
                                               generator, timings)
    if ran == "multimodal":  # the dense stage correlates structure fields, not intensities
        t = time.perf_counter()
        gray_a, gray_b = run_both(lambda: structure_image(img_a), lambda: structure_image(img_b))
        timings["structure"] = _ms(t)

    transform, converged, n_dense, confidence = sparse.transform, sparse.converged, 0, None
    if opts.dense and sparse.reason is None and sparse.n_inliers >= 6:
        t = time.perf_counter()
        refined = refine_dense(gray_a, gray_b, sparse.transform, opts, method, generator, m_a, m_b)
        if refined is not None:
            transform, converged, n_dense = refined.transform, refined.converged, refined.n_dense
            confidence = refined.confidence
        timings["dense"] = _ms(t)
    if confidence is None:
        t = time.perf_counter()
        confidence = confidence_map(gray_a, gray_b, transform, step=opts.dense_step, half_patch=opts.dense_patch,
                                    mask_a=m_a, max_side=opts.max_side)
        timings["confidence"] = _ms(t)

    t = time.perf_counter()
    folds = 0.0 if sparse.reason is not None else fold_fraction(transform, shape_a, max_samples=_FOLD_SAMPLES)
    timings["folds"] = _ms(t)
    timings["total"] = _ms(t_start)
    return ImageMatch(keypoints_a=kp_a, keypoints_b=kp_b, src=src, dst=dst,
                      inliers=sparse.inliers, scores=sparse.scores, transform=transform,
                      converged=bool(converged), reason=sparse.reason, seed=seed, timings_ms=timings,
                      shape_a=(int(shape_a[0]), int(shape_a[1])), shape_b=(int(shape_b[0]), int(shape_b[1])),
                      fold_fraction=folds, n_dense=n_dense, features=ran, method=method,
                      confidence=confidence)


def _sparse(features: str, img_a: np.ndarray, img_b: np.ndarray, gray_a: np.ndarray, gray_b: np.ndarray,
            m_a: np.ndarray | None, m_b: np.ndarray | None, opts: MatchOptions, method: Literal["l2e", "vfc"],
            rng: np.random.Generator, timings: dict[str, float]
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, FilterResult]:
    """Keypoints, putative matches and their robust filtering, by SIFT or by the multimodal features."""
    t = time.perf_counter()
    if features == "multimodal":
        # the multimodal path works on the images as they are (16-bit and float included, normalized
        # there) at a working size of its own, and refines each match by correlating structure fields
        kw = {"max_keypoints": min(opts.max_keypoints, MULTIMODAL_KEYPOINTS), "max_side": min(opts.max_side,
                                                                                               MULTIMODAL_SIDE)}
        # (numpy and scipy.fft release the GIL: the two images' features are computed at once)
        feat_a, feat_b = run_both(lambda: detect_multimodal(img_a, mask=m_a, **kw),
                                  lambda: detect_multimodal(img_b, mask=m_b, **kw))
    else:
        feat_a, feat_b = run_both(
            lambda: detect_sift(gray_a, mask=m_a, max_keypoints=opts.max_keypoints, max_side=opts.max_side),
            lambda: detect_sift(gray_b, mask=m_b, max_keypoints=opts.max_keypoints, max_side=opts.max_side))
    timings["features"] = timings.get("features", 0.0) + _ms(t)
    t = time.perf_counter()
    if features == "multimodal":
        ia, ib = match_multimodal(feat_a.descriptors, feat_b.descriptors, ratio=opts.multimodal_ratio, mutual=True)
        src, dst = feat_a.points[ia], feat_b.points[ib]
        if len(src):
            dst, _ = refine_matches(img_a, img_b, src, dst)
    else:
        ia, ib = match_descriptors(feat_a.descriptors, feat_b.descriptors, ratio=opts.ratio, mutual=opts.mutual)
        src, dst = feat_a.points[ia], feat_b.points[ib]
    timings["matching"] = timings.get("matching", 0.0) + _ms(t)
    t = time.perf_counter()
    if features == "multimodal" and method == "l2e" and opts.filter is None:
        sparse = _multimodal_fit(img_a, img_b, src, dst, rng, has_keypoints=bool(len(feat_a.points)
                                                                                and len(feat_b.points)))
    else:
        sparse = filter_matches(src, dst, method=method, options=opts.filter, rng=rng)
    timings["filter"] = timings.get("filter", 0.0) + _ms(t)
    return feat_a.points, feat_b.points, src, dst, sparse


def _two_stage(src: np.ndarray, dst: np.ndarray, rng: np.random.Generator) -> FilterResult:
    """Cross-sensor putatives: an affine L2E fit with a longer annealing first (their near misses,
    5-20 px off, would widen the default's scale), then the default field on the matches within
    ``MULTIMODAL_GATE_PX`` of it. Measured on the 82 multimodal pairs: 82 % success against 78 %
    for the affine fit alone and 70 % for the default (benchmarks/bench_multimodal.py)."""
    first = filter_matches(src, dst, options=MULTIMODAL_AFFINE, rng=rng)
    if first.reason is not None:
        return first
    keep = np.linalg.norm(first.transform(src) - dst, axis=1) < MULTIMODAL_GATE_PX
    second = filter_matches(src[keep], dst[keep], options=MULTIMODAL_FIELD, rng=rng)
    if second.reason is not None:
        return first
    inliers = np.zeros(len(src), dtype=bool)
    inliers[np.flatnonzero(keep)[second.inliers]] = True
    scores = np.zeros(len(src))
    scores[keep] = second.scores
    return FilterResult(inliers=inliers, scores=scores, transform=second.transform, sigma=second.sigma,
                        n_iter=first.n_iter + second.n_iter, converged=second.converged, reason=None,
                        method="l2e", seed=second.seed)


def _multimodal_fit(img_a: np.ndarray, img_b: np.ndarray, src: np.ndarray, dst: np.ndarray,
                    rng: np.random.Generator, *, has_keypoints: bool = True) -> FilterResult:
    """The multimodal path's estimate: :func:`_two_stage`, and :func:`_rigid_fallback` when it found
    fewer than ``MULTIMODAL_MIN_INLIERS`` inliers in images that have keypoints (images without
    any structure stay the "too few matches" answer)."""
    sparse = _two_stage(src, dst, rng)
    if has_keypoints and (sparse.reason is not None or sparse.n_inliers < MULTIMODAL_MIN_INLIERS):
        sparse = _rigid_fallback(img_a, img_b, src, dst, sparse)
    return sparse


def _rigid_fallback(img_a: np.ndarray, img_b: np.ndarray, src: np.ndarray, dst: np.ndarray,
                    sparse: FilterResult) -> FilterResult:
    """The rigid map of highest normalized mutual information when the features found too little.

    Blurred functional images (PET, SPECT) against anatomy (MR, CT) share hardly a corner: the
    features give a handful of matches, mostly false (measured: 0-4 inliers on MR / PET). When
    the two-stage fit has fewer than ``MULTIMODAL_MIN_INLIERS`` inliers,
    :func:`~reglib.features.multimodal.align_rigid` searches rotations within 15 degrees and shifts
    within a fifth of the image, and its map replaces the fit unless the fit's mutual information
    (NMI - 1) is ``MULTIMODAL_NMI_MARGIN`` times the map's or more: a kernel fit on a few matches
    bends freely and NMI rewards that a little even where the fit is wrong (SPECT_CT_8: 8.7 px
    off, NMI 1.238 against the rigid map's 1.237 at 0.9 px). The inliers are then the putatives
    within ``MULTIMODAL_GATE_PX`` of the map; with fewer than ``MULTIMODAL_MIN_INLIERS`` of them
    the result keeps the map but says ``converged=False``, ``reason="too_few_inliers"`` (only the
    mutual information supports it; unrelated textured images get a map as well). Masks are not
    used here. Measured on the 82
    multimodal pairs: MR / PET 0 -> 5 of 5, SPECT / CT 1 -> 5 of 5; of the other pairs only VN_28
    took the rigid map (wrong either way; bench_multimodal.py, ``mm_fit``).
    """
    matrix, nmi, nmi_fit, _ = align_rigid(img_a, img_b, compare=sparse.transform)
    if nmi_fit - 1.0 > MULTIMODAL_NMI_MARGIN * (nmi - 1.0):
        return sparse
    warp = rigid_warp(matrix)
    resid = np.linalg.norm(warp(src) - dst, axis=1) if len(src) else np.zeros(0)
    inliers = resid < MULTIMODAL_GATE_PX
    sigma = float(np.sqrt(np.mean(resid[inliers] ** 2))) if inliers.any() else 0.0
    # The map is the best estimate there is, but unless enough matches agree with it nothing but the
    # mutual information backs it (two unrelated images get a map too): that is said, not hidden.
    backed = int(inliers.sum()) >= MULTIMODAL_MIN_INLIERS
    return FilterResult(inliers=inliers, scores=inliers.astype(float), transform=warp, sigma=sigma,
                        n_iter=sparse.n_iter, converged=backed, reason=None if backed else "too_few_inliers",
                        method="l2e", seed=sparse.seed)


def _match_contours(gray_a: np.ndarray, gray_b: np.ndarray, mask_a: np.ndarray | None, mask_b: np.ndarray | None,
                    opts: MatchOptions, method: Literal["l2e", "vfc"], rng: np.random.Generator, seed: int | None,
                    timings: dict[str, float], t_start: float) -> ImageMatch:
    from .registration import register_points

    t = time.perf_counter()
    pts_a = edge_points(gray_a, opts.contour_points, mask_a)
    pts_b = edge_points(gray_b, opts.contour_points, mask_b)
    timings["features"] = _ms(t)
    shape_a, shape_b = (int(gray_a.shape[0]), int(gray_a.shape[1])), (int(gray_b.shape[0]), int(gray_b.shape[1]))
    if len(pts_a) < 10 or len(pts_b) < 10:
        empty = np.zeros((0, 2))
        timings["total"] = _ms(t_start)
        return ImageMatch(keypoints_a=pts_a, keypoints_b=pts_b, src=empty, dst=empty.copy(),
                          inliers=np.zeros(0, bool), scores=np.zeros(0), transform=KernelWarp.identity(2),
                          converged=False, reason="too_few_matches", seed=seed, timings_ms=timings,
                          shape_a=shape_a, shape_b=shape_b, features="shape_context", method=method)
    t = time.perf_counter()
    reg = register_points(pts_a, pts_b, method="l2e", rng=rng)
    timings["matching"] = _ms(t)
    keep = reg.correspondence >= 0
    src, dst = pts_a[keep], pts_b[reg.correspondence[keep]]
    t = time.perf_counter()
    res = filter_matches(src, dst, method=method, options=opts.filter, rng=rng)
    timings["filter"] = _ms(t)
    t = time.perf_counter()
    folds = fold_fraction(reg.transform, shape_a, max_samples=_FOLD_SAMPLES)
    timings["folds"] = _ms(t)
    timings["total"] = _ms(t_start)
    return ImageMatch(keypoints_a=pts_a, keypoints_b=pts_b, src=src, dst=dst, inliers=res.inliers, scores=res.scores,
                      transform=reg.transform, converged=bool(reg.converged and res.reason is None),
                      reason=res.reason, seed=seed, timings_ms=timings, shape_a=shape_a, shape_b=shape_b,
                      fold_fraction=folds, features="shape_context", method=method)


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0
