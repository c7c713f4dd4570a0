"""Support of a transform by the images: the check, the per-pixel confidence map and its summary.

A grid point of a supports a transform f when its patch, searched for within 3 px of f(p) in b,
is found there (a distinct correlation peak of at least 0.6) within 1 px of f(p).
:func:`check_support` runs that search, :func:`supported` reads it, :func:`confidence_map`
spreads it over a's pixels and :func:`confidence_summary` is the match JSON's summary of the
map. Coordinates are (x, y) pixels, x the column; maps are (H_a, W_a) indexed [row, col].
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from .._transforms import KernelWarp
from ._correlation import GridSearch, SearchSpec, Thresholds, search_grid
from ._evidence import EVIDENCE_PATCH, _working_copies
from ._fields import _as_fields, _downscaled
from ._flow import sample_positions
from ._options import DenseOptions

__all__ = ["AWAY_PX", "FIND_RADIUS", "MAX_FOUND_AWAY", "check_support", "confidence_map", "confidence_summary",
           "found_away", "supported"]

CHECK_RADIUS = 3  # search radius of the support check, px
SUPPORTED_PX = 1.0  # a check match within this of the transform (working px) supports it
CHECK_NCC = 0.6  # ... and correlating at least this well
SHARPNESS = 0.2  # the check's peak must stand out (relative drop 2 px away, see Thresholds) by this much
# found_away: a's places searched within FIND_RADIUS working px of an answer; a distinct peak more than AWAY_PX from
# it is the images' own match elsewhere. An answer that leaves a bent part of the field out is found away at the
# places there; a right one only at a few places of repetitive texture or of depth. MAX_FOUND_AWAY lies between the
# share of the training answers of the wider generator within 3 px and that of the one retry there that was wrong
# (benchmarks/README.md, issue 50)
FIND_RADIUS = 12
AWAY_PX = 3.0
MAX_FOUND_AWAY = 0.12


def check_support(field_a: np.ndarray, field_b: np.ndarray, transform: KernelWarp, step: int, half_patch: int,
                  mask_a: np.ndarray | None = None, min_std: float | None = None,
                  std: np.ndarray | None = None, radius: int = CHECK_RADIUS) -> GridSearch:
    """The support check's search: every ``step`` px of a, within ``radius`` px (3) of ``transform``, distinct
    peaks only.

    Trusted input, does not validate: (H, W, C) float32 fields with the same C, ``transform``
    in their pixels. ``min_std`` and ``std`` as :class:`~reglib.dense._correlation.Thresholds` and
    :func:`~reglib.dense._correlation.search_grid` take them. ``radius``: :func:`found_away` searches further.
    """
    spec = SearchSpec(step=step, radius=radius, half_patch=half_patch,
                      thresholds=Thresholds(min_ncc=CHECK_NCC, min_std=min_std, min_sharpness=SHARPNESS))
    return search_grid(field_a, field_b, transform, spec, mask_a=mask_a, std=std)


def found_away(field_a: np.ndarray, field_b: np.ndarray, transform: KernelWarp, options: DenseOptions) -> float:
    """The share of a's places whose own match is found away from ``transform``: on a grid of the working copies
    of ``options.max_side`` whose patches (2 * 12 + 1 px) do not overlap, as the evidence's, each patch searched
    within :data:`FIND_RADIUS` working px of ``transform`` (a -> b, original pixels) for a distinct peak (the
    support check's thresholds), the peaks more than :data:`AWAY_PX` from it, of those found (0.0 for none).

    A sharper test than the local similarity's neighbours (:func:`~reglib.dense.rate_over_no_motion`) of an
    answer that misses a steep part of the field: 4 px beside an answer 10 px off, the similarity is often no
    higher than at the answer, while the search reaches the right place. ``field_a``, ``field_b``: what the dense
    stage correlates ((H, W) grey or (H, W, C) fields, the same C); trusted input otherwise.
    """
    ga, gb, answer, _ = _working_copies(field_a, field_b, transform, options)
    s = check_support(ga, gb, answer, max(int(options.step), 2 * EVIDENCE_PATCH + 1), EVIDENCE_PATCH,
                      radius=FIND_RADIUS)
    found = int(np.count_nonzero(s.found))
    away = int(np.count_nonzero(s.found & (np.linalg.norm(s.offset, axis=1) > AWAY_PX)))
    return away / found if found else 0.0


def supported(s: GridSearch, around: KernelWarp, transform: KernelWarp) -> np.ndarray:
    """(G,) bool: the grid point's match (searched around ``around``) is distinct and lands within 1 px of
    ``transform``. Trusted input: does not validate."""
    if not len(s.grid):
        return np.zeros(0, bool)
    ok = s.found & (s.ncc >= CHECK_NCC) & (s.sharp >= SHARPNESS)
    if not ok.any():
        return ok
    dst = around(s.grid[ok] + s.offset[ok])
    near = np.linalg.norm(transform(s.grid[ok]) - dst, axis=1) <= SUPPORTED_PX
    out = np.zeros(len(s.grid), bool)
    out[np.flatnonzero(ok)[near]] = True
    return out


def support_map(s: GridSearch, support: np.ndarray, transform: KernelWarp, shape_b: tuple[int, int],
                shape_a: tuple[int, int], step: int) -> np.ndarray:
    """Per pixel of a: the Gaussian-weighted share (sigma one grid step) of grid points supporting ``transform``.

    Every grid point of a counts in the denominator (untextured ones too: they support nothing),
    so an area the flow only extrapolates into has a low value; pixels mapped outside b get 0.
    (H_a, W_a) float32 in [0, 1]. Trusted input: does not validate.
    """
    h, w = shape_a
    gh, gw = max(1, math.ceil(h / step)), max(1, math.ceil(w / step))
    num = np.zeros((gh, gw), np.float32)
    if len(s.grid):
        gi = np.clip((s.grid[support, 1] // step).astype(np.intp), 0, gh - 1)
        gj = np.clip((s.grid[support, 0] // step).astype(np.intp), 0, gw - 1)
        np.add.at(num, (gi, gj), 1.0)
    num = np.minimum(num, 1.0)
    # a normalized Gaussian: a fully supported neighbourhood reads 1 (the blur of an all-ones grid is 1)
    blur = cv2.GaussianBlur(num, (0, 0), 1.0, borderType=cv2.BORDER_REFLECT)
    conf = cv2.resize(blur, (w, h), interpolation=cv2.INTER_LINEAR)
    pos = sample_positions(transform, (h, w))
    hb, wb = shape_b
    inside = (pos[..., 0] >= 0) & (pos[..., 0] <= wb - 1) & (pos[..., 1] >= 0) & (pos[..., 1] <= hb - 1)
    conf = np.clip(conf, 0.0, 1.0)
    conf[~inside] = 0.0
    return conf.astype(np.float32)


def upsampled(small: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A map of a resized copy of a, back on a's (H, W) pixels (bilinear, clipped to [0, 1])."""
    return np.clip(cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR), 0.0, 1.0).astype(np.float32)


def confidence_map(image_a: np.ndarray, image_b: np.ndarray, transform: KernelWarp, *, step: int = 16,
                   half_patch: int = 5, mask_a: np.ndarray | None = None, max_side: int | None = None) -> np.ndarray:
    """How well ``transform`` is supported by the two images, per pixel of a: (H_a, W_a) float32 in [0, 1].

    On a grid of a (every ``step`` px), the patch of a is searched for within 3 px of
    ``transform(p)`` in b (normalized correlation, a distinct peak); a grid point supports the
    transform when the peak correlates at least 0.6 and lies within 1 px of it. The map is the
    Gaussian-weighted share of supporting grid points around each pixel (sigma one grid step):
    near 1 where the flow follows the image content, near 0 where it is only extrapolated
    (no texture, occluded, or mapped outside b, which is 0) or disagrees with what is there.

    Parameters
    ----------
    image_a, image_b : (H, W) or (H, W, C) ndarray
        Grey images or descriptor fields (see :func:`~reglib.dense.guided_matches`).
    transform : KernelWarp
        Maps a's pixels (x, y) into b.
    step, half_patch : int
        Grid spacing and patch half-size, pixels of the (possibly resized) copy.
    mask_a : (H_a, W_a) bool ndarray, optional
        Grid points outside it support nothing.
    max_side : int, optional
        Images with a longer side are checked on resized copies (the map is still (H_a, W_a)).

    Examples
    --------
    >>> import numpy as np
    >>> from skimage.data import camera
    >>> a = camera().astype(np.float32)
    >>> conf = confidence_map(a, a, KernelWarp.identity(2))
    >>> conf.shape, conf.dtype, float(np.median(conf)) > 0.5
    ((512, 512), dtype('float32'), True)
    """
    fa, fb = _as_fields(image_a, image_b)
    sa = 1.0 if max_side is None else min(1.0, max_side / max(fa.shape[:2]))
    sb = 1.0 if max_side is None else min(1.0, max_side / max(fb.shape[:2]))
    ga, ma = _downscaled(fa, mask_a, sa)
    gb, _ = _downscaled(fb, None, sb)
    g = transform.rescaled(sa, sb)
    s = check_support(ga, gb, g, step, half_patch, ma)
    small = support_map(s, supported(s, g, g), g, gb.shape[:2], ga.shape[:2], step)
    if sa >= 1.0:
        return small
    return upsampled(small, fa.shape[:2])


def confidence_summary(confidence: np.ndarray | None, transform: KernelWarp | None = None,
                       shape_b: tuple[int, int] | None = None) -> dict[str, float] | None:
    """The match JSON's summary of a confidence map (None for None).

    ``{"mean": ..., "supported_share": ..., "overlap": ...}``: the map's mean and its share of
    pixels >= 0.5 over the pixels of a that ``transform`` maps inside b (all of a when either
    ``transform`` or ``shape_b`` is not given), and that share of a's pixels (1.0 then).
    """
    if confidence is None:
        return None
    c = np.asarray(confidence, np.float32)
    inside = np.ones(c.shape, bool)
    if transform is not None and shape_b is not None and c.size:
        pos = sample_positions(transform, c.shape[:2])
        hb, wb = shape_b
        inside = (pos[..., 0] >= -0.5) & (pos[..., 0] <= wb - 0.5) & (pos[..., 1] >= -0.5) & (pos[..., 1] <= hb - 0.5)
    if not inside.any():
        return {"mean": 0.0, "supported_share": 0.0, "overlap": 0.0}
    v = c[inside].astype(np.float64)
    return {"mean": float(v.mean()), "supported_share": float(np.mean(v >= 0.5)), "overlap": float(inside.mean())}
