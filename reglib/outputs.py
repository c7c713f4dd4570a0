"""The files of one match on disk: the layout of ``reglib match A B --out DIR`` and of batch jobs.

::

    DIR/transform.json   the transform (CONTRACTS.md JSON)
    DIR/flow.flo         forward flow a -> b, Middlebury .flo
    DIR/confidence.png   with confidence=True: how well the flow is supported at each pixel of a (8-bit grey, 255 = 1.0)
    DIR/warped.png       b resampled into a's frame
    DIR/matches.png      a | b with inliers green, outliers red
    DIR/overlay.png      a blended with warped b
    DIR/match.json       the match result (CONTRACTS.md JSON), written LAST

Every file is written to a temporary file in DIR and moved into place with ``os.replace``, so a
reader never sees half a file; ``match.json`` existing means the folder is complete.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .dense import dense_flow, warp_image
from .errors import InputError
from .io import encode_png, read_image, write_bytes_atomic, write_flo
from .visualize import draw_matches, overlay, to_rgb_uint8

if TYPE_CHECKING:  # pragma: no cover
    from .matching import ImageMatch

__all__ = ["save_match", "MATCH_FILE"]

MATCH_FILE = "match.json"


def save_match(match: ImageMatch, out_dir: str | os.PathLike[str], *, image_a: Any = None, image_b: Any = None,
               flow: bool = True, warped: bool = True, pictures: bool = True,
               confidence: bool = True) -> dict[str, Path]:
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
        Write ``flow.flo``.
    confidence : bool
        Write ``confidence.png`` beside ``flow.flo`` (with ``flow``) when the match carries a confidence map
        (``round(255 * confidence)``, (H_a, W_a) 8-bit grey).
    warped : bool
        Write ``warped.png``.
    pictures : bool
        Write ``matches.png`` and ``overlay.png``.

    Returns
    -------
    dict of str to Path
        Keys among "transform", "flow", "confidence", "warped", "matches", "overlay", "match".
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"`out_dir` exists and is not a folder: {out}")
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    a = None if image_a is None else read_image(image_a, name="image_a")
    b = None if image_b is None else read_image(image_b, name="image_b")
    if a is not None and a.shape[:2] != tuple(match.shape_a):
        raise InputError(f"`image_a` has shape {a.shape[:2]}, the match was made on {tuple(match.shape_a)}")
    if b is not None and b.shape[:2] != tuple(match.shape_b):
        raise InputError(f"`image_b` has shape {b.shape[:2]}, the match was made on {tuple(match.shape_b)}")

    written["transform"] = _write_json(out / "transform.json", match.transform.to_dict())
    if flow:
        path = out / "flow.flo"
        write_flo(path, dense_flow(match.transform, match.shape_a))
        written["flow"] = path
    conf = getattr(match, "confidence", None)
    if confidence and conf is not None:
        path = out / "confidence.png"
        grey = np.round(np.clip(np.asarray(conf, np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)
        write_bytes_atomic(path, encode_png(grey))
        written["confidence"] = path
    warped_b = None
    if b is not None and (warped or (pictures and a is not None)):
        warped_b, _ = warp_image(b, match.transform, match.shape_a)
    if warped and warped_b is not None:
        path = out / "warped.png"
        img = warped_b if warped_b.dtype in (np.uint8, np.uint16) else to_rgb_uint8(warped_b, "warped")
        write_bytes_atomic(path, encode_png(img))
        written["warped"] = path
    if pictures and a is not None and b is not None:
        path = out / "matches.png"
        write_bytes_atomic(path, encode_png(draw_matches(a, b, match)))
        written["matches"] = path
        path = out / "overlay.png"
        write_bytes_atomic(path, encode_png(overlay(a, warped_b, 0.5)))
        written["overlay"] = path
    written["match"] = _write_json(out / MATCH_FILE, match.to_dict())
    return written


def _write_json(path: Path, body: Any) -> Path:
    write_bytes_atomic(path, json.dumps(body).encode("utf-8"))
    return path
