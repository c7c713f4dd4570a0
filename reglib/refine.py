"""Guided dense refinement: from a rough first estimate to a transform fitted to dense matches.

Image b is resampled through the current estimate, patches of a on a regular grid are matched to
it by normalized cross-correlation in a small window (:func:`guided_matches`), and the robust
estimator with a richer basis is fitted to those matches (:func:`refine_dense`). The images
correlated are either grey images (H, W) or multi-channel descriptor fields (H, W, C), e.g. a
modality-independent structure field for pairs from different sensors: the correlation is then
the mean over channels of each channel's zero-mean normalized correlation, so raw intensities are
never compared.

:func:`refine_dense` works coarse to fine over an image pyramid (a wide capture range at the
coarse levels, where a patch covers more of the scene and a pixel of search reaches further),
runs more rounds on a level while they still move the estimate, and sizes each round's search
window from how far the previous round moved it. Grid points are searched up to a's border (b is
resampled beyond a's frame), so the field is measured where the deformation is often largest
rather than extrapolated there, and the final fit's kernel keeps one width however many centres
the dense support allows. A guard then compares the dense estimate with
the first one on fresh image evidence: where the dense estimate is no longer supported but the
first one is, that evidence pins the final fit to the first estimate; if the result is still
supported less overall, the first estimate is kept. :func:`confidence_map` says, per pixel of a,
how well a transform is supported by the images there (ALGORITHMS.md section 6).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np

from ._parallel import run_both, split_range
from .dense import remap_image, remap_planes, sample_positions
from .errors import InputError
from .match_options import MatchOptions
from .robust import L2EOptions, filter_matches
from .transforms import KernelWarp

__all__ = [
    "DENSE_L2E",
    "DENSE_VFC",
    "DenseResult",
    "confidence_map",
    "confidence_summary",
    "guided_matches",
    "refine_dense",
]

# Options of the dense stage's estimator that differ from the sparse stage's (a richer basis).
# One layer: the dense stage's transform is the primary layer's in any case. Annealing from the
# identity (normalized units), not the locality-prior consensus start: that start is there to find
# a minority of true matches among random false ones, and the dense matches, searched around the
# current estimate, are mostly true; its neighbourhood statistics and candidate solves cost about a
# quarter of each dense fit. Measured on the synthetic families (seed 0 / seed 1 pairs): harder
# 0.454 -> 0.401 / 0.494 -> 0.433 px mean EPE, current 0.167 -> 0.167 / 0.355 -> 0.361.
DENSE_L2E: dict[str, Any] = {"max_centers": 150, "max_fit_points": 4000, "max_layers": 1, "start": "identity"}
DENSE_VFC: dict[str, Any] = {"n_centers": 60, "beta": 1.0, "linear": "affine"}

_MIN_MATCHES = 20  # fewer dense matches than this: the round (or level) gives no estimate
_MIN_LEVEL_SIDE = 64  # a pyramid level's shorter side, px, at least
_MAX_LEVELS = 3  # working resolution, 1/2 and 1/4
_MATCHES_PER_CENTER = 4.0  # dense matches per kernel centre at most, final level (the basis follows the support)
_COARSE_MATCHES_PER_CENTER = 6.0  # ... on a coarser level (a smaller basis: cheaper, and it need not resolve detail)
_FINAL_BETA = 1.8  # the final fit's kernel exp(-beta |u - c|^2) in normalized units (RMS radius 1): sigma ~0.5
_STILL = 0.3  # a round moving the estimate by less than this (median over the matches, level px) ends the level
_STILL_COARSE = 0.3  # ... on a coarser level (it only has to bring the estimate within the next level's reach)
_COARSE_STEP = 1.5  # coarser levels' grid spacing, relative to the finest level's (in scene units)
_COARSE_CENTERS = 0.5  # coarser levels' basis at most this share of the finest level's, per halving
_CHECK_RADIUS = 3  # search radius of the support check, px
_SUPPORTED_PX = 1.0  # a check match within this of the transform (working px) supports it
_CHECK_NCC = 0.6  # ... and correlating at least this well
_LOST_SHARE = 0.03  # the guard re-fits when f0 alone is supported at this share of its check's grid or more
_NEAR_RADIUS = 10  # search radius where the estimate barely moved (see _search's ``near``)
_SHARPNESS = 0.2  # the check's peak must stand out (relative drop 2 px away, see _search) by this much


# ------------------------------------------------------------------------------- correlation
def _as_field(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, C) -> float32 (H, W, C), contiguous."""
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise InputError(f"an image must be (H, W) or (H, W, C), got shape {img.shape}")
    if img.ndim == 2:
        img = img[:, :, None]
    return np.ascontiguousarray(img, dtype=np.float32)


def _as_fields(image_a: np.ndarray, image_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both as float32 (H, W, C) fields with the same C (an ``InputError`` otherwise)."""
    fa, fb = _as_field(image_a), _as_field(image_b)
    if fa.ndim != 3 or fb.ndim != 3 or fa.shape[2] != fb.shape[2]:
        raise InputError(f"`image_a` and `image_b` must be (H, W) images or (H, W, C) fields with the same C, "
                         f"got shapes {np.shape(image_a)} and {np.shape(image_b)}")
    return fa, fb


def _texture(field: np.ndarray, half_patch: int) -> np.ndarray:
    """Per pixel, the root mean over channels of the (2 h + 1)^2 patch variance."""
    k = (2 * half_patch + 1, 2 * half_patch + 1)
    var = np.zeros(field.shape[:2], np.float32)
    for c in range(field.shape[2]):
        ch = field[:, :, c]
        mean = cv2.boxFilter(ch, cv2.CV_32F, k, normalize=True)
        sq = cv2.boxFilter(ch * ch, cv2.CV_32F, k, normalize=True)
        var += np.maximum(sq - mean * mean, 0.0)
    return np.sqrt(var / field.shape[2])


def _texture_at(field: np.ndarray, half_patch: int, gy: np.ndarray, gx: np.ndarray) -> np.ndarray:
    """:func:`_texture` at the pixels (gx, gy) only (their patches inside the field), from the patches themselves:
    the same float32 means of x and x^2 (summed in float64, as OpenCV's box filter does), the same variance."""
    hp = int(half_patch)
    p = 2 * hp + 1
    dy, dx = np.mgrid[-hp:hp + 1, -hp:hp + 1]
    patches = field[gy[:, None, None] + dy, gx[:, None, None] + dx].reshape(len(gy), p * p, field.shape[2])
    mean = patches.mean(axis=1, dtype=np.float64).astype(np.float32)
    sq = (patches * patches).mean(axis=1, dtype=np.float64).astype(np.float32)
    var = np.maximum(sq - mean * mean, np.float32(0.0)).sum(axis=1, dtype=np.float32)
    return np.sqrt(var / np.float32(field.shape[2]))


def _default_min_std(field: np.ndarray) -> float:
    """2 grey levels for a grey image; for a descriptor field, 5 % of its channels' mean spread."""
    if field.shape[2] == 1:
        return 2.0
    return 0.05 * float(np.mean(field.reshape(-1, field.shape[2]).std(axis=0)))


@dataclass(frozen=True)
class _Search:
    """One grid search: every grid point tried, and what it found (level pixels)."""

    grid: np.ndarray  # (G, 2) grid points of a that were searched (textured, window inside b)
    found: np.ndarray  # (G,) bool: a peak inside the window, correlating at least min_ncc
    offset: np.ndarray  # (G, 2) the peak's offset from the estimate (warped-b frame), 0 where not found
    ncc: np.ndarray  # (G,) correlation at the peak (0 where not found)
    sharp: np.ndarray  # (G,) how far the peak stands out over its +-2 px neighbours, the smaller of x and y
    n_grid: int  # grid points considered at all (inside mask_a), textured or not


def _search(field_a: np.ndarray, field_b: np.ndarray, f0: KernelWarp, step: int, radius: int, half_patch: int,
            mask_a: np.ndarray | None, min_ncc: float, min_std: float | None, min_sharpness: float,
            std: np.ndarray | None = None, near: Callable[[np.ndarray], np.ndarray] | None = None) -> _Search:
    """Every grid point's patch of a searched for within ``radius`` of ``f0`` in b (see :class:`_Search`).

    ``near``: given the (G, 2) grid points, True where ``_NEAR_RADIUS`` suffices (the estimate
    barely moved there); those are searched within min(radius, _NEAR_RADIUS) only. OpenCV's
    correlation costs about twice as much per call beyond radius 10 (11 x 11 patches).
    """
    h, w = field_a.shape[:2]
    r, hp = int(radius), int(half_patch)
    none = _Search(np.zeros((0, 2)), np.zeros(0, bool), np.zeros((0, 2)), np.zeros(0), np.zeros(0), 0)
    if h <= 2 * hp or w <= 2 * hp:
        return none
    # b is resampled on a's frame grown by r on every side (f extrapolated there), so a grid point
    # only needs its patch inside a: the search window may reach past a's border into b, which
    # still shows that part of the scene (on a coarse level r + h px is a wide band of the image)
    pos = sample_positions(dataclasses.replace(f0, src_mean=f0.src_mean + r), (h + 2 * r, w + 2 * r))
    channels = field_a.shape[2]
    if channels == 1:
        warped, valid = remap_image(field_b[:, :, 0], pos, "linear")
    else:  # channel-first: each channel's window is then a slice of contiguous rows
        warped, valid = remap_planes(field_b, pos)
    ys = np.arange(hp, h - hp, step)
    xs = np.arange(hp, w - hp, step)
    grid_y, grid_x = np.meshgrid(ys, xs, indexing="ij")
    gy, gx = grid_y.ravel(), grid_x.ravel()
    if mask_a is not None:
        inside_a = mask_a[gy, gx]
        gy, gx = gy[inside_a], gx[inside_a]
    n_grid = len(gy)
    # the texture of a's patches: from a precomputed map when given, else at the grid points only
    texture = _texture_at(field_a, hp, gy, gx) if std is None else std[gy, gx]
    keep = texture >= (_default_min_std(field_a) if min_std is None else min_std)
    # the patch (and the 1 px its sub-pixel peak needs) must lie inside b at the estimate, and so
    # must it at the peak found (below); the rest of the window may not: near b's border the search
    # reaches as far inwards as elsewhere (rows and columns of the grown frame: a's + r)
    inval_sum = cv2.integral((~valid).astype(np.uint8))
    keep &= _invalid_in(inval_sum, gy + r, gx + r, hp + 1) == 0
    gy, gx = gy[keep], gx[keep]
    n = len(gy)
    found, offset = np.zeros(n, bool), np.zeros((n, 2))
    peaks, sharp = np.zeros(n), np.zeros(n)
    small = np.zeros(n, bool)
    if near is not None and r > _NEAR_RADIUS and n:
        small = np.asarray(near(np.c_[gx, gy].astype(np.float64)), bool)
    for rows, ri in ((np.flatnonzero(small), _NEAR_RADIUS), (np.flatnonzero(~small), r)):
        if len(rows):
            res = _window_peaks(field_a, warped, gy[rows], gx[rows], r, ri, hp, min_ncc, min_sharpness)
            found[rows], offset[rows], peaks[rows], sharp[rows] = res
    if n:  # a peak where the window reached past b's border compared a with b's replicated edge: no match
        outside = found & (_invalid_in(inval_sum, gy + r + np.rint(offset[:, 1]).astype(np.intp),
                                       gx + r + np.rint(offset[:, 0]).astype(np.intp), hp + 1) > 0)
        found &= ~outside
        offset[outside], peaks[outside], sharp[outside] = 0.0, 0.0, 0.0
    return _Search(np.c_[gx, gy].astype(np.float64), found, offset, peaks, sharp, n_grid)


def _window_peaks(field_a: np.ndarray, warped: np.ndarray, gy: np.ndarray, gx: np.ndarray, margin: int, r: int,
                  hp: int, min_ncc: float, min_sharpness: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                      np.ndarray]:
    """:func:`_peaks` of the grid points (gx, gy) of a searched within ``r`` in ``warped`` (b on a's frame grown
    by ``margin`` >= r on every side: grey (H, W) or channel-first (C, H, W))."""
    n, side, k = len(gy), 2 * r + 1, margin - r  # a window centred on (x, y) of a: on (x + margin, y + margin)
    maps = np.empty((n, side, side), np.float32)  # every point's correlation over the window
    if field_a.shape[2] == 1:
        match, ccoeff = cv2.matchTemplate, cv2.TM_CCOEFF_NORMED
        grey_a = field_a[:, :, 0]
        ys_l, xs_l = (gy + k).tolist(), (gx + k).tolist()
        ya_l, xa_l = gy.tolist(), gx.tolist()

        def grey_maps(lo: int, hi: int) -> None:
            for i in range(lo, hi):
                y, x, ya, xa = ys_l[i], xs_l[i], ya_l[i], xa_l[i]
                match(warped[y - hp:y + 2 * r + hp + 1, x - hp:x + 2 * r + hp + 1],
                      grey_a[ya - hp:ya + hp + 1, xa - hp:xa + hp + 1], ccoeff, result=maps[i])

        split_range(n, grey_maps)
    elif n:
        _multi_maps(field_a, warped[:, k:warped.shape[1] - k, k:warped.shape[2] - k], gy, gx, r, hp, maps)
    return _peaks(maps, min_ncc, min_sharpness)


def _invalid_in(inval_sum: np.ndarray, y: np.ndarray, x: np.ndarray, half: int) -> np.ndarray:
    """Invalid pixels in the (2 half + 1)^2 squares centred on (x, y), from the integral image of the invalid mask
    (centres clipped so that the squares stay inside the image)."""
    y = np.clip(y, half, inval_sum.shape[0] - 2 - half)
    x = np.clip(x, half, inval_sum.shape[1] - 2 - half)
    y0, y1, x0, x1 = y - half, y + half + 1, x - half, x + half + 1
    return inval_sum[y1, x1] - inval_sum[y0, x1] - inval_sum[y1, x0] + inval_sum[y0, x0]


def _peaks(maps: np.ndarray, min_ncc: float, min_sharpness: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                            np.ndarray]:
    """Peak of each (2 r + 1)^2 correlation map: found, sub-pixel offset from the centre, correlation, sharpness.

    A peak on the window's border, or below ``min_ncc``, is not found. Sharpness: the peak's drop to the
    larger correlation 2 px away in x and in y (the smaller of the two drops), divided by ``1.02 - peak``
    (a slowly varying texture correlating 0.99 drops less than a sharp one correlating 0.8); below
    ``min_sharpness``, not found. The sub-pixel offset is a parabola through the peak and its neighbours.
    """
    n, side, _ = maps.shape
    r, last = side // 2, side - 1
    if n == 0:
        return np.zeros(0, bool), np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    flat = maps.reshape(n, side * side)
    if np.isnan(flat).any():  # NaN correlations, if any, count as -1 (no copy when there are none)
        flat = np.where(np.isnan(flat), -1.0, flat).astype(maps.dtype)
    idx = flat.argmax(axis=1)
    iy, ix = np.divmod(idx, side)
    rows = np.arange(n)
    peak = flat[rows, idx].astype(np.float64)
    found = (peak >= min_ncc) & (iy > 0) & (ix > 0) & (iy < last) & (ix < last)

    def at(dy: int, dx: int) -> np.ndarray:
        return maps[rows, np.clip(iy + dy, 0, last), np.clip(ix + dx, 0, last)].astype(np.float64)

    drop = peak - np.maximum.reduce([at(0, -2), at(0, 2), at(-2, 0), at(2, 0)])
    sharp = drop / (1.02 - peak)
    found &= sharp >= min_sharpness
    left, right, up, down = at(0, -1), at(0, 1), at(-1, 0), at(1, 0)
    offset = np.zeros((n, 2))
    offset[:, 0] = ix - r + _parabolas(left, peak, right)
    offset[:, 1] = iy - r + _parabolas(up, peak, down)
    offset[~found] = 0.0
    return found, offset, np.where(found, peak, 0.0), np.where(found, sharp, 0.0)


def _parabolas(left: np.ndarray, centre: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Vertex of the parabola through three samples, clipped to +-0.5 (0 where it opens upwards)."""
    den = left - 2.0 * centre + right
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(den < 0.0, 0.5 * (left - right) / np.where(den < 0.0, den, -1.0), 0.0)
    return np.clip(v, -0.5, 0.5)


def _multi_maps(field_a: np.ndarray, planes_b: np.ndarray, gy: np.ndarray, gx: np.ndarray, r: int, hp: int,
                maps: np.ndarray) -> None:
    """:func:`_multi_ncc` of every grid point (x, y) of a against its window of the grown warped b, into ``maps``.

    ``planes_b``: the warped b, channel-first (C, H, W). The channels are sliced from channel-first
    arrays (rows contiguous: no copy per patch), and the
    channels flat in each template are found for all points at once."""
    channels = field_a.shape[2]
    planes_a = np.ascontiguousarray(field_a.transpose(2, 0, 1))
    p = 2 * hp + 1
    dy, dx = np.mgrid[-hp:hp + 1, -hp:hp + 1]
    # (n, C) template standard deviations, as np.std of each (p, p) float32 template
    tpl = field_a[gy[:, None, None] + dy, gx[:, None, None] + dx]  # (n, p, p, C)
    used = tpl.reshape(len(gy), p * p, channels).std(axis=1) >= 1e-6
    match, ccoeff = cv2.matchTemplate, cv2.TM_CCOEFF_NORMED
    ys_l, xs_l = gy.tolist(), gx.tolist()

    def part(lo: int, hi: int) -> None:
        res = np.empty(maps.shape[1:], np.float32)
        for i in range(lo, hi):
            y, x = ys_l[i], xs_l[i]
            total = maps[i]
            chans = np.flatnonzero(used[i]).tolist()
            if not chans:
                total[:] = 0.0
                continue
            for k, c in enumerate(chans):
                match(planes_b[c, y - hp:y + 2 * r + hp + 1, x - hp:x + 2 * r + hp + 1],
                      planes_a[c, y - hp:y + hp + 1, x - hp:x + hp + 1], ccoeff, result=total if k == 0 else res)
                if k:
                    total += res
            if len(chans) > 1:
                total /= len(chans)

    split_range(len(ys_l), part)


def _multi_ncc(template: np.ndarray, window: np.ndarray) -> np.ndarray:
    """Mean over channels of each channel's zero-mean NCC; channels flat in the template are left out."""
    total = None
    used = 0
    for c in range(template.shape[2]):
        tpl = np.ascontiguousarray(template[:, :, c])
        if float(tpl.std()) < 1e-6:
            continue
        res = cv2.matchTemplate(np.ascontiguousarray(window[:, :, c]), tpl, cv2.TM_CCOEFF_NORMED)
        total = res if total is None else total + res
        used += 1
    if total is None:
        size = window.shape[0] - template.shape[0] + 1
        return np.zeros((size, size), np.float32)
    return total / used


def _matched(s: _Search, f0: KernelWarp, mask_b: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    src = s.grid[s.found]
    dst = f0(src + s.offset[s.found]) if len(src) else np.zeros((0, 2))
    ncc = s.ncc[s.found]
    if mask_b is not None and len(src):
        hb, wb = mask_b.shape
        col_b = np.clip(np.round(dst[:, 0]).astype(np.intp), 0, wb - 1)
        row_b = np.clip(np.round(dst[:, 1]).astype(np.intp), 0, hb - 1)
        inside = mask_b[row_b, col_b]
        src, dst, ncc = src[inside], dst[inside], ncc[inside]
    return src, dst, ncc


def guided_matches(image_a: np.ndarray, image_b: np.ndarray, f0: KernelWarp, *, step: int = 8,
                   radius: int = 6, half_patch: int = 7, mask_a: np.ndarray | None = None,
                   mask_b: np.ndarray | None = None, min_ncc: float = 0.5, min_std: float | None = None,
                   min_sharpness: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense putative matches on a regular grid of a, searched near the first estimate ``f0``.

    Image b is first resampled into a's frame through ``f0`` (this removes the rotation, scale and
    bending that ``f0`` already explains), so each grid point of a only needs a small search for the
    residual shift: the peak of the normalized cross-correlation of a (2 h + 1)^2 patch of a within
    ``+-radius`` px of the warped b, refined to sub-pixel by a parabola through the peak. This is
    the guided dense sampling of the L2E paper's dense step (ALGORITHMS.md section 6) with a patch
    correlation instead of per-candidate SIFT descriptors: after the pre-warp, the two patches
    differ by a small shift and a photometric change, which zero-mean NCC absorbs, at a fraction
    of the cost. Every grid point whose patch lies inside a is searched (b is resampled beyond a's
    frame, so the window may reach past a's border); a peak counts only where the patch it matched
    lies inside b.

    Parameters
    ----------
    image_a, image_b : (H, W) or (H, W, C) float32 ndarray
        Grey images, or descriptor fields with C channels (both the same C), pixels (x, y), x the
        column. With C > 1 the correlation is the mean over channels of each channel's zero-mean
        NCC (channels flat in a patch of a are left out of that patch's mean).
    f0 : KernelWarp
        First estimate, a -> b.
    step : int
        Grid spacing in a, pixels.
    radius : int
        Search radius around f0(p), pixels of a's frame.
    half_patch : int
        Patch half-size h.
    mask_a, mask_b : (H, W) bool ndarray, optional
        Grid points outside ``mask_a``, and matches landing outside ``mask_b``, are dropped.
    min_ncc : float
        Correlation peak below this: no match.
    min_std : float, optional
        Patches of a whose standard deviation (root mean over channels) is below this (no texture)
        are skipped. Default: 2 grey levels for a grey image, 5 % of the field's mean channel
        spread for a multi-channel field.
    min_sharpness : float
        The peak's drop to the largest correlation 2 px away in x or y, divided by ``1.02 - peak``,
        must be at least this (0: no check). Rejects matches along straight edges and ramps, where
        the peak slides, and keeps smooth but two-dimensional texture.

    Returns
    -------
    src : (N, 2) float64 ndarray
        Grid points of a.
    dst : (N, 2) float64 ndarray
        Their matches in b.
    ncc : (N,) float64 ndarray
        Correlation at the peak.

    Examples
    --------
    >>> import numpy as np, cv2
    >>> from skimage.data import camera
    >>> a = camera().astype(np.float32)
    >>> b = cv2.warpAffine(a, np.float32([[1, 0, 2], [0, 1, 1]]), (512, 512))
    >>> src, dst, ncc = guided_matches(a, b, KernelWarp.identity(2), step=32)
    >>> np.round(np.median(dst - src, axis=0), 1)
    array([2., 1.])
    """
    fa, fb = _as_fields(image_a, image_b)
    s = _search(fa, fb, f0, step, radius, half_patch, mask_a, min_ncc, min_std, min_sharpness)
    return _matched(s, f0, mask_b)


# ----------------------------------------------------------------------------------- support
def _support(s: _Search, f0: KernelWarp, f: KernelWarp) -> np.ndarray:
    """(G,) bool: the grid point's match (searched around f0) is distinct and lands within _SUPPORTED_PX of f."""
    if not len(s.grid):
        return np.zeros(0, bool)
    ok = s.found & (s.ncc >= _CHECK_NCC) & (s.sharp >= _SHARPNESS)
    if not ok.any():
        return ok
    dst = f0(s.grid[ok] + s.offset[ok])
    near = np.linalg.norm(f(s.grid[ok]) - dst, axis=1) <= _SUPPORTED_PX
    out = np.zeros(len(s.grid), bool)
    out[np.flatnonzero(ok)[near]] = True
    return out


def _check(fa: np.ndarray, fb: np.ndarray, f: KernelWarp, step: int, half_patch: int,
           mask_a: np.ndarray | None, min_std: float | None = None, std: np.ndarray | None = None) -> _Search:
    return _search(fa, fb, f, step, _CHECK_RADIUS, half_patch, mask_a, _CHECK_NCC, min_std, _SHARPNESS, std)


def _support_map(s: _Search, supported: np.ndarray, f: KernelWarp, shape_b: tuple[int, int],
                 shape_a: tuple[int, int], step: int) -> np.ndarray:
    """Per pixel of a: the Gaussian-weighted share (sigma one grid step) of grid points supporting f.

    Every grid point of a counts in the denominator (untextured ones too: they support nothing),
    so an area the flow only extrapolates into has a low value; pixels mapped outside b get 0.
    """
    h, w = shape_a
    gh, gw = max(1, math.ceil(h / step)), max(1, math.ceil(w / step))
    num = np.zeros((gh, gw), np.float32)
    if len(s.grid):
        gi = np.clip((s.grid[supported, 1] // step).astype(np.intp), 0, gh - 1)
        gj = np.clip((s.grid[supported, 0] // step).astype(np.intp), 0, gw - 1)
        np.add.at(num, (gi, gj), 1.0)
    num = np.minimum(num, 1.0)
    blur = cv2.GaussianBlur(num, (0, 0), 1.0, borderType=cv2.BORDER_REFLECT)
    conf = cv2.resize(blur, (w, h), interpolation=cv2.INTER_LINEAR)
    # Normalize so that a fully supported neighbourhood reads 1 (the blur of an all-ones grid is 1).
    pos = sample_positions(f, (h, w))
    hb, wb = shape_b
    inside = (pos[..., 0] >= 0) & (pos[..., 0] <= wb - 1) & (pos[..., 1] >= 0) & (pos[..., 1] <= hb - 1)
    conf = np.clip(conf * (1.0 / _FULL_BLUR), 0.0, 1.0)
    conf[~inside] = 0.0
    return conf.astype(np.float32)


# The Gaussian-blurred share where every grid point supports: exactly 1 with a normalized kernel.
_FULL_BLUR = 1.0


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
        Grey images or descriptor fields (see :func:`guided_matches`).
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
    s = _check(ga, gb, g, step, half_patch, ma)
    small = _support_map(s, _support(s, g, g), g, gb.shape[:2], ga.shape[:2], step)
    if sa >= 1.0:
        return small
    return _upsampled(small, fa.shape[:2])


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


def _upsampled(small: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    return np.clip(cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR), 0.0, 1.0).astype(np.float32)


# ----------------------------------------------------------------------------- the dense stage
@dataclass(frozen=True, eq=False)
class DenseResult:
    """What :func:`refine_dense` found.

    Attributes
    ----------
    transform : KernelWarp
        The final estimate, a -> b, original pixels.
    converged : bool
        Whether its estimator converged.
    n_dense : int
        Dense matches it was fitted to (0 when the guard kept the first estimate).
    confidence : (H_a, W_a) float32 ndarray
        The support of ``transform`` as :func:`confidence_map` measures it, in [0, 1]; when the
        guard kept ``f0``, from its check of ``f0`` (every other grid point).
    rounds : int
        Rounds of guided matching run, over all pyramid levels.
    kept_first : bool
        True when the guard kept the first estimate ``f0`` (the dense one was supported less, or
        hardly at all: :func:`_keep_first`).
    """

    transform: KernelWarp
    converged: bool
    n_dense: int
    confidence: np.ndarray
    rounds: int
    kept_first: bool


def _dense_options(opts: MatchOptions, method: Literal["l2e", "vfc"], n: int, level: int = 0) -> dict[str, Any]:
    if opts.dense_filter is not None:
        return dict(opts.dense_filter)
    base = {**(DENSE_L2E if method == "l2e" else DENSE_VFC), **dict(opts.filter or {})}
    if method == "l2e" and "max_centers" not in (opts.filter or {}):
        # the basis follows the support: about one centre per _MATCHES_PER_CENTER dense matches, and a
        # coarser level (which cannot resolve the finest detail) a smaller one
        cap = base["max_centers"] * _COARSE_CENTERS ** level
        per_center = _MATCHES_PER_CENTER if level == 0 else _COARSE_MATCHES_PER_CENTER
        base["max_centers"] = int(max(15, min(cap, n / per_center)))
        if level == 0 and "beta" not in (opts.filter or {}):
            # the final fit's kernel width is fixed in the estimator's normalized units (it scales
            # beta by M / n_centers over its levels), however many centres the support allows:
            # a basis that narrows with the number of matches decays to the affine part within a
            # few of its widths from the matches, i.e. across any untextured area
            n_centers = int(base.get("n_centers", L2EOptions().n_centers))
            m_final = base["max_centers"] if base["max_centers"] >= 1.5 * n_centers else n_centers
            base["beta"] = _FINAL_BETA * n_centers / m_final
    return base


def _levels(shape_a: tuple[int, int], shape_b: tuple[int, int]) -> int:
    side = min(min(shape_a), min(shape_b))
    n = 1
    while n < _MAX_LEVELS and side / 2 ** n >= _MIN_LEVEL_SIDE:
        n += 1
    return n


def refine_dense(image_a: np.ndarray, image_b: np.ndarray, f0: KernelWarp, opts: MatchOptions,
                 method: Literal["l2e", "vfc"], rng: np.random.Generator, mask_a: np.ndarray | None = None,
                 mask_b: np.ndarray | None = None) -> DenseResult | None:
    """From the first estimate ``f0`` to a transform fitted to dense matches; None when it finds too little.

    Parameters
    ----------
    image_a, image_b : (H, W) or (H, W, C) ndarray
        What is correlated: grey images (any real dtype), or descriptor fields with C channels
        (float32, e.g. a modality-independent structure field) for pairs whose intensities
        cannot be compared. Same C in both.
    f0 : KernelWarp
        First estimate (the sparse stage's), a -> b, original pixels.
    opts : MatchOptions
        ``max_side``, ``dense_step``, ``dense_radius``, ``dense_rounds``, ``dense_patch``,
        ``filter`` / ``dense_filter``.
    method : {"l2e", "vfc"}
        Estimator of each round.
    rng : numpy.random.Generator
        Passed to the estimator.
    mask_a, mask_b : (H, W) bool ndarray, optional
        Grid points outside ``mask_a`` and matches outside ``mask_b`` are dropped.

    Returns
    -------
    DenseResult or None
        None when no level found enough dense matches (the caller keeps ``f0``).

    Notes
    -----
    Images larger than ``opts.max_side`` are matched on resized copies (the working resolution);
    matches are mapped back to original pixels exactly before each fit. On top of it, up to two
    coarser levels (1/2, 1/4; shorter side >= 64 px) are matched first with 1.5 times the grid
    spacing in scene units, so patches cover more and the search reaches further there.
    Every grid point whose patch lies inside a is searched, also within the search radius of a's
    border (b is resampled beyond a's frame; a match counts where its patch lies inside b).
    On each level at most ``opts.dense_rounds`` rounds run, fewer once a round moves the estimate
    by less than 0.3 level px (median over the matches). The first round of the coarsest
    level searches ``opts.dense_radius`` px; every later round searches 2 px beyond twice the
    previous round's 90th-percentile move (between 3 px and ``opts.dense_radius``); on the working
    level, grid points where the last round (or the coarser level's last) moved the estimate by at
    most 4 px search within 10 px at most (OpenCV's correlation costs about twice as much per call
    beyond radius 10; on coarser levels the same rule lost a strongly deformed pair). The final
    fit's basis follows the dense matches' support (one kernel centre per 4 matches at most,
    centres placed among the matches) at a fixed kernel width (beta 1.8 in the estimator's
    normalized units, whatever the number of centres: a kernel that narrowed with the basis
    would let the field fall back to its affine part across every untextured area). The guard
    then checks both the dense estimate and ``f0`` (:func:`confidence_map`'s test); check
    matches that support ``f0`` where the dense estimate is unsupported join the dense matches
    for one more fit (kept if, on every other grid point, it is supported at least as often as the
    dense estimate), and ``f0`` is kept if the result is still supported at fewer grid points
    than ``f0``, or at almost none (:func:`_keep_first`). The guard's check of ``f0`` runs beside
    the levels (it depends on ``f0`` alone).
    """
    fa, fb = _as_fields(image_a, image_b)
    sa = min(1.0, opts.max_side / max(fa.shape[:2]))
    sb = min(1.0, opts.max_side / max(fb.shape[:2]))
    ga, ma = _downscaled(fa, mask_a, sa)
    gb, mb = _downscaled(fb, mask_b, sb)
    n_levels = _levels(ga.shape[:2], gb.shape[:2])
    def texture_stats(field: np.ndarray) -> tuple[float, np.ndarray | None]:
        # a level's texture threshold (a whole-field statistic) and, for a grey field, its texture map
        # (cheaper once than at each search's grid points; a multi-channel field's is made at the grid
        # points only, a full map costs more there)
        return _default_min_std(field), (_texture(field, opts.dense_patch) if field.shape[2] == 1 else None)

    min_std0, std0 = texture_stats(ga)  # the working level's, shared with the guard's check of f0

    def levels() -> tuple[tuple[KernelWarp, bool, np.ndarray, np.ndarray] | None, tuple[_Search, KernelWarp] | None,
                          int]:
        f = f0
        fitted: tuple[KernelWarp, bool, np.ndarray, np.ndarray] | None = None
        last: tuple[_Search, KernelWarp] | None = None  # the finest level's last search, and what it searched around
        rounds = 0
        radius = opts.dense_radius
        moved_by: tuple[KernelWarp, KernelWarp] | None = None  # the last round's estimate before and after its fit
        for level in range(n_levels - 1, -1, -1):
            k = 2.0 ** -level
            la, lma = _downscaled(ga, ma, k) if level else (ga, ma)
            lb, lmb = _downscaled(gb, mb, k) if level else (gb, mb)
            step = opts.dense_step if not level else max(4, round(_COARSE_STEP * opts.dense_step * k))
            ka, kb = sa * k, sb * k
            min_std, std = texture_stats(la) if level else (min_std0, std0)  # once per level
            for _ in range(opts.dense_rounds):
                g = f.rescaled(ka, kb)
                near = None if moved_by is None or level else functools.partial(_barely_moved, *moved_by, ka, kb)
                search = _search(la, lb, g, step, radius, opts.dense_patch, lma, 0.5, min_std, 0.0, std, near)
                src, dst, _ = _matched(search, g, lmb)
                rounds += 1
                if len(src) < _MIN_MATCHES:
                    break
                src = (src + 0.5) / ka - 0.5
                dst = (dst + 0.5) / kb - 0.5
                res = filter_matches(src, dst, method=method, options=_dense_options(opts, method, len(src), level),
                                     rng=rng)
                if res.reason is not None or res.n_inliers < _MIN_MATCHES:
                    break
                moves = np.linalg.norm(res.transform(src) - f(src), axis=1) * kb
                moved, spread = float(np.median(moves)), float(np.percentile(moves, 90))
                moved_by = (f, res.transform)
                f = res.transform
                fitted = (f, res.converged, src, dst)
                last = (search, g) if level == 0 else None
                radius = int(min(opts.dense_radius, max(3, math.ceil(2.0 * spread + 2.0))))
                if moved < (_STILL if level == 0 else _STILL_COARSE):
                    break
            # the next level's pixels are half the size: the same uncertainty is twice as many of them
            radius = int(min(opts.dense_radius, max(3, 2 * radius - 2)))
        return fitted, last, rounds

    # The guard's check of f0 depends on f0 alone: it runs beside the levels (run_both; the
    # searches' calls release the GIL), its result unused when no level finds enough matches.
    g0 = f0.rescaled(sa, sb)
    check0, (fitted, last, rounds) = run_both(
        lambda: _check(ga, gb, g0, 2 * opts.dense_step, opts.dense_patch, ma, min_std0, std0), levels)
    if fitted is None:
        return None
    f_dense, converged, src, dst = fitted
    return _guarded(ga, gb, ma, mb, sa, sb, f0, f_dense, converged, src, dst, last, opts, method, rng, rounds,
                    fa.shape[:2], min_std0, std0, check0)


def _guarded(ga: np.ndarray, gb: np.ndarray, ma: np.ndarray | None, mb: np.ndarray | None, sa: float, sb: float,
             f0: KernelWarp, f_dense: KernelWarp, converged: bool, src: np.ndarray, dst: np.ndarray,
             last: tuple[_Search, KernelWarp] | None, opts: MatchOptions, method: Literal["l2e", "vfc"],
             rng: np.random.Generator, rounds: int, shape_a: tuple[int, int], min_std: float | None,
             std: np.ndarray | None = None, check0: _Search | None = None) -> DenseResult:
    """The guard: keep ``f0`` where (and if) the dense estimate is supported less than it.

    ``check0``: f0's check on every other grid point (which suffices to compare), when the caller
    has made it."""
    step, hp = opts.dense_step, opts.dense_patch
    g0, gd = f0.rescaled(sa, sb), f_dense.rescaled(sa, sb)
    if check0 is None:
        check0 = _check(ga, gb, g0, 2 * step, hp, ma, min_std, std)
    sup0 = _support(check0, g0, g0)
    if last is not None:  # the finest level's last round searched close to the dense estimate: its evidence
        checkd, around = last
        supd = _support(checkd, around, gd)
    else:
        checkd = _check(ga, gb, gd, step, hp, ma, min_std, std)
        supd = _support(checkd, gd, gd)
    final, final_converged, n_dense, check, sup, g = f_dense, converged, len(src), checkd, supd, gd
    # grid cells where f0 is supported and the dense estimate is not
    lost = sup0 & ~_cells_of(check0.grid, checkd.grid[supd], step)
    if lost.sum() >= max(3, _LOST_SHARE * len(check0.grid)):
        p, q, _ = _matched(_Search(check0.grid[lost], check0.found[lost], check0.offset[lost], check0.ncc[lost],
                                   check0.sharp[lost], int(lost.sum())), g0, mb)
        p = (p + 0.5) / sa - 0.5
        q = (q + 0.5) / sb - 0.5
        src2, dst2 = np.r_[src, p], np.r_[dst, q]
        res = filter_matches(src2, dst2, method=method, options=_dense_options(opts, method, len(src2)), rng=rng)
        if res.reason is None and res.n_inliers >= _MIN_MATCHES:
            # the re-fit is checked on f0's lattice (every other grid point) and compared with the
            # dense estimate's support there; which cells only one of them supports (below) only
            # ever involves those points. The whole grid is checked only for a re-fit that is kept
            # to the end (its confidence map).
            g2 = res.transform.rescaled(sa, sb)
            check2 = _check(ga, gb, g2, 2 * step, hp, ma, min_std, std)
            sup2 = _support(check2, g2, g2)
            if sup2.sum() >= supd[_on_lattice(checkd.grid, 2 * step, hp)].sum():
                final, final_converged, n_dense = res.transform, res.converged, len(src2)
                check, sup, g = check2, sup2, g2
    # f0 is kept when it is supported at clearly more grid cells than the final estimate (cells both searched)
    both = _cells_of(check0.grid, check.grid, step)
    only0 = int(np.count_nonzero(sup0 & both & ~_cells_of(check0.grid, check.grid[sup], step)))
    only_final = int(np.count_nonzero(sup & _cells_of(check.grid, check0.grid, step)
                                      & ~_cells_of(check.grid, check0.grid[sup0], step)))
    kept_first = _keep_first(only0, only_final, int(np.count_nonzero(sup)), len(check0.grid), len(check.grid))
    map_step = step
    if kept_first:  # the confidence map then shows the evidence f0 was judged by: its check, every other grid point
        check, sup, map_step = check0, sup0, 2 * step
        final, final_converged, n_dense, g = f0, converged, 0, g0
    elif final is not f_dense:  # the re-fit, checked on the whole grid for its map
        check = _check(ga, gb, g, step, hp, ma, min_std, std)
        sup = _support(check, g, g)
    conf = _support_map(check, sup, g, gb.shape[:2], ga.shape[:2], map_step)
    if sa < 1.0:
        conf = _upsampled(conf, shape_a)
    return DenseResult(transform=final, converged=bool(final_converged), n_dense=int(n_dense), confidence=conf,
                       rounds=rounds, kept_first=kept_first)


def _on_lattice(grid: np.ndarray, spacing: int, half_patch: int) -> np.ndarray:
    """(G,) bool: the grid points (x, y) that lie on the lattice of ``spacing`` a search's grid starts at half_patch."""
    return ((grid[:, 0] - half_patch) % spacing == 0) & ((grid[:, 1] - half_patch) % spacing == 0)


def _barely_moved(before: KernelWarp, after: KernelWarp, ka: float, kb: float, points: np.ndarray) -> np.ndarray:
    """(G,) bool: the last round moved the estimate at these grid points (a level's px, scales ``ka`` of a and
    ``kb`` of b) by at most (_NEAR_RADIUS - 2) / 2 of that level's px.

    The round's radius rule (2 px beyond twice the move; the next level, twice that less 2 px,
    in pixels half the size) asks no more than ``_NEAR_RADIUS`` there."""
    q = (points + 0.5) / ka - 0.5
    move = np.linalg.norm(after(q) - before(q), axis=1) * kb
    return move <= (_NEAR_RADIUS - 2) / 2.0


def _keep_first(only_first: int, only_final: int, n_supported: int, n_check_first: int, n_check: int) -> bool:
    """The guard's decision: keep the sparse estimate f0 rather than the dense stage's final one?

    Yes when f0 is supported at clearly more grid cells than the final estimate (``only_first``
    against ``only_final``: cells where only one of them is, both searched; margin max(3, 3 % of
    f0's check grid of ``n_check_first`` points)), and yes when the final estimate is supported at
    fewer than max(3, _LOST_SHARE of its ``n_check`` grid points): then nothing the images show
    backs it over f0, which the sparse stage's inliers back (across sensors the check often finds
    no support for either; the dense fit then rests on its own weak matches alone).
    """
    if n_supported < max(3, _LOST_SHARE * n_check):
        return True
    return only_first > only_final + max(3, 0.03 * n_check_first)


def _cells_of(points: np.ndarray, marked: np.ndarray, step: int) -> np.ndarray:
    """(len(points),) bool: the grid cell (floor(x / step), floor(y / step)) of each point holds a marked point."""
    if not len(points) or not len(marked):
        return np.zeros(len(points), bool)
    def key(p: np.ndarray) -> np.ndarray:
        return (p[:, 1] // step).astype(np.int64) * 1_000_003 + (p[:, 0] // step).astype(np.int64)

    return np.isin(key(points), key(marked))


def _downscaled(image: np.ndarray, mask: np.ndarray | None, s: float) -> tuple[np.ndarray, np.ndarray | None]:
    """float32 copy resized by exactly ``s`` (OpenCV half-pixel centres), and the mask likewise."""
    g = _as_field(image)
    if s >= 1.0:
        return g, mask
    small = _area_resized(g, s)
    m = None
    if mask is not None:
        m = cv2.resize(mask.astype(np.uint8), (small.shape[1], small.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    return small, m


def _area_resized(field: np.ndarray, s: float) -> np.ndarray:
    """(H, W, C) float32 field resized by ``s`` with OpenCV's area interpolation, any C.

    OpenCV's area resampling takes at most 4 channels at a scale that is not 1 / integer (a
    structure field has 9): the channels, each resampled on its own anyway, go 4 at a time."""
    parts = []
    for c in range(0, field.shape[2], 4):
        part = cv2.resize(np.ascontiguousarray(field[:, :, c:c + 4]), (0, 0), fx=s, fy=s, interpolation=cv2.INTER_AREA)
        parts.append(part.reshape(part.shape[0], part.shape[1], -1))
    return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=2)
