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
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np

from ._validation import as_choice, as_options, as_rng, check_int, check_range
from .dense import fold_fraction, guided_matches
from .errors import InputError
from .features.sift import (
    check_mask,
    detect_sift,
    match_descriptors,
    to_gray_uint8,
)
from .io import DEFAULT_MAX_PIXELS, read_image
from .robust import L2EOptions, VFCOptions, filter_matches
from .robust.filter import METHODS
from .transforms import KernelWarp, LinearPart

__all__ = ["MatchOptions", "ImageMatch", "match_images", "edge_points", "FEATURES"]

FEATURES: tuple[Literal["sift", "shape_context"], ...] = ("sift", "shape_context")

_FOLD_SAMPLES = 2_000_000  # pixels of a at most on which the fold share is measured

# Options of the dense stage's estimator that differ from the sparse stage's (a richer basis).
_DENSE_L2E = {"max_centers": 100, "max_fit_points": 4000}
_DENSE_VFC = {"n_centers": 60, "beta": 1.0, "linear": "affine"}


@dataclass(frozen=True, slots=True, kw_only=True)
class MatchOptions:
    """Options of :func:`match_images`.

    Parameters
    ----------
    ratio : float
        Lowe's ratio test on RootSIFT distances, in (0, 1]; 1.0 keeps every nearest neighbour.
    mutual : bool
        Keep only matches that are each other's nearest neighbour.
    max_keypoints : int
        Strongest keypoints kept per image.
    dense : bool
        Guided dense refinement after the sparse estimate (a more accurate transform).
    max_side : int
        Images whose longer side exceeds this are detected (and densely matched) on a resized
        copy; coordinates are mapped back to the original pixels exactly.
    max_pixels : int
        Largest W * H accepted per image (read from an encoded image's header before decoding).
    filter : dict or None
        Options of the estimator (``L2EOptions`` / ``VFCOptions`` fields).
    dense_step : int
        Grid spacing of the dense stage, pixels (of the possibly resized copy).
    dense_radius : int
        Search radius of the dense stage around the first estimate, pixels.
    dense_filter : dict or None
        Estimator options of the dense stage; default: the ``filter`` options over a richer
        basis (L2E: ``max_centers`` 100; VFC: 60 centres, beta 1, affine part).
    dense_rounds : int
        Rounds of guided matching, each around the previous round's estimate (rounds after the
        first search within half of ``dense_radius``, at least 3 px).
    dense_patch : int
        Half-size h of the (2 h + 1)^2 patches correlated by the dense stage, pixels.
    contour_points : int
        ``features="shape_context"``: edge points sampled from each image.

    Sizes are bounded (dense_radius 256, dense_rounds 10, dense_patch 64, contour_points 20000)
    so that no request runs without end.
    """

    ratio: float = 0.8
    mutual: bool = False
    max_keypoints: int = 4000
    dense: bool = True
    max_side: int = 1600
    max_pixels: int = DEFAULT_MAX_PIXELS
    filter: dict[str, Any] | None = None
    dense_step: int = 16
    dense_radius: int = 14
    dense_filter: dict[str, Any] | None = None
    dense_rounds: int = 2
    dense_patch: int = 5
    contour_points: int = 300

    def __post_init__(self) -> None:
        check_range("ratio", self.ratio, 0.0, 1.0, low_open=True)
        # Upper bounds keep every request finite in time and memory, far beyond any use.
        for name, low, high in (("max_keypoints", 1, None), ("max_side", 16, None), ("max_pixels", 1, None),
                                ("dense_step", 1, None), ("dense_radius", 1, 256), ("dense_rounds", 1, 10),
                                ("dense_patch", 2, 64), ("contour_points", 10, 20000)):
            check_int(name, getattr(self, name), low, high)
        if not isinstance(self.mutual, (bool, np.bool_)):
            raise InputError(f"`mutual` must be a bool, got {self.mutual!r}")
        if not isinstance(self.dense, (bool, np.bool_)):
            raise InputError(f"`dense` must be a bool, got {self.dense!r}")
        for name in ("filter", "dense_filter"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, dict):
                raise InputError(f"`{name}` must be a dict of estimator options or None, got {type(value).__name__}")


@dataclass(frozen=True, eq=False)
class ImageMatch:
    """What :func:`match_images` found. Coordinates are (x, y) pixels of the original images.

    Attributes
    ----------
    keypoints_a, keypoints_b : (Ka, 2), (Kb, 2) float64 ndarray
        Detected keypoints.
    src, dst : (N, 2) float64 ndarray
        Putative matches: ``src[i]`` in a matched to ``dst[i]`` in b.
    inliers : (N,) bool ndarray
        Matches consistent with the estimated transformation (the sparse L2E/VFC stage).
    scores : (N,) float64 ndarray
        Their agreement in [0, 1].
    transform : KernelWarp
        Maps a's pixels into b (the dense stage's estimate when dense refinement ran).
    converged : bool
        False when the estimator hit an iteration cap or there was too little to work with.
    reason : str or None
        "too_few_matches" when nothing could be estimated (no keypoints included), else None.
    seed : int or None
        The integer seed given as ``rng``, recorded for reproduction.
    timings_ms : dict of str to float
        Per-stage wall time: "read", "features", "matching", "filter", "dense", "total".
    shape_a, shape_b : (int, int)
        (H, W) of the images.
    fold_fraction : float
        Share of a's pixels where the transform folds (Jacobian determinant <= 0).
    n_dense : int
        Dense matches the final transform was fitted to (0 without dense refinement).
    """

    keypoints_a: np.ndarray
    keypoints_b: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    inliers: np.ndarray
    scores: np.ndarray
    transform: KernelWarp
    converged: bool
    reason: str | None
    seed: int | None
    timings_ms: dict[str, float] = field(default_factory=dict)
    shape_a: tuple[int, int] = (0, 0)
    shape_b: tuple[int, int] = (0, 0)
    fold_fraction: float = 0.0
    n_dense: int = 0

    @property
    def n_matches(self) -> int:
        """Number of putative matches N."""
        return int(len(self.src))

    @property
    def n_inliers(self) -> int:
        """Number of inliers."""
        return int(np.count_nonzero(self.inliers))

    def to_dict(self) -> dict[str, Any]:
        """The match-result JSON of CONTRACTS.md (inliers as ascending indices), plus shapes and folds."""
        return {
            "n_matches": self.n_matches,
            "n_inliers": self.n_inliers,
            "src": self.src.tolist(),
            "dst": self.dst.tolist(),
            "inliers": np.flatnonzero(self.inliers).tolist(),
            "scores": [float(s) for s in self.scores],
            "transform": self.transform.to_dict(),
            "converged": bool(self.converged),
            "reason": self.reason,
            "seed": self.seed,
            "timings_ms": {k: float(v) for k, v in self.timings_ms.items()},
            "shape_a": [int(v) for v in self.shape_a],
            "shape_b": [int(v) for v in self.shape_b],
            "fold_fraction": float(self.fold_fraction),
        }


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
    seed = None
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        seed = int(rng)
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
        refined = _dense_stage(gray_a, gray_b, sparse.transform, opts, method, generator, m_a, m_b)
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
                      fold_fraction=folds, n_dense=n_dense)


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
                          shape_a=shape_a, shape_b=shape_b)
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
                      fold_fraction=folds)


def edge_points(gray: np.ndarray, n_points: int, mask: np.ndarray | None = None) -> np.ndarray:
    """About ``n_points`` (x, y) points spread evenly along the edges of a grey uint8 image.

    Edges are Canny's (thresholds from the median grey level, after a light blur); the edge
    curves (``cv2.findContours``) are concatenated and sampled at equal steps of their total length.
    """
    if min(gray.shape) < 3:
        return np.zeros((0, 2))
    blur = cv2.GaussianBlur(gray, (5, 5), 1.0)
    med = float(np.median(blur))
    lo, hi = max(0.0, 0.66 * med), min(255.0, 1.33 * med)
    if hi - lo < 20:  # near-black or near-white backgrounds (silhouettes): fixed thresholds
        lo, hi = 50.0, 150.0
    edges = cv2.Canny(blur, lo, hi)
    if mask is not None:
        edges[~mask] = 0
    contours, _ = cv2.findContours(edges, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float64)
    # findContours walks each thin edge curve twice (both sides): drop repeated pixels
    _, first = np.unique(pts, axis=0, return_index=True)
    pts = pts[np.sort(first)]
    if len(pts) <= n_points:
        return pts
    idx = np.linspace(0, len(pts) - 1, n_points).round().astype(np.intp)
    return pts[idx]


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0


def _dense_options(opts: MatchOptions, method: Literal["l2e", "vfc"]) -> dict[str, Any]:
    if opts.dense_filter is not None:
        return dict(opts.dense_filter)
    base = dict(opts.filter or {})
    return {**(_DENSE_L2E if method == "l2e" else _DENSE_VFC), **base}


def _dense_stage(gray_a: np.ndarray, gray_b: np.ndarray, f0: KernelWarp, opts: MatchOptions,
                 method: Literal["l2e", "vfc"], rng: np.random.Generator, mask_a: np.ndarray | None,
                 mask_b: np.ndarray | None) -> tuple[KernelWarp, bool, int] | None:
    """Guided dense matching around ``f0`` and the final estimate; None when it finds too little."""
    sa = min(1.0, opts.max_side / max(gray_a.shape))
    sb = min(1.0, opts.max_side / max(gray_b.shape))
    ga, ma = _downscaled(gray_a, mask_a, sa)
    gb, mb = _downscaled(gray_b, mask_b, sb)
    current: tuple[KernelWarp, bool, int] | None = None
    f = f0
    for k in range(opts.dense_rounds):
        # later rounds start from a dense estimate: a smaller search window suffices
        radius = opts.dense_radius if k == 0 else max(3, opts.dense_radius // 2)
        src, dst, _ = guided_matches(ga, gb, _rescaled(f, sa, sb), step=opts.dense_step, radius=radius,
                                     half_patch=opts.dense_patch, mask_a=ma, mask_b=mb)
        if len(src) < 20:
            break
        src = (src + 0.5) / sa - 0.5
        dst = (dst + 0.5) / sb - 0.5
        res = filter_matches(src, dst, method=method, options=_dense_options(opts, method), rng=rng)
        if res.reason is not None or res.n_inliers < 20:
            break
        current = (res.transform, res.converged, len(src))
        f = res.transform
    return current


def _downscaled(gray: np.ndarray, mask: np.ndarray | None, s: float) -> tuple[np.ndarray, np.ndarray | None]:
    """float32 copy resized by exactly ``s`` (OpenCV half-pixel centres), and the mask likewise."""
    g = gray.astype(np.float32)
    if s >= 1.0:
        return g, mask
    small = cv2.resize(g, (0, 0), fx=s, fy=s, interpolation=cv2.INTER_AREA)
    m = None
    if mask is not None:
        m = cv2.resize(mask.astype(np.uint8), (small.shape[1], small.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    return small, m


def _rescaled(f: KernelWarp, sa: float, sb: float) -> KernelWarp:
    """The warp between copies of a and b resized by ``sa`` and ``sb`` (x' = s (x + 0.5) - 0.5)."""
    if sa == 1.0 and sb == 1.0:
        return f
    lin = None if f.linear is None else LinearPart(kind=f.linear.kind, matrix=f.linear.matrix.copy())
    return KernelWarp(dim=2, src_mean=sa * (f.src_mean + 0.5) - 0.5, src_scale=sa * f.src_scale,
                      dst_mean=sb * (f.dst_mean + 0.5) - 0.5, dst_scale=sb * f.dst_scale, linear=lin,
                      beta=f.beta, centers=f.centers, weights=f.weights)
