"""``MatchOptions``: the options of :func:`reglib.match_images`, each declared once with its bounds.

The service's form fields (and their OpenAPI schema), the CLI's flags of ``reglib match`` and the
columns of a batch manifest are all derived from these declarations (:mod:`reglib.options`), so
a new field here appears in every one of them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from ..io import DEFAULT_MAX_PIXELS
from ..options import check_declared, declared, option

__all__ = ["MatchOptions", "FEATURES", "DEFAULT_MAX_PIXELS"]

FEATURES: tuple[Literal["sift", "shape_context", "multimodal", "auto"], ...] = (
    "sift", "shape_context", "multimodal", "auto")


@declared
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
        Estimator options of the dense stage, replacing its defaults; default: the ``filter``
        options over ``reglib.dense.DENSE_L2E`` / ``DENSE_VFC`` (L2E: a richer basis, up to 150
        centres, one per 4 dense matches at the working size and one per 6 on coarser levels, one
        layer, annealing from the identity, as the dense matches are mostly true; VFC: 60
        centres, beta 1, affine part).
    dense_rounds : int
        Rounds of guided matching per pyramid level at most (the dense stage works coarse to
        fine over up to three levels), each around the previous round's estimate; a level stops
        early once a round no longer moves the estimate, and each round's search radius follows
        how far the previous one moved it (at least 3 px, at most ``dense_radius``).
    dense_patch : int
        Half-size h of the (2 h + 1)^2 patches correlated by the dense stage, pixels.
    dense_detail : bool
        Grey images: the dense stage's coarser levels follow a strongly bent field with a narrow-kernel fit on a
        lattice (:func:`reglib.dense.detailed`) before the finer levels search around it. More accurate on strong
        local deformation and slower (``benchmarks/README.md``, the narrow-kernel detail): off by default.
    contour_points : int
        ``features="shape_context"``: edge points sampled from each image.
    multimodal_ratio : float
        ``features="multimodal"``: ratio test of its descriptor matching (looser than SIFT's: the
        estimator filters afterwards, and cross-sensor descriptors are less distinct).
    band : int or None
        The one band (0-based) of multi-band images that the features see; None: the grey
        rendering of :func:`reglib.features.feature_bands` (the first three bands read as RGB, a
        grey image as it is). Warps keep every band either way.

    Sizes are bounded (max_keypoints 1,000,000, max_side 100,000, max_pixels 2^31,
    dense_step 1024, dense_radius 256, dense_rounds 10, dense_patch 64, contour_points 20000)
    so that no request runs without end; :func:`reglib.options.option_specs` lists every bound.
    """

    ratio: float = option(0.8, kind="float", low=0.0, high=1.0, low_open=True,
                          doc="Lowe's ratio test on descriptor distances (1.0 keeps every nearest neighbour)")
    mutual: bool = option(False, kind="bool", doc="keep only mutual nearest neighbours")
    max_keypoints: int = option(4000, kind="int", low=1, high=1_000_000, doc="strongest keypoints kept per image")
    dense: bool = option(True, kind="bool", doc="guided dense refinement after the sparse estimate")
    max_side: int = option(1600, kind="int", low=16, high=100_000,
                           doc="images with a longer side are detected on a resized copy (px)")
    max_pixels: int = option(DEFAULT_MAX_PIXELS, kind="int", low=1, high=2**31,
                             doc="largest W * H accepted per image (from the header, before decoding)")
    filter: dict[str, Any] | None = option(None, kind="json", doc="options of the estimator (a JSON object)")
    dense_step: int = option(16, kind="int", low=1, high=1024, doc="grid spacing of the dense stage (px)")
    dense_radius: int = option(14, kind="int", low=1, high=256,
                               doc="search radius of the dense stage around the first estimate (px)")
    dense_filter: dict[str, Any] | None = option(None, kind="json",
                                                 doc="estimator options of the dense stage (a JSON object)")
    dense_rounds: int = option(2, kind="int", low=1, high=10,
                               doc="rounds of guided dense matching per pyramid level, at most")
    dense_patch: int = option(5, kind="int", low=2, high=64, doc="half-size of the dense stage's patches (px)")
    dense_detail: bool = option(False, kind="bool",
                                doc="dense stage: follow strongly bent fields on coarser levels (grey images; slower)")
    contour_points: int = option(300, kind="int", low=10, high=20000,
                                 doc="features=shape_context: edge points sampled per image")
    multimodal_ratio: float = option(0.95, kind="float", low=0.0, high=1.0, low_open=True,
                                     doc="features=multimodal: ratio test of its descriptor matching")
    band: int | None = option(None, kind="int", low=0, high=1023, optional=True,
                              doc="the one band (0-based) the features see; none: grey from the first three bands")

    def __post_init__(self) -> None:
        check_declared(self)
