"""The correlation search: patches of a on a regular grid found in b near a first estimate.

Image b is resampled into a's frame through the current estimate (this removes the rotation,
scale and bending the estimate already explains), so each grid point of a only needs a small
search for the residual shift: the peak of the zero-mean normalized cross-correlation (NCC) of a
(2 h + 1)^2 patch of a within ``radius`` px, refined to sub-pixel by a parabola. The images
correlated are grey images (H, W) or multi-channel descriptor fields (H, W, C), whose correlation
is the mean over channels of each channel's zero-mean NCC (:mod:`reglib.dense._ncc`); grid points
whose patch has too little texture (:mod:`reglib.dense._texture`) are not searched.

:func:`search_grid` is the search itself (every grid point tried, :class:`GridSearch`);
:func:`~reglib.dense.guided_matches` (:mod:`reglib.dense._guided`) its public form, the matches it
found. Coordinates are (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from .._parallel import split_range
from .._transforms import KernelWarp
from ..features import parabola_vertex
from ._flow import remap_image, remap_planes, sample_positions
from ._ncc import multi_channel_maps
from ._texture import _default_min_std, texture_at

__all__ = ["GridSearch", "SearchSpec", "Thresholds", "on_lattice", "search_grid"]

_NEAR_RADIUS = 10  # search radius where the estimate barely moved (see search_grid's ``near``)


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
    (:func:`~reglib.dense.guided_matches` is the validating form).

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
        :func:`~reglib.dense.texture_map` of ``field_a`` when the caller has it (else the texture is measured
        at the grid points only, :func:`~reglib.dense._texture.texture_at`).
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
