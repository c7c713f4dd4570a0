"""``match_images``: two images in; putative matches, the inlier set and the transform out.

Stages (the L2E paper's image pipeline [1]_), one private module each, each returning a record:
the images read (``_inputs``; a large TIFF at a working size) -> the sparse stage (``_sparse``: SIFT
keypoints with RootSIFT descriptors, nearest-neighbour matching with Lowe's ratio test, robust filtering by
L2E or VFC giving a first transform f0; or the multimodal features, whose estimate is
:mod:`reglib.matching._multimodal`'s; ``auto`` falls back from one to the other) -> the dense stage
(``_dense``: guided dense matching around f0 and a final transform with a richer kernel basis,
:mod:`reglib.dense`) -> the verdict (the images' evidence here, the decision
:func:`reglib._verdict.image_verdict`; an ``unsupported`` answer gets a second try: on the haematoxylin
channel for ``features="auto"``, ``_second_try``; from a start that needs no putatives for ``features="sift"``,
:func:`._dense.residual_retry`) -> for a large TIFF read at a working size, the answer mapped to full resolution
(``_working``). The shape-context path is ``_contours``.

Coordinates: (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0); the transform
maps image a into image b.

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of
       Transformation for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
"""
from __future__ import annotations

import time
from typing import Any, Literal

import numpy as np

from .._verdict import UNSUPPORTED, Reason, image_verdict
from ..dense import EVIDENCE_Z, MAX_FOUND_AWAY, OverNoMotion, fold_fraction, found_away, rate_over_no_motion
from ._contours import FOLD_SAMPLES, match_contours
from ._dense import DENSE_STARTS, Dense, dense_options, dense_stage, residual_retry
from ._inputs import Images, Run, ms, read_images, run_of
from ._options import MatchOptions
from ._result import ImageMatch
from ._second_try import rated_better, stain_views
from ._sparse import Sparse, sift_stage, sparse_stage, too_few
from ._working import full_resolution

__all__ = ["dense_options", "match_images"]

_SECOND_TRY_FEATURES = ("auto",)  # the features whose unsupported answers on colour images get a second try


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
        PNG / JPEG / TIFF / BMP / WebP files, or their encoded bytes. A TIFF file over
        ``options.max_pixels`` (a whole slide, a satellite scene) is read reduced by a whole factor
        to at most ``max_side``, tile by tile or from a pyramid level, and the answer is mapped back
        to its full-resolution pixels exactly (no masks then; the confidence map is not carried).
    features : {"sift", "shape_context", "multimodal", "auto"}
        "sift": SIFT keypoints with RootSIFT descriptors (photographs). An ``unsupported`` answer
        gets a residual try: the dense stage again from the sparse fit composed with the motion it
        left (optical flow on b warped onto a), kept when usable, rated better by the images and
        found away from by few of a's patches searched around it (``timings_ms["residual_try"]``).
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
        30 inliers (``ImageMatch.features`` says which ran). Between the two, where both images are
        colour (stained sections: H&E against an immunostain), SIFT on both images' haematoxylin
        channel (colour deconvolution), its answer kept when usable (``timings_ms["haematoxylin"]``).
        When the answer is ``unsupported`` on colour images, both paths again on the channel; that
        answer is kept only when it is usable and the first try's images rate it over no motion by the
        margin and more clearly than the first answer (``timings_ms["second_try"]``).
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
        transform, ``converged=False`` and the reason ``too_few_matches``.

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
    run = run_of(features, method, options, rng)
    images = read_images(image_a, image_b, mask_a, mask_b, run)
    if run.features == "shape_context":
        return full_resolution(match_contours(images, run), images)
    sparse, dense, (converged, reason, rating), stain_sift = _try(images, run)
    if reason == UNSUPPORTED and rating is not None:
        # (a second try repeats what the haematoxylin channel's SIFT already found enough matches for)
        if run.features in _SECOND_TRY_FEATURES and (stain_sift is None or too_few(stain_sift)):
            sparse, dense, converged, reason = _second_try(images, run, sparse, dense, rating, stain_sift)
        elif run.features == "sift":
            dense, converged, reason = _residual_try(images, run, sparse, dense, rating)
    folds = _folds(sparse, dense, images, run)
    run.timings["total"] = ms(run.t_start)
    fit = sparse.fit
    match = ImageMatch(keypoints_a=sparse.keypoints_a, keypoints_b=sparse.keypoints_b, src=sparse.src, dst=sparse.dst,
                      inliers=fit.inliers, scores=fit.scores, transform=dense.transform, converged=bool(converged),
                      reason=reason, seed=run.seed, timings_ms=run.timings, shape_a=images.shape_a,
                      shape_b=images.shape_b, fold_fraction=folds, n_dense=dense.n_dense, features=sparse.features,
                      method=run.method, confidence=dense.confidence, dense=dense.outcome)
    return full_resolution(match, images)


def _try(images: Images, run: Run, sift: Sparse | None = None
         ) -> tuple[Sparse, Dense, tuple[bool, Reason | None, OverNoMotion | None], Sparse | None]:
    """The sparse and dense stages on ``images`` and their verdict, and the SIFT stage on the haematoxylin
    channel where it ran (None elsewhere).

    With ``features="auto"`` (and no ``sift``, SIFT's stage on ``images`` when it already ran), where SIFT finds
    too little on two colour images, the haematoxylin channel's SIFT comes before the multimodal features
    (:func:`_haematoxylin_first`)."""
    stain_sift = None
    if run.features == "auto" and sift is None:
        sift = sift_stage(images, run)
        if too_few(sift):
            stain_sift, answer = _haematoxylin_first(images, run)
            if answer is not None:
                return (*answer, stain_sift)
    sparse = sparse_stage(images, run, sift)
    dense = dense_stage(sparse, images, run)
    return sparse, dense, _verdict(sparse, dense, run), stain_sift


def _haematoxylin_first(images: Images, run: Run
                        ) -> tuple[Sparse | None, tuple[Sparse, Dense, tuple[bool, Reason | None,
                                                                               OverNoMotion | None]] | None]:
    """SIFT on both colour images' haematoxylin channel (:func:`._second_try.stain_views`), and where it finds
    enough, the dense stage and the verdict on that channel: that SIFT stage (None for images without colour),
    and the answer where its verdict makes it usable (None otherwise).

    Stained sections whose grey renderings SIFT cannot match (H&E against an immunostain) share their nuclei: on
    the channel SIFT finds them, and its answer costs a fraction of the multimodal features' and their
    structure fields'. Where the channel has too little (a section with a pale counterstain) or its answer is not
    usable, the multimodal features run as before."""
    stains = stain_views(images)
    if stains is None:
        return None, None
    t = time.perf_counter()
    sift = sift_stage(stains, run)
    answer = None
    if not too_few(sift):
        dense = dense_stage(sift, stains, run)
        verdict = _verdict(sift, dense, run)
        answer = (sift, dense, verdict) if verdict[0] else None
    run.timings["haematoxylin"] = ms(t)
    return sift, answer


def _second_try(images: Images, run: Run, sparse: Sparse, dense: Dense, rating: OverNoMotion,
                sift: Sparse | None = None) -> tuple[Sparse, Dense, bool, Reason | None]:
    """For an ``unsupported`` first answer (``sparse``, ``dense``; ``rating``, its images' rating of it) on
    colour images: the stages again on both images' haematoxylin channel (:mod:`._second_try`; ``sift``, the
    channel's SIFT stage where the first try ran it), whose answer is kept when it is usable and the first try's
    images rate it better (:func:`._second_try.rated_better`); otherwise the first answer, ``unsupported``."""
    t = time.perf_counter()
    stains = stain_views(images)
    timings = dict(run.timings)
    run.timings.clear()  # the stages' timings of the try whose answer is kept
    if stains is not None:
        second_sparse, second, (converged, _, _), _ = _try(stains, run, sift)
        if converged and rated_better(rate_over_no_motion(dense.field_a, dense.field_b, second.transform,
                                                          dense.options), rating):
            run.timings["second_try"] = ms(t)
            return second_sparse, second, True, None
    run.timings.clear()
    run.timings.update(timings, second_try=ms(t))  # the first try's stage timings, and the second's total
    return sparse, dense, False, UNSUPPORTED


def _residual_try(images: Images, run: Run, sparse: Sparse, dense: Dense, rating: OverNoMotion
                  ) -> tuple[Dense, bool, Reason | None]:
    """For an ``unsupported`` answer of ``features="sift"``: the dense stage again from a start that finds the
    motion the sparse fit missed (:func:`._dense.residual_retry`); its answer is kept when it is usable, the images
    rate it better than the first (:func:`._second_try.rated_better`) and a's patches, searched around it, are
    found away from it at no more than :data:`reglib.dense.MAX_FOUND_AWAY` of the places
    (:func:`reglib.dense.found_away`), else the first, ``unsupported``.

    The last test is this try's own: its start comes from optical flow, not from matches, and its answer can be
    a clear peak of the similarity 4 px around while the images' own match of a bent part lies 10 px away."""
    t = time.perf_counter()
    timings = dict(run.timings)
    retried = residual_retry(sparse, dense, images, run)
    if retried is not None:
        converged, reason, second = _verdict(sparse, retried, run)
        if (converged and second is not None and rated_better(second, rating)
                and found_away(retried.field_a, retried.field_b, retried.transform, retried.options) <= MAX_FOUND_AWAY):
            run.timings["residual_try"] = ms(t)  # the stages' timings of the try whose answer is kept
            return retried, True, reason
    run.timings.clear()
    run.timings.update(timings, residual_try=ms(t))  # the first try's stage timings, and the retry's total
    return dense, False, UNSUPPORTED


def _verdict(sparse: Sparse, dense: Dense, run: Run) -> tuple[bool, Reason | None, OverNoMotion | None]:
    """``converged`` and ``reason``: the images' evidence for the answer over no motion, measured where the
    sparse fit is one the dense stage starts from, and the decision (:func:`reglib._verdict.image_verdict`);
    and that rating (None where it was not measured)."""
    reason = sparse.fit.reason
    if reason not in DENSE_STARTS:
        return (*image_verdict(reason, dense.converged, dense.outcome, None, EVIDENCE_Z), None)
    t = time.perf_counter()
    rating = rate_over_no_motion(dense.field_a, dense.field_b, dense.transform, dense.options)
    run.timings["evidence"] = ms(t)
    # a region where the answer is no peak: judged where the caller asked for SIFT (one modality), where a right
    # answer is a clear peak everywhere; across sensors a right answer can lose its peak in a region whose content
    # the two sensors see differently, also when "auto" found enough SIFT matches (benchmarks/README.md, issue 50)
    missed_part = run.features == "sift" and rating.weak_region
    return (*image_verdict(reason, dense.converged, dense.outcome, rating.z, EVIDENCE_Z,
                           short_of_margin=rating.short_of_margin or missed_part), rating)


def _folds(sparse: Sparse, dense: Dense, images: Images, run: Run) -> float:
    """The share of a where the transform folds (0 for a fit with nothing to judge)."""
    t = time.perf_counter()
    folds = 0.0
    if sparse.fit.reason in DENSE_STARTS:
        folds = fold_fraction(dense.transform, images.shape_a, max_samples=FOLD_SAMPLES)
    run.timings["folds"] = ms(t)
    return folds
