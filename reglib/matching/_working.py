"""The last stage of :func:`reglib.match_images` for images read at a working size: the match mapped back.

A TIFF over ``max_pixels`` is read reduced by a whole factor k (:func:`reglib.io.read_working_image`);
everything found on the copies is mapped to the full images' pixels exactly: a point x' of a copy is
``k (x' + 0.5) - 0.5`` of its image (CONTRACTS.md's centre convention), and the transform is
:meth:`reglib.KernelWarp.rescaled` by the two factors. The confidence map stays at the working size
and is not carried; its summary is.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ._inputs import Images
from ._result import ImageMatch


def _scaled(points: np.ndarray, factor: int) -> np.ndarray:
    """Points (x, y) of a copy reduced by ``factor``, in the full image's pixels."""
    return factor * (np.asarray(points, np.float64) + 0.5) - 0.5


def full_resolution(match: ImageMatch, images: Images) -> ImageMatch:
    """``match`` in the full images' pixels when ``images`` were read reduced; else ``match`` itself."""
    if images.full_shapes is None:
        return match
    ka, kb = images.factors
    summary = match.confidence_summary
    stats = None if summary is None else {k: float(v) for k, v in summary.items() if k != "dense"}
    return dataclasses.replace(match, keypoints_a=_scaled(match.keypoints_a, ka),
                               keypoints_b=_scaled(match.keypoints_b, kb), src=_scaled(match.src, ka),
                               dst=_scaled(match.dst, kb), transform=match.transform.rescaled(ka, kb),
                               shape_a=images.full_shapes[0], shape_b=images.full_shapes[1], confidence=None,
                               confidence_stats=stats)
