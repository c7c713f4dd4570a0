"""The images' own similarity as evidence for a transform, where the support check finds no distinct peak.

Across stains and sensors fine structure differs, so the support check (:mod:`reglib.dense._confidence`)
often finds no distinct correlation peak for either of two estimates; the similarity of the images
at the right transform still stays higher than at a wrong one. :func:`local_similarity` measures it
at given points (zero-mean NCC of a patch of a with b resampled through the transform, no search),
:func:`evidence_z` is the sign test that one transform makes the images more similar than another at
clearly more places (on patches that do not overlap), and :func:`evidence_over_no_motion` rates an
answer against no motion at all. Coordinates are (x, y) pixels, x the column.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from .._transforms import KernelWarp
from ._fields import _as_fields, _downscaled
from ._flow import remap_planes, sample_positions
from ._options import DenseOptions

__all__ = ["EVIDENCE_Z", "evidence_over_no_motion", "evidence_z", "local_similarity"]

EVIDENCE_PATCH = 12  # half-size of the patches of the similarity evidence (working px)
# a sign test's z at least (patches that do not overlap) for one estimate to be more similar than another at
# clearly more places (one-sided p about 3e-5): between what a right dense estimate reaches across stains and
# what a wrong one reaches across sensors
EVIDENCE_Z = 4.0


def local_similarity(field_a: np.ndarray, field_b: np.ndarray, transform: KernelWarp, points: np.ndarray,
                     half_patch: int) -> np.ndarray:
    """(G,) float64: at each point (x, y) of a, the zero-mean NCC of a's (2 h + 1)^2 patch with b's resampled
    through ``transform`` there (no search; over C channels, the mean of each channel's NCC); NaN where the patch
    leaves a or is mapped outside b, or either patch is flat.

    The evidence of a transform that needs no distinct peak: where fine structure differs between the images
    (across stains) the check finds none, yet the similarity at the right place stays higher than at a wrong
    one. Trusted input: (H, W, C) float32 fields, ``transform`` in their pixels; does not validate.
    """
    h, w = field_a.shape[:2]
    out = np.full(len(points), np.nan)
    if not len(points):
        return out
    warped, valid = remap_planes(field_b, sample_positions(transform, (h, w)))
    k = (2 * half_patch + 1, 2 * half_patch + 1)
    ix, iy = np.rint(points[:, 0]).astype(np.intp), np.rint(points[:, 1]).astype(np.intp)
    inside = (ix >= half_patch) & (ix < w - half_patch) & (iy >= half_patch) & (iy < h - half_patch)
    ix, iy = np.clip(ix, 0, w - 1), np.clip(iy, 0, h - 1)
    cover = cv2.boxFilter(valid.astype(np.float32), cv2.CV_32F, k, normalize=True)[iy, ix]
    inside &= cover > 0.999
    total, n = np.zeros(len(points)), np.zeros(len(points))
    for c in range(field_a.shape[2]):
        x, y = np.ascontiguousarray(field_a[:, :, c]), warped[c]
        mx, my = cv2.boxFilter(x, cv2.CV_32F, k)[iy, ix], cv2.boxFilter(y, cv2.CV_32F, k)[iy, ix]
        vx = cv2.boxFilter(x * x, cv2.CV_32F, k)[iy, ix] - mx * mx
        vy = cv2.boxFilter(y * y, cv2.CV_32F, k)[iy, ix] - my * my
        cxy = cv2.boxFilter(x * y, cv2.CV_32F, k)[iy, ix] - mx * my
        ok = (vx > 1e-8) & (vy > 1e-8)
        total[ok] += cxy[ok] / np.sqrt(vx[ok] * vy[ok])
        n[ok] += 1
    good = inside & (n > 0)
    out[good] = total[good] / n[good]
    return out


def evidence_z(field_a: np.ndarray, field_b: np.ndarray, better: KernelWarp, worse: KernelWarp, step: int) -> float:
    """The sign test's z that ``better`` makes the fields more similar than ``worse`` does (both in their pixels).

    On a grid of a whose patches do not overlap (spacing the larger of ``step`` and the patch, 2 * 12 + 1 px,
    offset by half of it, so that the points are about independent samples), the local similarity
    (:func:`local_similarity`) at both transforms; z = (wins - n / 2) / sqrt(n / 4)
    over the n points where both are measured and differ (0.0 for none). Positive: ``better`` is more similar
    at more points. Trusted input: (H, W, C) float32 fields with the same C; does not validate.
    """
    h, w = field_a.shape[:2]
    spacing = max(int(step), 2 * EVIDENCE_PATCH + 1)
    ys, xs = np.mgrid[spacing // 2:h:spacing, spacing // 2:w:spacing]
    points = np.c_[xs.ravel(), ys.ravel()].astype(np.float64)
    s1 = local_similarity(field_a, field_b, better, points, EVIDENCE_PATCH)
    s2 = local_similarity(field_a, field_b, worse, points, EVIDENCE_PATCH)
    both = np.isfinite(s1) & np.isfinite(s2) & (s1 != s2)
    n = int(np.count_nonzero(both))
    if not n:
        return 0.0
    wins = int(np.count_nonzero(s1[both] > s2[both]))
    return float((wins - n / 2.0) / math.sqrt(n / 4.0))


def evidence_over_no_motion(image_a: np.ndarray, image_b: np.ndarray, transform: KernelWarp,
                            options: DenseOptions) -> float:
    """How clearly the images themselves rate ``transform`` (a -> b, original pixels) over no motion at all.

    :func:`evidence_z` of ``transform`` over the identity on the working copies of ``options.max_side``:
    at most -4 (``-EVIDENCE_Z``), the identity makes the images more similar at clearly more places
    (the answer is worse than no motion); at least 4, ``transform`` clearly better. ``image_a``,
    ``image_b``: what the dense stage correlates ((H, W) grey or (H, W, C) fields, the same C); trusted input
    otherwise.
    """
    fa, fb = _as_fields(image_a, image_b)
    sa = min(1.0, options.max_side / max(fa.shape[:2]))
    sb = min(1.0, options.max_side / max(fb.shape[:2]))
    ga, _ = _downscaled(fa, None, sa)
    gb, _ = _downscaled(fb, None, sb)
    none = KernelWarp.identity(2)
    return evidence_z(ga, gb, transform.rescaled(sa, sb), none.rescaled(sa, sb), options.step)
