"""A start for the dense stage that needs no putatives: the motion the sparse fit left, found by dense optical flow.

Where a strong local deformation bends part of the image, the sparse fit can miss it entirely: its putatives there
are mostly wrong, and the few right ones read as outliers of the smooth field. The dense stage then searches that
part around a start far off, beyond its reach. Once b is warped onto a by the sparse fit ``f0``, what is left is
smooth and much smaller than the whole motion, and a coarse-to-fine optical flow (OpenCV's DIS, which needs no
putatives and no estimate) finds much of it over the whole image.

:func:`residual_start` composes that residual flow with ``f0``, samples the composed map on a grid of a and fits
it with the robust estimator (one layer, up to 150 kernel centres) into the form the dense stage takes as its
start. Grey images of one modality only: the flow compares intensities, after
b's grey levels are mapped onto a's by their histograms (a gain or a gamma between the images keeps the order of
the grey levels, which is all the mapping needs).
"""
from __future__ import annotations

from typing import cast

import cv2
import numpy as np

from .._transforms import KernelWarp
from ..robust import L2EOptions, fit_matches
from ._flow import dense_flow
from ._options import MIN_MATCHES, DenseOptions
from ._refine import working_frames

__all__ = ["residual_start"]

# DIS's "fast" preset and the sample grid: chosen on the wider generator's training seeds, over "ultrafast", "medium"
# and grids of 8, 24 and 32 px (benchmarks/README.md, issue 50).
_PRESET = cv2.DISOPTICAL_FLOW_PRESET_FAST
_GRID = 16  # spacing of the composed map's samples, working px (the dense stage's default grid)
# 150 centres rather than 300: the fit is most of the start's cost, and 300 did not clearly do better on training
_START_L2E = L2EOptions(max_centers=150, max_layers=1)


def residual_start(image_a: np.ndarray, image_b: np.ndarray, f0: KernelWarp, options: DenseOptions,
                   rng: np.random.Generator, mask_a: np.ndarray | None = None,
                   mask_b: np.ndarray | None = None) -> KernelWarp | None:
    """``f0`` composed with the optical flow between a and b warped onto a by ``f0``, as a kernel transform.

    Parameters
    ----------
    image_a, image_b : (H, W) or (H, W, 1) ndarray
        Grey images of one modality (values 0-255).
    f0 : KernelWarp
        The sparse fit, a -> b, original pixels.
    options : DenseOptions
        Its ``max_side`` sets the working resolution (the dense stage's).
    rng : numpy.random.Generator
        Passed to the estimator.
    mask_a, mask_b : (H, W) bool ndarray, optional
        Samples outside ``mask_a``, or mapped outside ``mask_b``, are dropped.

    Returns
    -------
    KernelWarp or None
        The composed map fitted on a grid of a (original pixels); None when too few samples are left or the
        estimator gives a reason. Trusted input: does not validate.
    """
    frames = working_frames(image_a, image_b, options, mask_a, mask_b)  # the dense stage's working copies
    sa, sb, ma, mb = frames.scale_a, frames.scale_b, frames.mask_a, frames.mask_b
    a8 = np.clip(frames.a[:, :, 0], 0, 255).astype(np.uint8)
    b8 = np.clip(frames.b[:, :, 0], 0, 255).astype(np.uint8)
    h, w = a8.shape
    flow0 = dense_flow(f0.rescaled(sa, sb), (h, w))
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    warped = cv2.remap(b8, xs + flow0[..., 0], ys + flow0[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    dis = cv2.DISOpticalFlow.create(_PRESET)
    dis.setUseMeanNormalization(True)
    # no initial flow: OpenCV's stubs do not admit None for the output argument that it accepts
    residual = np.asarray(dis.calc(a8, _histogram_matched(warped, a8), cast("cv2.typing.MatLike", None)))
    gy, gx = np.mgrid[_GRID // 2:h:_GRID, _GRID // 2:w:_GRID]
    q = np.stack([gx, gy], axis=-1) + residual[gy, gx]
    inside = (q[..., 0] >= 0) & (q[..., 0] <= w - 1) & (q[..., 1] >= 0) & (q[..., 1] <= h - 1)
    if ma is not None:
        inside &= ma[gy, gx]
    q32 = q.astype(np.float32)
    dst = q + cv2.remap(flow0, q32[..., 0], q32[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if mb is not None:
        d = np.rint(dst).astype(np.intp)
        hb, wb = mb.shape
        ok = (d[..., 0] >= 0) & (d[..., 0] < wb) & (d[..., 1] >= 0) & (d[..., 1] < hb)
        inside &= ok & mb[np.clip(d[..., 1], 0, hb - 1), np.clip(d[..., 0], 0, wb - 1)]
    if int(inside.sum()) < MIN_MATCHES:
        return None
    src = (np.stack([gx[inside], gy[inside]], axis=1).astype(np.float64) + 0.5) / sa - 0.5
    dst_o = (dst[inside].astype(np.float64) + 0.5) / sb - 0.5
    res = fit_matches(src, dst_o, method="l2e", options=_START_L2E, rng=rng)
    return res.transform if res.reason is None else None


def _histogram_matched(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """uint8 ``image`` with its grey levels mapped monotonically so that their distribution is ``reference``'s."""
    cdf = np.cumsum(np.bincount(image.ravel(), minlength=256)) / image.size
    ref_counts = np.cumsum(np.bincount(reference.ravel(), minlength=256))
    # each level goes to the reference's level at the same rank (ranks from counts: no sort of the pixels)
    rank = np.clip(np.ceil(cdf * reference.size).astype(np.int64), 1, reference.size)
    lut = np.searchsorted(ref_counts, rank, side="left").astype(np.uint8)
    return lut[image]
