"""Dense structure fields (CFOG) and the refinement of cross-modal matches by correlating them.

A structure field replaces an image's intensities by oriented-gradient channels that do not
depend on its contrast, brightness or polarity (CFOG [1]_): the zero-mean normalized correlation
of two such fields is meaningful across sensors, where that of the intensities is not. It serves
the dense stage of the multimodal path (correlated in place of grey levels) and
:func:`refine_matches`, which moves the end in b of each putative descriptor match to where the
two fields correlate best.

Coordinates: (x, y) pixels, x the column, the centre of the top-left pixel (0, 0).

References
----------
.. [1] Y. Ye, L. Bruzzone, J. Shan, F. Bovolo, Q. Zhu, "Fast and Robust Matching for Multimodal
       Remote Sensing Image Registration", IEEE TGRS 57(11), 2019 (CFOG).
       :doi:`10.1109/TGRS.2019.2924684`
"""
from __future__ import annotations

import cv2
import numpy as np

from .._parallel import run_both
from .._validation import check_int
from ..errors import InputError
from ._normalize import NormalizedImage, _normalized, _working_copy
from ._peaks import parabola_vertex

__all__ = ["refine_matches", "structure_image"]


def structure_image(image: np.ndarray | NormalizedImage, *, n_orient: int = 9, sigma: float = 1.0) -> np.ndarray:
    """Dense modality-independent structure field: channels of oriented gradients (CFOG [1]_).

    Per pixel, the absolute gradient projected on ``n_orient`` directions over [0, pi) (absolute,
    so that a contrast reversal between modalities gives the same field), smoothed by a Gaussian
    of ``sigma`` pixels in the image plane and by [1, 2, 1] / 4 along the (cyclic) orientation
    axis, then divided by the pixel's channel-vector L2 norm plus a floor (5 % of the field's
    median norm) so that weak noise does not become unit-length structure.

    Normalization, for a dense stage: every pixel's vector has L2 norm at most 1 and about 1
    wherever there is structure; intensities are first stretched by
    :func:`~reglib.features.normalize_intensity`.
    The field does not depend on the image's contrast, brightness or polarity, so the zero-mean
    normalized correlation of two such fields over a window (subtract each channel's window mean,
    sum the products over the window and the channels, divide by the two root sums of squares)
    is meaningful across modalities, and is computed on the same pixel grid as ``image``.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) ndarray, or NormalizedImage
        Any real dtype; or its normalized copy (:class:`~reglib.features.NormalizedImage`).
    n_orient : int
        Orientation channels C (CFOG: 9, 20 degrees apart).
    sigma : float
        Spatial Gaussian smoothing, pixels.

    Returns
    -------
    (H, W, C) float32 ndarray

    Examples
    --------
    >>> from skimage.data import camera
    >>> f, g = structure_image(camera()), structure_image(255 - camera())
    >>> f.shape, bool(np.allclose(f, g, atol=1e-5))
    ((512, 512, 9), True)
    """
    if isinstance(image, NormalizedImage):
        gray = image.gray
    else:
        arr = np.asarray(image)
        if arr.ndim not in (2, 3) or arr.dtype.kind not in "biuf":
            raise InputError(f"`image` must be a real (H, W) or (H, W, 3) array, got shape {arr.shape} "
                             f"dtype {arr.dtype}")
        gray = _normalized(arr)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REFLECT) / 8.0
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REFLECT) / 8.0
    angles = np.arange(n_orient) * np.pi / n_orient
    field = np.empty(gray.shape + (n_orient,), np.float32)
    for o, t in enumerate(angles):
        ch = np.abs(np.float32(np.cos(t)) * gx + np.float32(np.sin(t)) * gy)
        field[:, :, o] = cv2.GaussianBlur(ch, (0, 0), sigma, borderType=cv2.BORDER_REFLECT) if sigma > 0 else ch
    field = 0.5 * field + 0.25 * (np.roll(field, 1, axis=2) + np.roll(field, -1, axis=2))
    norm = np.sqrt((field ** 2).sum(axis=2))
    floor = 0.05 * float(norm.mean()) + 1e-6
    field /= (norm + floor)[:, :, None]
    return field.astype(np.float32, copy=False)


def refine_matches(image_a: np.ndarray | NormalizedImage, image_b: np.ndarray | NormalizedImage, src: np.ndarray,
                   dst: np.ndarray, *, radius: int = 8, half_patch: int = 12,
                   max_side: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Move each ``dst`` to where b's structure field best correlates with a's around ``src``.

    Descriptor matches across modalities are often right to within a cell of the descriptor grid
    but not to a pixel: keypoints of two sensors do not repeat exactly. For each match, the
    (2 h + 1)^2 window of a's :func:`structure_image` around ``src`` is correlated (zero-mean
    normalized, over all channels) with b's at every integer shift within ``radius`` of ``dst``
    on working copies of longer side ``max_side``; the peak, refined by a parabola per axis, is
    the new ``dst``.

    Parameters
    ----------
    image_a, image_b : ndarray or NormalizedImage
        The two images, (H, W) or (H, W, 3), any real dtype, or their normalized copies.
    src, dst : (N, 2) array_like
        Putative matches, (x, y) pixels of a and of b (centre of the top-left pixel (0, 0)).
    radius : int
        Search radius, working pixels.
    half_patch : int
        Half-size h of the correlated windows, working pixels.
    max_side : int
        Longer side of the working copies (as in :func:`~reglib.features.detect_multimodal`).

    Returns
    -------
    dst : (N, 2) float64 ndarray
        Refined positions in b's pixels.
    score : (N,) float64 ndarray
        Peak correlation in [-1, 1] (-1 where a's window has no structure; ``dst`` is kept there).

    Notes
    -----
    The default ``radius`` of 8 working pixels covers the error of near-miss descriptor matches
    (about a descriptor cell); ``half_patch`` 12 gives 25 x 25 windows.
    """
    src_a, dst_a = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src_a.ndim != 2 or src_a.shape[1] != 2 or src_a.shape != dst_a.shape:
        raise InputError(f"`src` and `dst` must both be (N, 2), got {src_a.shape} and {dst_a.shape}")
    if not (np.all(np.isfinite(src_a)) and np.all(np.isfinite(dst_a))):
        raise InputError("`src` and `dst` must be finite")
    check_int("radius", radius, 1, 64)
    check_int("half_patch", half_patch, 2, 64)
    check_int("max_side", max_side, 32, 8192)
    n = len(src_a)
    if n == 0:
        return dst_a.copy(), np.zeros(0)
    wa, sxa, sya = _working_copy(_normalized(image_a), max_side)
    wb, sxb, syb = _working_copy(_normalized(image_b), max_side)
    fa, fb = run_both(lambda: structure_image(wa), lambda: structure_image(wb))
    h, r = half_patch, radius
    size = 2 * h + 1
    pad = h + r + 1
    fa_p = np.pad(fa, ((pad, pad), (pad, pad), (0, 0)))
    fb_p = np.pad(fb, ((pad, pad), (pad, pad), (0, 0)))
    n_px = float(size * size)
    # window statistics of b at every position: sum over channels of the centred sum of squares
    s1 = np.stack([cv2.boxFilter(fb_p[:, :, c], -1, (size, size), normalize=False,
                                 borderType=cv2.BORDER_CONSTANT) for c in range(fb.shape[2])], axis=2)
    s2 = cv2.boxFilter((fb_p ** 2).sum(axis=2), -1, (size, size), normalize=False, borderType=cv2.BORDER_CONSTANT)
    b_energy = np.sqrt(np.maximum(s2 - (s1 ** 2).sum(axis=2) / n_px, 0.0))
    pa = np.rint(np.stack([sxa * (src_a[:, 0] + 0.5) - 0.5, sya * (src_a[:, 1] + 0.5) - 0.5], 1)).astype(np.intp)
    qb = np.stack([sxb * (dst_a[:, 0] + 0.5) - 0.5, syb * (dst_a[:, 1] + 0.5) - 0.5], 1)
    qi = np.rint(qb).astype(np.intp)
    ha, wa_ = fa.shape[:2]
    hb, wb_ = fb.shape[:2]
    pa[:, 0] = np.clip(pa[:, 0], 0, wa_ - 1)
    pa[:, 1] = np.clip(pa[:, 1], 0, ha - 1)
    qi[:, 0] = np.clip(qi[:, 0], 0, wb_ - 1)
    qi[:, 1] = np.clip(qi[:, 1], 0, hb - 1)
    out = qb.copy()
    score = np.full(n, -1.0)
    n_ch = fa.shape[2]
    for i in range(n):  # one small correlation per match (not per pixel)
        ya, xa = pa[i, 1] + pad, pa[i, 0] + pad
        tpl = fa_p[ya - h:ya + h + 1, xa - h:xa + h + 1]
        tpl = tpl - tpl.mean(axis=(0, 1), keepdims=True)
        t_norm = float(np.sqrt((tpl ** 2).sum()))
        if t_norm < 1e-3:
            continue
        yb, xb = qi[i, 1] + pad, qi[i, 0] + pad
        win = fb_p[yb - h - r:yb + h + r + 1, xb - h - r:xb + h + r + 1]
        num = np.zeros((2 * r + 1, 2 * r + 1), np.float32)
        for c in range(0, n_ch, 3):
            num += cv2.matchTemplate(np.ascontiguousarray(win[:, :, c:c + 3]), np.ascontiguousarray(tpl[:, :, c:c + 3]),
                                     cv2.TM_CCORR)
        den = b_energy[yb - r:yb + r + 1, xb - r:xb + r + 1] * t_norm + 1e-6
        ncc = num / den
        iy, ix = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
        dx = dy = 0.0  # the parabola needs both neighbours inside the search window
        if 0 < ix < 2 * r:
            dx = float(parabola_vertex(ncc[iy, ix - 1], ncc[iy, ix], ncc[iy, ix + 1], min_curvature=1e-9))
        if 0 < iy < 2 * r:
            dy = float(parabola_vertex(ncc[iy - 1, ix], ncc[iy, ix], ncc[iy + 1, ix], min_curvature=1e-9))
        out[i, 0] = qi[i, 0] + ix - r + dx
        out[i, 1] = qi[i, 1] + iy - r + dy
        score[i] = float(ncc[iy, ix])
    res = np.empty_like(out)
    res[:, 0] = (out[:, 0] + 0.5) / sxb - 0.5
    res[:, 1] = (out[:, 1] + 0.5) / syb - 0.5
    return res, score

