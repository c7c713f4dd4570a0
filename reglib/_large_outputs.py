"""The files of a match between images larger than memory (TIFF files over the pixel limit).

:func:`reglib.outputs.save_match` writes ``transform.json`` and ``match.json`` as for any pair; the
rest is sized for what a large pair is for:

- ``flow.<format>`` is not written: a full-size flow is 8 bytes a pixel of a (3.2 GB for 20,000 x
  20,000), and ``reglib apply DIR/transform.json --out flow.flo --shape-a H W`` writes it band by
  band when it is wanted;
- ``warped.tif`` (with ``warped``): b warped onto a at full resolution, a tiled TIFF written tile by
  tile (:func:`reglib.warp_image_file`), every band and the dtype kept;
- ``matches.png`` and ``overlay.png`` (with ``pictures``): drawn on copies reduced by a whole factor
  to at most :data:`PICTURE_SIDE` (they are for looking at), the match scaled to them;
- ``confidence.png`` is not written: the confidence map is made at the working size and not carried.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from .matching import ImageMatch

__all__ = ["PICTURE_SIDE", "is_large", "save_large"]

PICTURE_SIDE = 1600  # longer side of the pictures of a large pair, at most


def is_large(match: ImageMatch, max_pixels: int) -> bool:
    """Whether a match's images are over ``max_pixels`` (either of them): its files are those of a large pair."""
    return any(int(h) * int(w) > max_pixels for h, w in (match.shape_a, match.shape_b))


def save_large(match: ImageMatch, out: Path, image_a: Any, image_b: Any, *, warped: bool,
               pictures: bool) -> dict[str, Path]:
    """``warped.tif`` and the pictures of a large pair (see the module docstring), those asked for and possible."""
    from .dense import warp_image_file

    for name, image in (("image_a", image_a), ("image_b", image_b)):
        if image is not None and not isinstance(image, (str, os.PathLike)):
            raise InputError(f"`{name}` of a match over the pixel limit must be given as its file's path")
    written: dict[str, Path] = {}
    if image_b is None:
        return written
    if warped:
        warp_image_file(image_b, match.transform, match.shape_a, out / "warped.tif")
        written["warped"] = out / "warped.tif"
    if pictures and image_a is not None:
        written.update(_pictures(match, out, image_a, image_b))
    return written


def _pictures(match: ImageMatch, out: Path, image_a: Any, image_b: Any) -> dict[str, Path]:
    """``matches.png`` and (for an answer that converged) ``overlay.png``, on reduced copies of a and b."""
    from .dense import warp_image
    from .io import encode_png, read_working_image, write_bytes_atomic
    from .outputs import writes_motion
    from .visualize import draw_matches
    from .visualize import overlay as blend

    a = read_working_image(image_a, max_side=PICTURE_SIDE, max_pixels=PICTURE_SIDE**2, name="image_a")
    b = read_working_image(image_b, max_side=PICTURE_SIDE, max_pixels=PICTURE_SIDE**2, name="image_b")
    ka, kb = a.factor, b.factor
    small = dataclasses.replace(match, keypoints_a=_reduced(match.keypoints_a, ka),
                                keypoints_b=_reduced(match.keypoints_b, kb), src=_reduced(match.src, ka),
                                dst=_reduced(match.dst, kb), transform=match.transform.rescaled(1.0 / ka, 1.0 / kb),
                                shape_a=a.image.shape[:2], shape_b=b.image.shape[:2])
    written = {"matches": out / "matches.png"}
    write_bytes_atomic(written["matches"], encode_png(draw_matches(a.image, b.image, small)))
    if writes_motion(match):
        warped_b, _ = warp_image(b.image, small.transform, a.image.shape[:2])
        written["overlay"] = out / "overlay.png"
        write_bytes_atomic(written["overlay"], encode_png(blend(a.image, warped_b, 0.5)))
    return written


def _reduced(points: np.ndarray, factor: int) -> np.ndarray:
    """Points (x, y) of a full image in the pixels of its copy reduced by ``factor``."""
    return (np.asarray(points, np.float64) + 0.5) / factor - 0.5
