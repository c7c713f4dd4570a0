"""The files of one match on disk: the layout of ``reglib match A B --out DIR`` and of batch jobs.

::

    DIR/transform.json   the transform (CONTRACTS.md JSON)
    DIR/flow.flo         forward flow a -> b, Middlebury .flo (or flow.mha, ... by ``flow_format``)
    DIR/confidence.png   with confidence=True: how well the flow is supported at each pixel of a (8-bit grey, 255 = 1.0)
    DIR/warped.png       b resampled into a's frame
    DIR/matches.png      a | b with inliers green, outliers red
    DIR/overlay.png      a blended with warped b
    DIR/match.json       the match result (CONTRACTS.md JSON), written LAST

An answer that did not converge (``match.converged`` False: do not use it without a look, and
``reason`` says why) gets ``transform.json``, ``matches.png`` and ``match.json`` only: no flow,
confidence, warped image or overlay. Those files carry the motion itself, and a pipeline that
picks up ``flow.flo`` or ``warped.png`` from a folder would use a motion nobody vouches for; the
matches picture shows the evidence the verdict read, and ``reglib apply`` makes the warp of
``transform.json`` on purpose. The service's page shows the same (see :func:`writes_motion`).

A pair of images over the pixel limit (TIFF files read at a working size, :func:`reglib.match_images`)
gets ``transform.json`` and ``match.json``, a tiled full-resolution ``warped.tif`` with ``warped``, and
``matches.png`` / ``overlay.png`` drawn at a reduced size; no flow (8 bytes a pixel: ``reglib apply``
writes it on request) and no confidence map (:mod:`reglib._large_outputs`).

Every file is written to a temporary file in DIR and moved into place with ``os.replace``, so a
reader never sees half a file; ``match.json`` existing means the folder is complete.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._large_outputs import is_large, save_large
from .dense import dense_flow, warp_image
from .errors import InputError
from .io import DEFAULT_MAX_PIXELS, FLOW_SUFFIXES, encode_png, read_image, write_bytes_atomic, write_flow
from .visualize import draw_matches, to_rgb_uint8
from .visualize import overlay as blend

if TYPE_CHECKING:  # pragma: no cover
    from .matching import ImageMatch

__all__ = ["FLOW_FORMATS", "MATCH_FILE", "save_match", "writes_motion"]

MATCH_FILE = "match.json"


def save_match(match: ImageMatch, out_dir: str | os.PathLike[str], *, image_a: Any = None, image_b: Any = None,
               flow: bool = True, warped: bool = True, pictures: bool = True,
               confidence: bool = True, flow_format: str = "flo",
               max_pixels: int = DEFAULT_MAX_PIXELS) -> dict[str, Path]:
    """Write a match's files into ``out_dir`` (created if needed); return {name: path} of what was written.

    Parameters
    ----------
    match : ImageMatch
        The result of :func:`reglib.match_images`.
    out_dir : path
        Target folder.
    image_a, image_b : ndarray, path or bytes, optional
        The matched images; needed for ``warped.png`` (b) and the pictures (a and b). Files that
        need a missing image are skipped.
    flow : bool
        Write the flow a -> b, ``flow.flo`` or as ``flow_format`` says.
    confidence : bool
        Write ``confidence.png`` beside ``flow.flo`` (with ``flow``) when the match carries a confidence map
        (``round(255 * confidence)``, (H_a, W_a) 8-bit grey).
    warped : bool
        Write ``warped.png``.
    pictures : bool
        Write ``matches.png`` and ``overlay.png``.
    flow_format : str
        The flow's file, one of :data:`FLOW_FORMATS`: ``"flo"`` (Middlebury), ``"npy"``, or an ITK
        displacement field (``"mha"``, ``"nrrd"``, ``"nii"``, ``"nii.gz"``; :func:`reglib.io.write_flow`).
    max_pixels : int
        A match whose image a or b is over this many pixels is a large pair: its images are given
        as paths to their files, ``warped`` writes a tiled full-resolution ``warped.tif``, the pictures
        are drawn at a reduced size, and no flow or confidence map is written (the module docstring).

    An answer that did not converge gets no flow, confidence, warped image or overlay, whatever the
    flags say (:func:`writes_motion`; the module docstring says why).

    Returns
    -------
    dict of str to Path
        Keys among "transform", "flow", "confidence", "warped", "matches", "overlay", "match".
    """
    if flow_format not in FLOW_FORMATS:
        raise InputError(f"`flow_format` must be one of {', '.join(FLOW_FORMATS)}, got {flow_format!r}")
    out = _folder(out_dir)
    if is_large(match, max_pixels):
        written = {"transform": _write_json(out / "transform.json", match.transform.to_dict())}
        written.update(save_large(match, out, image_a, image_b, warped=warped and writes_motion(match),
                                  pictures=pictures))
        written["match"] = _write_json(out / MATCH_FILE, match.to_dict())
        return written
    a, b = _images(match, image_a, image_b)
    written = {"transform": _write_json(out / "transform.json", match.transform.to_dict())}
    motion = writes_motion(match)
    if flow and motion:
        written["flow"] = _write_flow(out / f"flow.{flow_format}", match)
    if confidence and motion:
        written.update(_write_confidence(out / "confidence.png", match))
    written.update(_write_warped_and_pictures(out, match, a, b, warped=warped and motion, pictures=pictures,
                                              overlay=motion))
    written["match"] = _write_json(out / MATCH_FILE, match.to_dict())
    return written


FLOW_FORMATS: tuple[str, ...] = tuple(suffix[1:] for suffix in FLOW_SUFFIXES)
"""The files ``save_match`` writes a flow as (``flow.<format>``): :func:`reglib.io.write_flow`'s suffixes."""


def writes_motion(match: ImageMatch) -> bool:
    """Whether the files that carry a match's motion (flow, confidence, warped image, overlay) are written:
    only for an answer that converged. ``reglib match``, batch jobs and the service's page agree on it."""
    return bool(match.converged)


def _folder(out_dir: str | os.PathLike[str]) -> Path:
    """``out_dir``, created with its parents if needed; refused when it is a file."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"`out_dir` exists and is not a folder: {out}")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _images(match: ImageMatch, image_a: Any, image_b: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Images a and b read (None where not given), each refused unless of the size the match was made on."""
    a = None if image_a is None else read_image(image_a, name="image_a")
    b = None if image_b is None else read_image(image_b, name="image_b")
    for label, image, shape in (("image_a", a, match.shape_a), ("image_b", b, match.shape_b)):
        if image is not None and image.shape[:2] != tuple(shape):
            raise InputError(f"`{label}` has shape {image.shape[:2]}, the match was made on {tuple(shape)}")
    return a, b


def _write_flow(path: Path, match: ImageMatch) -> Path:
    """The forward flow a -> b over a's pixels, in the file ``path``'s suffix names."""
    write_flow(path, dense_flow(match.transform, match.shape_a))
    return path


def _write_confidence(path: Path, match: ImageMatch) -> dict[str, Path]:
    """{"confidence": path} of the confidence map as 8-bit grey (255 = 1.0); {} when the match carries none."""
    conf = getattr(match, "confidence", None)
    if conf is None:
        return {}
    grey = np.round(np.clip(np.asarray(conf, np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)
    return {"confidence": _write_png(path, grey)}


def _write_warped_and_pictures(out: Path, match: ImageMatch, a: np.ndarray | None, b: np.ndarray | None, *,
                               warped: bool, pictures: bool, overlay: bool) -> dict[str, Path]:
    """``warped.png`` (needs b), then ``matches.png`` and (with ``overlay``) ``overlay.png`` (need a and b), those
    asked for."""
    written: dict[str, Path] = {}
    if b is None:
        return written
    both = pictures and a is not None
    warped_b = None
    if warped or (both and overlay):  # b is warped only for a file that shows it
        warped_b, _ = warp_image(b, match.transform, match.shape_a)
    if warped and warped_b is not None:
        # 8- and 16-bit images are written as they are; PNG holds no other dtype
        keep = warped_b.dtype in (np.uint8, np.uint16) and (warped_b.ndim == 2 or warped_b.shape[2] in (3, 4))
        written["warped"] = _write_png(out / "warped.png", warped_b if keep else to_rgb_uint8(warped_b, "warped"))
    if both and a is not None:
        written["matches"] = _write_png(out / "matches.png", draw_matches(a, b, match))
        if overlay and warped_b is not None:
            written["overlay"] = _write_png(out / "overlay.png", blend(a, warped_b, 0.5))
    return written


def _write_png(path: Path, image: np.ndarray) -> Path:
    """``image`` as a PNG file at ``path``."""
    write_bytes_atomic(path, encode_png(image))
    return path


def _write_json(path: Path, body: Any) -> Path:
    """``body`` as a JSON file at ``path``."""
    write_bytes_atomic(path, json.dumps(body).encode("utf-8"))
    return path
