"""Multi-channel correlation: the mean over channels of each channel's zero-mean NCC.

Descriptor fields (H, W, C), e.g. a modality-independent structure field for pairs from different
sensors, are correlated channel by channel with OpenCV's normalized correlation coefficient and
averaged, so raw intensities are never compared; channels flat in a patch of a are left out of that
patch's mean. :func:`multi_channel_maps` correlates many grid points at once (the grid search's
path); :func:`multi_channel_ncc` is its point-by-point reference.
"""
from __future__ import annotations

import cv2
import numpy as np

from .._parallel import split_range

__all__ = ["multi_channel_maps", "multi_channel_ncc"]


def multi_channel_maps(field_a: np.ndarray, planes_b: np.ndarray, gy: np.ndarray, gx: np.ndarray, r: int, hp: int,
                       maps: np.ndarray) -> None:
    """:func:`multi_channel_ncc` of every grid point (x, y) of a against its window in ``planes_b``, into ``maps``.

    ``planes_b``: the warped b, channel-first (C, H, W), where the window of a's point (x, y)
    starts at (x - hp, y - hp); ``maps``: (len(gy), 2 r + 1, 2 r + 1) float32. The channels are
    sliced from channel-first arrays (rows contiguous: no copy per patch), and the channels flat
    in each template are found for all points at once. Trusted input: does not validate."""
    channels = field_a.shape[2]
    planes_a = np.ascontiguousarray(field_a.transpose(2, 0, 1))
    p = 2 * hp + 1
    dy, dx = np.mgrid[-hp:hp + 1, -hp:hp + 1]
    # (n, C) template standard deviations, as np.std of each (p, p) float32 template
    tpl = field_a[gy[:, None, None] + dy, gx[:, None, None] + dx]  # (n, p, p, C)
    used = tpl.reshape(len(gy), p * p, channels).std(axis=1) >= 1e-6
    match, ccoeff = cv2.matchTemplate, cv2.TM_CCOEFF_NORMED
    ys_l, xs_l = gy.tolist(), gx.tolist()
    # the loop runs thousands of times a search: per-channel planes, window sides and the channel list of
    # the common case (every channel used) are looked up once, not sliced or built per point
    pa, pb = list(planes_a), list(planes_b)
    every = list(range(channels))
    all_used = used.all(axis=1).tolist()
    q = 2 * r + p

    def part(lo: int, hi: int) -> None:
        res = np.empty(maps.shape[1:], np.float32)
        for i in range(lo, hi):
            y0, x0 = ys_l[i] - hp, xs_l[i] - hp
            total = maps[i]
            chans = every if all_used[i] else np.flatnonzero(used[i]).tolist()
            if not chans:
                total[:] = 0.0
                continue
            y1, x1, ty, tx = y0 + q, x0 + q, y0 + p, x0 + p
            match(pb[chans[0]][y0:y1, x0:x1], pa[chans[0]][y0:ty, x0:tx], ccoeff, total)
            for c in chans[1:]:
                match(pb[c][y0:y1, x0:x1], pa[c][y0:ty, x0:tx], ccoeff, res)
                total += res
            if len(chans) > 1:
                total /= len(chans)

    split_range(len(ys_l), part)


def multi_channel_ncc(template: np.ndarray, window: np.ndarray) -> np.ndarray:
    """Mean over channels of each channel's zero-mean NCC; channels flat in the template are left out.

    ``template`` (p, p, C) and ``window`` (q, q, C) float32, q >= p; the map is (q - p + 1, q - p + 1)
    float32 (zeros when every channel of the template is flat). The reference, point by point, of
    :func:`multi_channel_maps`."""
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
