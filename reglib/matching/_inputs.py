"""The first stage of :func:`reglib.match_images`: the call's options checked and both images read.

A TIFF file over ``max_pixels`` is read reduced by a whole factor to at most ``max_side``
(:func:`reglib.io.read_working_image`); the match is made on the copies and :func:`full_resolution`
maps it back to the full images' pixels exactly.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .._parallel import run_both
from .._validation import as_choice, as_options, as_rng, seed_of
from ..errors import InputError
from ..features import NormalizedImage, check_mask, feature_bands, to_gray_uint8
from ..io import read_working_image
from ..robust import METHODS, L2EOptions, VFCOptions
from ._options import FEATURES, MatchOptions

Features = Literal["sift", "shape_context", "multimodal", "auto"]


def ms(t0: float) -> float:
    """Milliseconds since ``t0`` (a ``time.perf_counter()`` reading)."""
    return (time.perf_counter() - t0) * 1000.0


@dataclass(frozen=True, eq=False)
class Run:
    """What one call runs with: the features asked for, the estimator and its options, the random state,
    and the stage timings."""

    features: Features
    method: Literal["l2e", "vfc"]
    options: MatchOptions
    filter: L2EOptions | VFCOptions  # the estimator's options (``MatchOptions.filter``, checked)
    rng: np.random.Generator
    seed: int | None  # recorded in the result
    timings: dict[str, float]  # stage -> ms, filled in as the stages run
    t_start: float


@dataclass(frozen=True, eq=False)
class Images:
    """The two images as read, the bands their features see, their grey uint8 copies and their masks (checked)."""

    img_a: np.ndarray
    img_b: np.ndarray
    view_a: np.ndarray  # (H, W) or (H, W, 3): :func:`~reglib.features.feature_bands` of the image
    view_b: np.ndarray
    gray_a: np.ndarray
    gray_b: np.ndarray
    mask_a: np.ndarray | None
    mask_b: np.ndarray | None
    factors: tuple[int, int] = (1, 1)  # whole factors the images were reduced by as read (1: read whole)
    full_shapes: tuple[tuple[int, int], tuple[int, int]] | None = None  # (H, W) of the files, when reduced

    @property
    def shape_a(self) -> tuple[int, int]:
        return int(self.img_a.shape[0]), int(self.img_a.shape[1])

    @property
    def shape_b(self) -> tuple[int, int]:
        return int(self.img_b.shape[0]), int(self.img_b.shape[1])

    @functools.cached_property
    def normalized(self) -> tuple[NormalizedImage, NormalizedImage]:
        """Both images normalized once for the multimodal path (features, refinement, structure fields)."""
        return run_both(lambda: NormalizedImage.of(self.view_a), lambda: NormalizedImage.of(self.view_b))


def run_of(features: Any, method: Any, options: Any, rng: Any) -> Run:
    """The :class:`Run` of a call, every option checked now (a misspelled field fails before SIFT runs)."""
    t_start = time.perf_counter()
    features = as_choice(features, "features", FEATURES)
    method = as_choice(method, "method", METHODS)
    opts = as_options(options, MatchOptions)
    estimator_options: type[L2EOptions | VFCOptions] = L2EOptions if method == "l2e" else VFCOptions
    filter_options = as_options(opts.filter, estimator_options, "filter")
    if opts.dense_filter is not None:
        as_options(opts.dense_filter, estimator_options, "dense_filter")
    return Run(features=features, method=method, options=opts, filter=filter_options, rng=as_rng(rng),
               seed=seed_of(rng), timings={}, t_start=t_start)


def read_images(image_a: Any, image_b: Any, mask_a: Any, mask_b: Any, run: Run) -> Images:
    """Both images read (within ``max_pixels``), the bands the features see (``MatchOptions.band``), their grey
    copies, and their masks checked against them."""
    t = time.perf_counter()
    max_pixels, max_side = run.options.max_pixels, run.options.max_side
    read_a = read_working_image(image_a, max_side=max_side, max_pixels=max_pixels, name="image_a")
    read_b = read_working_image(image_b, max_side=max_side, max_pixels=max_pixels, name="image_b")
    img_a, img_b = read_a.image, read_b.image
    reduced = read_a.factor > 1 or read_b.factor > 1
    if reduced and (mask_a is not None or mask_b is not None):
        raise InputError("masks are not taken with an image read at a working size (a TIFF over `max_pixels`)")
    band = run.options.band
    view_a, view_b = feature_bands(img_a, band), feature_bands(img_b, band)
    images = Images(img_a=img_a, img_b=img_b, view_a=view_a, view_b=view_b,
                    gray_a=to_gray_uint8(view_a), gray_b=to_gray_uint8(view_b),
                    mask_a=check_mask(mask_a, img_a.shape[:2], "mask_a"),
                    mask_b=check_mask(mask_b, img_b.shape[:2], "mask_b"),
                    factors=(read_a.factor, read_b.factor),
                    full_shapes=(read_a.shape, read_b.shape) if reduced else None)
    run.timings["read"] = ms(t)
    return images
