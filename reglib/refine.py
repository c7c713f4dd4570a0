"""Guided dense refinement: from a first estimate to a transform fitted to dense matches.

Image b is resampled through the first estimate, patches of a on a regular grid are matched to it
by normalized cross-correlation in a small window (:func:`guided_matches`), and the robust
estimator with a richer basis is fitted to those matches (:func:`refine_dense`), for a few rounds.
"""
from __future__ import annotations

from typing import Any, Literal

import cv2
import numpy as np

from .dense import remap_image, sample_positions
from .match_options import MatchOptions
from .robust import filter_matches
from .transforms import KernelWarp

__all__ = ["guided_matches", "refine_dense", "DENSE_L2E", "DENSE_VFC"]

# Options of the dense stage's estimator that differ from the sparse stage's (a richer basis).
DENSE_L2E: dict[str, Any] = {"max_centers": 100, "max_fit_points": 4000}
DENSE_VFC: dict[str, Any] = {"n_centers": 60, "beta": 1.0, "linear": "affine"}


def guided_matches(gray_a: np.ndarray, gray_b: np.ndarray, f0: KernelWarp, *, step: int = 8,
                   radius: int = 6, half_patch: int = 7, mask_a: np.ndarray | None = None,
                   mask_b: np.ndarray | None = None, min_ncc: float = 0.5,
                   min_std: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense putative matches on a regular grid of a, searched near the first estimate ``f0``.

    Image b is first resampled into a's frame through ``f0`` (this removes the rotation, scale and
    bending that ``f0`` already explains), so each grid point of a only needs a small search for the
    residual shift: the peak of the normalized cross-correlation of a (2 h + 1)^2 patch of a within
    ``+-radius`` px of the warped b, refined to sub-pixel by a parabola through the peak. This is
    the guided dense sampling of the L2E paper's dense step (ALGORITHMS.md section 6) with a patch
    correlation instead of per-candidate SIFT descriptors: after the pre-warp, the two patches
    differ by a small shift and a photometric change, which zero-mean NCC absorbs, at a fraction
    of the cost.

    Parameters
    ----------
    gray_a, gray_b : (H, W) float32 ndarray
        Grey images (pixels (x, y), x the column).
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
    min_std : float
        Patches of a with grey-level standard deviation below this (no texture) are skipped.

    Returns
    -------
    src : (N, 2) float64 ndarray
        Grid points of a.
    dst : (N, 2) float64 ndarray
        Their matches in b.
    ncc : (N,) float64 ndarray
        Correlation at the peak.
    """
    h, w = gray_a.shape
    pos = sample_positions(f0, (h, w))
    warped, valid = remap_image(gray_b, pos, "linear")
    r, hp = int(radius), int(half_patch)
    margin = r + hp
    empty = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    if h <= 2 * margin or w <= 2 * margin:
        return empty
    ys = np.arange(margin, h - margin, step)
    xs = np.arange(margin, w - margin, step)
    # texture: local standard deviation of a at every grid point (box filters)
    mean = cv2.boxFilter(gray_a, cv2.CV_32F, (2 * hp + 1, 2 * hp + 1), normalize=True)
    sq = cv2.boxFilter(gray_a * gray_a, cv2.CV_32F, (2 * hp + 1, 2 * hp + 1), normalize=True)
    std = np.sqrt(np.maximum(sq - mean * mean, 0.0))
    grid_y, grid_x = np.meshgrid(ys, xs, indexing="ij")
    gy, gx = grid_y.ravel(), grid_x.ravel()
    keep = std[gy, gx] >= min_std
    if mask_a is not None:
        keep &= mask_a[gy, gx]
    # the whole search window must lie inside b
    inval = (~valid).astype(np.uint8)
    inval_sum = cv2.integral(inval)
    y0, y1, x0, x1 = gy - margin, gy + margin + 1, gx - margin, gx + margin + 1
    n_bad = inval_sum[y1, x1] - inval_sum[y0, x1] - inval_sum[y1, x0] + inval_sum[y0, x0]
    keep &= n_bad == 0
    gy, gx = gy[keep], gx[keep]
    src_l, off_l, ncc_l = [], [], []
    last = 2 * r
    for y, x in zip(gy.tolist(), gx.tolist()):
        tpl = gray_a[y - hp:y + hp + 1, x - hp:x + hp + 1]
        win = warped[y - margin:y + margin + 1, x - margin:x + margin + 1]
        res = cv2.matchTemplate(win, tpl, cv2.TM_CCOEFF_NORMED)
        _, peak, _, (ix, iy) = cv2.minMaxLoc(res)
        if not peak >= min_ncc or iy == 0 or ix == 0 or iy == last or ix == last:
            continue
        dx = _parabola(float(res[iy, ix - 1]), peak, float(res[iy, ix + 1]))
        dy = _parabola(float(res[iy - 1, ix]), peak, float(res[iy + 1, ix]))
        src_l.append((x, y))
        off_l.append((ix - r + dx, iy - r + dy))
        ncc_l.append(peak)
    if not src_l:
        return empty
    src = np.asarray(src_l, np.float64)
    moved = src + np.asarray(off_l, np.float64)
    dst = f0(moved)
    ncc = np.asarray(ncc_l, np.float64)
    if mask_b is not None:
        hb, wb = mask_b.shape
        col_b = np.clip(np.round(dst[:, 0]).astype(np.intp), 0, wb - 1)
        row_b = np.clip(np.round(dst[:, 1]).astype(np.intp), 0, hb - 1)
        inside = mask_b[row_b, col_b]
        src, dst, ncc = src[inside], dst[inside], ncc[inside]
    return src, dst, ncc


def _parabola(left: float, centre: float, right: float) -> float:
    den = left - 2.0 * centre + right
    if den >= 0.0:
        return 0.0
    return min(0.5, max(-0.5, 0.5 * (left - right) / den))


def _dense_options(opts: MatchOptions, method: Literal["l2e", "vfc"]) -> dict[str, Any]:
    if opts.dense_filter is not None:
        return dict(opts.dense_filter)
    base = dict(opts.filter or {})
    return {**(DENSE_L2E if method == "l2e" else DENSE_VFC), **base}


def refine_dense(gray_a: np.ndarray, gray_b: np.ndarray, f0: KernelWarp, opts: MatchOptions,
                 method: Literal["l2e", "vfc"], rng: np.random.Generator, mask_a: np.ndarray | None,
                 mask_b: np.ndarray | None) -> tuple[KernelWarp, bool, int] | None:
    """Guided dense matching around ``f0`` and the final estimate; None when it finds too little.

    Images larger than ``opts.max_side`` are matched on resized copies; the matches are mapped
    back to the original pixels exactly before the estimate, so the answer is in original pixels.
    Returns the final transform, whether its estimator converged, and the number of dense matches.
    """
    sa = min(1.0, opts.max_side / max(gray_a.shape))
    sb = min(1.0, opts.max_side / max(gray_b.shape))
    ga, ma = _downscaled(gray_a, mask_a, sa)
    gb, mb = _downscaled(gray_b, mask_b, sb)
    current: tuple[KernelWarp, bool, int] | None = None
    f = f0
    for k in range(opts.dense_rounds):
        # later rounds start from a dense estimate: a smaller search window suffices
        radius = opts.dense_radius if k == 0 else max(3, opts.dense_radius // 2)
        src, dst, _ = guided_matches(ga, gb, f.rescaled(sa, sb), step=opts.dense_step, radius=radius,
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
