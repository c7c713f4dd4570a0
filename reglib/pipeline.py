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

from ._validation import as_choice, as_options, as_rng, seed_of
from .dense import fold_fraction
from .features.edges import edge_points
from .features.sift import check_mask, detect_sift, match_descriptors, to_gray_uint8
from .image_match import ImageMatch
from .io import read_image
from .match_options import FEATURES, MatchOptions
from .refine import refine_dense
from .robust import METHODS, L2EOptions, VFCOptions, filter_matches
from .transforms import KernelWarp

__all__ = ["match_images"]

_FOLD_SAMPLES = 2_000_000  # pixels of a at most on which the fold share is measured


def match_images(image_a: Any, image_b: Any, *, features: Literal["sift", "shape_context"] = "sift",
                 method: Literal["l2e", "vfc"] = "l2e", options: MatchOptions | dict[str, Any] | None = None,
                 rng: int | np.random.Generator | None = None, mask_a: Any = None,
                 mask_b: Any = None) -> ImageMatch:
    """Find which feature matches between two images are real, and the smooth map between them.

    Parameters
    ----------
    image_a, image_b : ndarray, path or bytes
        (H, W) or (H, W, 3) arrays of any real dtype (RGB; an alpha channel is dropped), paths to
        PNG / JPEG / TIFF / BMP / WebP files, or their encoded bytes.
    features : {"sift", "shape_context"}
        "sift": SIFT keypoints with RootSIFT descriptors (photographs).
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

    t = time.perf_counter()
    feat_a = detect_sift(gray_a, mask=m_a, max_keypoints=opts.max_keypoints, max_side=opts.max_side)
    feat_b = detect_sift(gray_b, mask=m_b, max_keypoints=opts.max_keypoints, max_side=opts.max_side)
    timings["features"] = _ms(t)

    t = time.perf_counter()
    ia, ib = match_descriptors(feat_a.descriptors, feat_b.descriptors, ratio=opts.ratio, mutual=opts.mutual)
    src, dst = feat_a.points[ia], feat_b.points[ib]
    timings["matching"] = _ms(t)

    t = time.perf_counter()
    sparse = filter_matches(src, dst, method=method, options=opts.filter, rng=generator)
    timings["filter"] = _ms(t)

    transform, converged, n_dense = sparse.transform, sparse.converged, 0
    if opts.dense and sparse.reason is None and sparse.n_inliers >= 6:
        t = time.perf_counter()
        refined = refine_dense(gray_a, gray_b, sparse.transform, opts, method, generator, m_a, m_b)
        if refined is not None:
            transform, converged, n_dense = refined
        timings["dense"] = _ms(t)

    t = time.perf_counter()
    folds = 0.0 if sparse.reason is not None else fold_fraction(transform, shape_a, max_samples=_FOLD_SAMPLES)
    timings["folds"] = _ms(t)
    timings["total"] = _ms(t_start)
    return ImageMatch(keypoints_a=feat_a.points, keypoints_b=feat_b.points, src=src, dst=dst,
                      inliers=sparse.inliers, scores=sparse.scores, transform=transform,
                      converged=bool(converged), reason=sparse.reason, seed=seed, timings_ms=timings,
                      shape_a=(int(shape_a[0]), int(shape_a[1])), shape_b=(int(shape_b[0]), int(shape_b[1])),
                      fold_fraction=folds, n_dense=n_dense, features=features, method=method)


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
