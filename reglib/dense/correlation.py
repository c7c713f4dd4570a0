"""The correlation search: patches of a on a regular grid found in b near a first estimate.

Image b is resampled into a's frame through the current estimate (this removes the rotation,
scale and bending the estimate already explains), so each grid point of a only needs a small
search for the residual shift: the peak of the zero-mean normalized cross-correlation (NCC) of a
(2 h + 1)^2 patch of a within ``radius`` px, refined to sub-pixel by a parabola. The images
correlated are grey images (H, W) or multi-channel descriptor fields (H, W, C), e.g. a
modality-independent structure field for pairs from different sensors: the correlation is then
the mean over channels of each channel's zero-mean NCC, so raw intensities are never compared.

:func:`search_grid` is the search itself (every grid point tried, :class:`GridSearch`);
:func:`guided_matches` its public form, the matches it found. Coordinates are (x, y) pixels, x
the column, the centre of the top-left pixel at (0, 0).

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of
       Transformation for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from .._parallel import split_range
from ..errors import InputError
from ..features.peaks import parabola_vertex
from ..transforms import KernelWarp
from .flow import remap_image, remap_planes, sample_positions

__all__ = ["GridSearch", "SearchSpec", "Thresholds", "area_resized", "guided_matches", "multi_channel_maps",
           "multi_channel_ncc", "on_lattice", "search_grid", "texture_at", "texture_map"]

_NEAR_RADIUS = 10  # search radius where the estimate barely moved (see search_grid's ``near``)


def _as_field(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, C) -> float32 (H, W, C), contiguous (an ``InputError`` for other shapes)."""
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


def texture_map(field: np.ndarray, half_patch: int) -> np.ndarray:
    """(H, W) float32: per pixel, the root mean over channels of the (2 h + 1)^2 patch variance.

    ``field`` is (H, W, C) float32, h = ``half_patch``. Trusted input: does not validate.
    """
    k = (2 * half_patch + 1, 2 * half_patch + 1)
    var = np.zeros(field.shape[:2], np.float32)
    for c in range(field.shape[2]):
        ch = field[:, :, c]
        mean = cv2.boxFilter(ch, cv2.CV_32F, k, normalize=True)
        sq = cv2.boxFilter(ch * ch, cv2.CV_32F, k, normalize=True)
        var += np.maximum(sq - mean * mean, 0.0)
    return np.sqrt(var / field.shape[2])


def texture_at(field: np.ndarray, half_patch: int, gy: np.ndarray, gx: np.ndarray) -> np.ndarray:
    """:func:`texture_map` at the pixels (gx, gy) only (their patches inside the field), from the patches themselves.

    The same float32 means of x and x^2 (summed in float64, as OpenCV's box filter does), the same
    variance. Trusted input: does not validate.
    """
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


@dataclass(frozen=True, slots=True, kw_only=True)
class Thresholds:
    """What a grid point's patch and its correlation peak must reach to give a match.

    Attributes
    ----------
    min_ncc : float
        Correlation peak below this: no match.
    min_std : float, optional
        Patches of a whose standard deviation (root mean over channels) is below this (no
        texture) are skipped. None: 2 grey levels for a grey image, 5 % of the field's mean
        channel spread for a multi-channel field.
    min_sharpness : float
        The peak's drop to the largest correlation 2 px away in x or y, divided by
        ``1.02 - peak``, must be at least this (0: no check). Rejects matches along straight
        edges and ramps, where the peak slides, and keeps smooth but two-dimensional texture.
    """

    min_ncc: float = 0.5
    min_std: float | None = None
    min_sharpness: float = 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SearchSpec:
    """One grid search: the grid of a, the window searched in b, and what counts as a match.

    Attributes
    ----------
    step : int
        Grid spacing in a, pixels; the grid starts at ``half_patch``.
    radius : int
        Search radius around the estimate, pixels of a's frame.
    half_patch : int
        Patch half-size h of the (2 h + 1)^2 patches correlated.
    thresholds : Thresholds
        What a patch and its peak must reach.
    """

    step: int = 8
    radius: int = 6
    half_patch: int = 7
    thresholds: Thresholds = field(default_factory=Thresholds)


@dataclass(frozen=True)
class GridSearch:
    """One grid search: every grid point tried, and what it found (pixels of the fields searched).

    Attributes
    ----------
    grid : (G, 2) float64 ndarray
        Grid points (x, y) of a that were searched (textured, their patch inside b at the estimate).
    found : (G,) bool ndarray
        A peak inside the window, passing the thresholds.
    offset : (G, 2) float64 ndarray
        The peak's offset from the estimate (in the warped-b frame), 0 where not found.
    ncc : (G,) float64 ndarray
        Correlation at the peak (0 where not found).
    sharp : (G,) float64 ndarray
        How far the peak stands out over its +-2 px neighbours, the smaller of x and y.
    n_grid : int
        Grid points considered at all (inside ``mask_a``), textured or not.
    """

    grid: np.ndarray
    found: np.ndarray
    offset: np.ndarray
    ncc: np.ndarray
    sharp: np.ndarray
    n_grid: int

    @classmethod
    def empty(cls) -> GridSearch:
        """No grid point (an image smaller than one patch)."""
        return cls(np.zeros((0, 2)), np.zeros(0, bool), np.zeros((0, 2)), np.zeros(0), np.zeros(0), 0)

    def where(self, keep: np.ndarray) -> GridSearch:
        """The grid points where ``keep`` (a (G,) bool mask) holds; ``n_grid`` their number."""
        return GridSearch(self.grid[keep], self.found[keep], self.offset[keep], self.ncc[keep], self.sharp[keep],
                          int(keep.sum()))


def search_grid(field_a: np.ndarray, field_b: np.ndarray, f0: KernelWarp, spec: SearchSpec, *,
                mask_a: np.ndarray | None = None, std: np.ndarray | None = None,
                near: Callable[[np.ndarray], np.ndarray] | None = None) -> GridSearch:
    """Every grid point's patch of a searched for within ``spec.radius`` of ``f0`` in b.

    Trusted input, does not validate: ``field_a``, ``field_b`` float32 (H, W, C) with the same C
    (:func:`guided_matches` is the validating form).

    Parameters
    ----------
    field_a, field_b : (H, W, C) float32 ndarray
        What is correlated.
    f0 : KernelWarp
        The estimate searched around, a -> b, pixels of the fields.
    spec : SearchSpec
        The grid, the window and the thresholds.
    mask_a : (H, W) bool ndarray, optional
        Grid points outside it are not searched.
    std : (H, W) float32 ndarray, optional
        :func:`texture_map` of ``field_a`` when the caller has it (else the texture is measured
        at the grid points only, :func:`texture_at`).
    near : callable, optional
        Given the (G, 2) grid points, True where 10 px suffice (the estimate barely
        moved there); those are searched within min(radius, 10) only. OpenCV's
        correlation costs more per call beyond radius 10 (11 x 11 windows).

    Returns
    -------
    GridSearch
    """
    h, w = field_a.shape[:2]
    step, r, hp = spec.step, int(spec.radius), int(spec.half_patch)
    thresholds = spec.thresholds
    if h <= 2 * hp or w <= 2 * hp:
        return GridSearch.empty()
    # b is resampled on a's frame grown by r on every side (f extrapolated there), so a grid point
    # only needs its patch inside a: the search window may reach past a's border into b, which
    # still shows that part of the scene (on a coarse level r + h px is a wide band of the image)
    pos = sample_positions(f0, (h, w), margin=r)
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
    texture = texture_at(field_a, hp, gy, gx) if std is None else std[gy, gx]
    keep = texture >= (_default_min_std(field_a) if thresholds.min_std is None else thresholds.min_std)
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
            res = _window_peaks(field_a, warped, _Window(gy[rows], gx[rows], r, ri, hp), thresholds)
            found[rows], offset[rows], peaks[rows], sharp[rows] = res
    if n:  # a peak where the window reached past b's border compared a with b's replicated edge: no match
        outside = found & (_invalid_in(inval_sum, gy + r + np.rint(offset[:, 1]).astype(np.intp),
                                       gx + r + np.rint(offset[:, 0]).astype(np.intp), hp + 1) > 0)
        found &= ~outside
        offset[outside], peaks[outside], sharp[outside] = 0.0, 0.0, 0.0
    return GridSearch(np.c_[gx, gy].astype(np.float64), found, offset, peaks, sharp, n_grid)


def on_lattice(grid: np.ndarray, spacing: int, half_patch: int) -> np.ndarray:
    """(G,) bool: the grid points (x, y) on the lattice of ``spacing`` that a search's grid starts at ``half_patch``."""
    return ((grid[:, 0] - half_patch) % spacing == 0) & ((grid[:, 1] - half_patch) % spacing == 0)


@dataclass(frozen=True)
class _Window:
    """The windows of grid points (gx, gy) of a: radius ``radius`` in b resampled on a's frame grown by
    ``margin`` >= radius on every side; patches of half-size ``half_patch``."""

    gy: np.ndarray
    gx: np.ndarray
    margin: int
    radius: int
    half_patch: int


def _window_peaks(field_a: np.ndarray, warped: np.ndarray, win: _Window, thresholds: Thresholds
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_peaks` of the grid points of ``win`` searched in ``warped`` (b on a's grown frame: grey (H, W) or
    channel-first (C, H, W))."""
    gy, gx, r, hp = win.gy, win.gx, win.radius, win.half_patch
    n, side, k = len(gy), 2 * r + 1, win.margin - r  # a window centred on (x, y) of a: on (x + margin, y + margin)
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
        multi_channel_maps(field_a, warped[:, k:warped.shape[1] - k, k:warped.shape[2] - k], gy, gx, r, hp, maps)
    return _peaks(maps, thresholds.min_ncc, thresholds.min_sharpness)


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
    offset[:, 0] = ix - r + parabola_vertex(left, peak, right)
    offset[:, 1] = iy - r + parabola_vertex(up, peak, down)
    offset[~found] = 0.0
    return found, offset, np.where(found, peak, 0.0), np.where(found, sharp, 0.0)


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


def _matched(s: GridSearch, f0: KernelWarp, mask_b: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The matches a search found: grid points of a (N, 2), their matches in b (N, 2), their correlation (N,).

    ``f0`` is the estimate the search ran around; matches landing outside ``mask_b`` are dropped.
    Trusted input: does not validate."""
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
                   mask_b: np.ndarray | None = None, thresholds: Thresholds | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense putative matches on a regular grid of a, searched near the first estimate ``f0``.

    Image b is first resampled into a's frame through ``f0`` (this removes the rotation, scale and
    bending that ``f0`` already explains), so each grid point of a only needs a small search for the
    residual shift: the peak of the normalized cross-correlation of a (2 h + 1)^2 patch of a within
    ``+-radius`` px of the warped b, refined to sub-pixel by a parabola through the peak. This is
    the guided dense sampling of the L2E paper's dense step [1]_ with a patch correlation instead
    of per-candidate SIFT descriptors: after the pre-warp, the two patches differ by a small shift
    and a photometric change, which zero-mean NCC absorbs, at a fraction of the cost. Every grid
    point whose patch lies inside a is searched (b is resampled beyond a's frame, so the window
    may reach past a's border); a peak counts only where the patch it matched lies inside b.

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
    thresholds : Thresholds, optional
        The least correlation, texture and peak sharpness of a match (default: :class:`Thresholds`'
        defaults: correlation 0.5, the default texture, no sharpness test).

    Returns
    -------
    src : (N, 2) float64 ndarray
        Grid points of a.
    dst : (N, 2) float64 ndarray
        Their matches in b.
    ncc : (N,) float64 ndarray
        Correlation at the peak.

    Raises
    ------
    InputError
        Images that are not (H, W) or (H, W, C), or fields with different C.

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
    spec = SearchSpec(step=step, radius=radius, half_patch=half_patch,
                      thresholds=Thresholds() if thresholds is None else thresholds)
    return _matched(search_grid(fa, fb, f0, spec, mask_a=mask_a), f0, mask_b)


def _downscaled(image: np.ndarray, mask: np.ndarray | None, s: float) -> tuple[np.ndarray, np.ndarray | None]:
    """float32 (H, W, C) copy resized by exactly ``s`` (OpenCV half-pixel centres), and the mask likewise.

    ``s >= 1`` leaves both as they are. Trusted input: does not validate."""
    g = _as_field(image)
    if s >= 1.0:
        return g, mask
    small = area_resized(g, s)
    m = None
    if mask is not None:
        m = cv2.resize(mask.astype(np.uint8), (small.shape[1], small.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    return small, m


def area_resized(field: np.ndarray, s: float) -> np.ndarray:
    """(H, W, C) float32 field resized by ``s`` with OpenCV's area interpolation, any C.

    OpenCV's area resampling takes at most 4 channels at a scale that is not 1 / integer (a
    structure field has 9): the channels, each resampled on its own anyway, go 4 at a time.
    Trusted input: does not validate."""
    parts = []
    for c in range(0, field.shape[2], 4):
        part = cv2.resize(np.ascontiguousarray(field[:, :, c:c + 4]), (0, 0), fx=s, fy=s, interpolation=cv2.INTER_AREA)
        parts.append(part.reshape(part.shape[0], part.shape[1], -1))
    return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=2)
