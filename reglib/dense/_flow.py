"""Dense fields from a transformation: flow, image warps and the fold check.

Conventions (CONTRACTS.md): points are (x, y) with x the column, the centre of the top-left pixel
at (0, 0). A transform ``f`` maps image a into image b. Flow is forward and ``(H_a, W_a, 2)``
float32 of (dx, dy): ``flow[r, c] = f((c, r)) - (c, r)``. ``warp_image(b, f, shape_a)`` samples
b at f(p) for every pixel p of a, so the result overlays a.

Fields are evaluated exactly on a coarse grid of nodes and interpolated with separable
Catmull-Rom cubics (the field is smooth); the node spacing is halved until the interpolation
agrees with exact evaluation to within a quarter of the 0.05 px budget at the cell centres, where
interpolation error peaks.
"""
from __future__ import annotations

import functools
import math
import os
import threading
from collections.abc import Callable
from typing import Any, Literal, cast

import cv2
import numpy as np
from scipy import sparse

from .._transforms import KernelWarp
from .._validation import as_choice
from ..errors import InputError

__all__ = ["dense_flow", "fold_fraction", "warp_image", "as_transform", "as_shape", "sample_positions", "remap_image",
           "remap_planes"]

_MAX_GRID_PIXELS = 1 << 28
_FLOW_TOL = 0.0125  # px, checked at cell centres; the contract is 0.05 px max over all pixels
_START_STEP = 32


def as_transform(transform: Any, name: str = "transform") -> KernelWarp:
    """A :class:`KernelWarp`, or its JSON dict form, as a 2-D KernelWarp."""
    if isinstance(transform, dict):
        transform = KernelWarp.from_dict(transform)
    if not isinstance(transform, KernelWarp):
        raise InputError(f"`{name}` must be a KernelWarp or its dict form, got {type(transform).__name__}")
    if transform.dim != 2:
        raise InputError(f"`{name}` must be 2-D for images, got dim {transform.dim}")
    return transform


def as_shape(shape: Any, name: str = "shape", *, bounded: bool = True) -> tuple[int, int]:
    """(H, W) from a shape tuple (extra trailing entries such as channels are ignored); with ``bounded``, at most
    the pixels a whole-image grid may hold (the tiled warp, which never holds one, passes False)."""
    try:
        dims = tuple(shape)
    except TypeError:
        raise InputError(f"`{name}` must be a tuple (H, W), got {shape!r}") from None
    if len(dims) < 2 or any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) for v in dims[:2]):
        raise InputError(f"`{name}` must start with two integers (H, W), got {shape!r}")
    h, w = int(dims[0]), int(dims[1])
    if h < 1 or w < 1:
        raise InputError(f"`{name}` must be positive, got {(h, w)}")
    if bounded and h * w > _MAX_GRID_PIXELS:
        raise InputError(f"`{name}` {(h, w)} is over {_MAX_GRID_PIXELS} pixels")
    return h, w


# ------------------------------------------------------------------------ smooth-field evaluation
@functools.lru_cache(maxsize=32)
def _catmull_rom(n_out: int, step: int) -> tuple[sparse.csr_matrix, int]:
    """Sparse (n_out, n_nodes) weights interpolating nodes at x = step * (i - 1) onto pixels 0..n_out-1.

    Cached (the dense stage evaluates many fields on the same few grids): callers must not modify
    the matrix in place.
    """
    x = np.arange(n_out, dtype=np.float64)
    u = x / step + 1.0
    i0 = np.floor(u).astype(np.intp)
    t = u - i0
    t2, t3 = t * t, t * t * t
    w = np.stack([(-t3 + 2 * t2 - t) / 2, (3 * t3 - 5 * t2 + 2) / 2, (-3 * t3 + 4 * t2 + t) / 2, (t3 - t2) / 2], 1)
    cols = i0[:, None] + np.arange(-1, 3)[None, :]
    n_nodes = (n_out - 1) // step + 4
    rows = np.repeat(np.arange(n_out), 4)
    mat = sparse.csr_matrix((w.ravel().astype(np.float32), (rows, cols.ravel())), shape=(n_out, n_nodes))
    return mat, n_nodes


@functools.lru_cache(maxsize=32)
def _catmull_rom_centres(n_out: int, step: int) -> sparse.csr_matrix:
    """The rows of :func:`_catmull_rom` at the cell centres step // 2, step // 2 + step, ... (cached likewise)."""
    return _catmull_rom(n_out, step)[0][np.arange(step // 2, n_out, step)]


def _interpolate(values: np.ndarray, wy: sparse.csr_matrix, wx: sparse.csr_matrix) -> np.ndarray:
    """(ny, nx, C) node values -> (H, W, C) by the separable weights (x pass on the small grid first)."""
    ny, nx, c = values.shape
    small = values.astype(np.float32).transpose(1, 0, 2).reshape(nx, ny * c)
    rows = (wx @ small).reshape(wx.shape[0], ny, c).transpose(1, 0, 2)  # (ny, W, C), small
    out = wy @ np.ascontiguousarray(rows).reshape(ny, -1)  # (H, W*C): already in the final layout
    return out.reshape(wy.shape[0], wx.shape[0], c)


GridFunc = Callable[[np.ndarray, np.ndarray], np.ndarray]


def grid_map(f: KernelWarp, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """f on the grid xs x ys, (ny, nx, 2) float64, using the separability of the Gaussian kernel.

    exp(-beta |u - c|^2) = exp(-beta (u_x - c_x)^2) exp(-beta (u_y - c_y)^2), so the kernel sum on a
    grid is two small matrix products instead of an (ny nx, M) kernel matrix.
    """
    ux = (np.asarray(xs, np.float64) - f.src_mean[0]) / f.src_scale
    uy = (np.asarray(ys, np.float64) - f.src_mean[1]) / f.src_scale
    gx, gy = np.meshgrid(ux, uy)
    u = np.c_[gx.ravel(), gy.ravel()]
    g = (u.copy() if f.linear is None else f.linear.apply(u)).reshape(len(uy), len(ux), 2)
    if f.n_centers:
        ex = np.exp(-f.beta * (ux[None, :] - f.centers[:, :1]) ** 2)  # (M, nx)
        ey = np.exp(-f.beta * (uy[None, :] - f.centers[:, 1:]) ** 2)  # (M, ny)
        for d in range(2):
            g[..., d] += ey.T @ (f.weights[:, d:d + 1] * ex)
    return f.dst_mean + f.dst_scale * g


def grid_jacobian_det(f: KernelWarp, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """det df/dx on the grid xs x ys, (ny, nx), separably like :func:`grid_map`."""
    ux = (np.asarray(xs, np.float64) - f.src_mean[0]) / f.src_scale
    uy = (np.asarray(ys, np.float64) - f.src_mean[1]) / f.src_scale
    gx, gy = np.meshgrid(ux, uy)
    u = np.c_[gx.ravel(), gy.ravel()]
    if f.linear is None:
        jac = np.zeros((len(uy), len(ux), 2, 2))
        jac[..., 0, 0] = jac[..., 1, 1] = 1.0
    else:
        jac = f.linear.jacobian(u).reshape(len(uy), len(ux), 2, 2)
    if f.n_centers:
        dx = ux[None, :] - f.centers[:, :1]
        dy = uy[None, :] - f.centers[:, 1:]
        ex, ey = np.exp(-f.beta * dx * dx), np.exp(-f.beta * dy * dy)
        dex, dey = -2.0 * f.beta * dx * ex, -2.0 * f.beta * dy * ey
        for i in range(2):
            w = f.weights[:, i:i + 1]
            jac[..., i, 0] += ey.T @ (w * dex)
            jac[..., i, 1] += dey.T @ (w * ex)
    return jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]


def smooth_field(func: GridFunc, shape: tuple[int, int], *, tol: float = _FLOW_TOL,
                 step: int = _START_STEP) -> np.ndarray:
    """Evaluate a smooth map on every pixel of ``shape`` from a coarse grid of exact values.

    ``func(xs, ys)`` returns the (len(ys), len(xs), C) values on the grid of pixel positions xs x ys.
    Returns (H, W, C) float32 (float64 when evaluated at every pixel), within about ``tol`` of
    exact evaluation (checked at cell centres, where interpolation error is largest; the node
    spacing halves until it holds).
    """
    h, w = shape
    while True:
        if step <= 1 or h * w <= 4096:
            return func(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        wy, ny = _catmull_rom(h, step)
        wx, nx = _catmull_rom(w, step)
        vals = func((np.arange(nx) - 1.0) * step, (np.arange(ny) - 1.0) * step)
        cy = np.arange(step // 2, h, step)
        cx = np.arange(step // 2, w, step)
        if len(cy) and len(cx):
            # interpolate only at the check points first; the full field once the spacing passes
            exact = func(cx.astype(np.float64), cy.astype(np.float64))
            err = np.abs(_interpolate(vals, _catmull_rom_centres(h, step), _catmull_rom_centres(w, step)) - exact).max()
            if err > tol:
                step //= 2
                continue
        return _interpolate(vals, wy, wx)


def dense_flow(transform: KernelWarp | dict[str, Any], shape: Any) -> np.ndarray:
    """Forward flow of ``transform`` on the pixel grid of image a.

    Parameters
    ----------
    transform : KernelWarp or dict
        Maps image a's pixels (x, y) into image b (its JSON dict form is accepted).
    shape : tuple
        (H, W) of image a (an image's ``.shape`` works; channels are ignored).

    Returns
    -------
    (H, W, 2) float32 ndarray
        ``flow[r, c] = f((c, r)) - (c, r)``, components (dx, dy); within 0.05 px of evaluating
        ``transform`` pixel by pixel (evaluated on a coarse grid, cubic-interpolated).

    Examples
    --------
    >>> from reglib import KernelWarp
    >>> dense_flow(KernelWarp.identity(2), (3, 4)).shape
    (3, 4, 2)
    """
    f = as_transform(transform)
    h, w = as_shape(shape)

    def disp(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        out = grid_map(f, xs, ys)
        out[..., 0] -= xs[None, :]
        out[..., 1] -= ys[:, None]
        return out

    return np.asarray(smooth_field(disp, (h, w), step=_first_step(f)), dtype=np.float32)


# Catmull-Rom interpolation of a Gaussian-kernel field, measured at the cell centres of node
# spacings 4-32 px on the dense stage's fields (kernel widths 28-122 px, amplitudes 26-240 px):
# max error ~= 0.09 A (step / width)^4, A = dst_scale * max |w|, width = src_scale / sqrt(2 beta).
_CR_ERROR = 0.09


def _first_step(f: KernelWarp, tol: float = _FLOW_TOL) -> int:
    """The node spacing :func:`smooth_field` tries first for ``f``: twice the largest power of two
    (at most ``_START_STEP``) whose predicted interpolation error is within ``tol``.

    The check still decides, halving a spacing that fails it, so the spacing it settles on is the
    one a start at ``_START_STEP`` would reach whenever the prediction is within a factor of two:
    the same field, without the exact evaluations of the larger spacings that fail."""
    amplitude = f.dst_scale * float(np.abs(f.weights).max(initial=0.0)) if f.n_centers else 0.0
    if amplitude <= 0.0 or f.beta <= 0.0:
        return _START_STEP
    width = f.src_scale / math.sqrt(2.0 * f.beta)
    best = width * (tol / (_CR_ERROR * amplitude)) ** 0.25
    step = _START_STEP
    while step > 1 and step > best:
        step //= 2
    return min(_START_STEP, 2 * step)


def fold_fraction(transform: KernelWarp | dict[str, Any], shape: Any, *, max_samples: int | None = None) -> float:
    """Share of image a's pixels where the warp's Jacobian determinant is <= 0 (the warp folds).

    A smooth warp between two views of one surface keeps orientation everywhere (determinant > 0);
    folds point to an estimate that followed outliers. The determinant is evaluated exactly on a
    coarse grid and interpolated like :func:`dense_flow`.

    Parameters
    ----------
    transform : KernelWarp or dict
        Maps a's pixels (x, y) into b.
    shape : tuple
        (H, W) of image a.
    max_samples : int, optional
        For images with more pixels than this, the share is measured exactly on a regular lattice
        of about ``max_samples`` pixels instead of on every pixel (bounded memory for huge images).
    """
    f = as_transform(transform)
    h, w = as_shape(shape)
    if max_samples is not None and h * w > max_samples:
        k = int(np.ceil(np.sqrt(h * w / max(1, int(max_samples)))))
        det_lattice = grid_jacobian_det(f, np.arange(0, w, k, dtype=np.float64), np.arange(0, h, k, dtype=np.float64))
        return float(np.count_nonzero(det_lattice <= 0.0)) / float(det_lattice.size)

    def det(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        return grid_jacobian_det(f, xs, ys)[..., None]

    field = smooth_field(det, (h, w), tol=0.01)
    return float(np.count_nonzero(field[..., 0] <= 0.0)) / float(h * w)


def sample_positions(transform: KernelWarp, shape: tuple[int, int], *, margin: int = 0) -> np.ndarray:
    """(H + 2 m, W + 2 m, 2) float32 positions f(p) in b of every pixel p of a's frame grown by ``margin`` m.

    Pixel (row, col) of the grown frame is a's pixel (x, y) = (col - m, row - m); with m = 0 the
    frame is a's (H, W) own. Trusted input (a 2-D transform, a positive shape): does not validate.
    """
    m = int(margin)
    if m:  # f(p - m) on the grown frame's pixel p: the same map, its source origin moved by m
        transform = transform.source_shifted(m)
    h, w = as_shape(shape)
    grown = (h + 2 * m, w + 2 * m)
    flow = dense_flow(transform, grown)
    flow += pixel_grid(*grown)
    return flow


# The dense stage resamples the same few frames many times: their pixel grids are kept, the most
# recently used first, up to this many bytes in all (a grid larger than that is made each time).
_GRID_CACHE_BYTES = 32 << 20
_grids: dict[tuple[int, int], np.ndarray] = {}
_grids_lock = threading.Lock()


def pixel_grid(h: int, w: int) -> np.ndarray:
    """(H, W, 2) float32 (x, y) of every pixel, read-only.

    Grids are kept for reuse, the most recently used first, up to 32 MiB in all; a grid larger
    than that is made on each call.
    """
    with _grids_lock:
        grid = _grids.pop((h, w), None)
        if grid is not None:
            _grids[(h, w)] = grid  # now the most recent
            return grid
    grid = np.empty((h, w, 2), np.float32)
    grid[..., 0] = np.arange(w, dtype=np.float32)[None, :]
    grid[..., 1] = np.arange(h, dtype=np.float32)[:, None]
    grid.flags.writeable = False
    if grid.nbytes <= _GRID_CACHE_BYTES:
        with _grids_lock:
            _grids[(h, w)] = grid
            while sum(g.nbytes for g in _grids.values()) > _GRID_CACHE_BYTES:
                del _grids[next(iter(_grids))]  # the least recently used
    return grid


# ------------------------------------------------------------------------------------ warping
_REMAP_DTYPES = (np.uint8, np.uint16, np.int16, np.float32, np.float64)


def warp_image(image_b: Any, transform: KernelWarp | dict[str, Any], shape_a: Any, *,
               interpolation: Literal["linear", "nearest"] = "linear") -> tuple[np.ndarray, np.ndarray]:
    """Resample image b into image a's frame: ``out[p] = b(f(p))`` for every pixel p of a.

    Parameters
    ----------
    image_b : (H_b, W_b) or (H_b, W_b, C) ndarray, path or bytes
        An array of any real or boolean dtype and any number of channels (label maps included), or
        what :func:`reglib.match_images` takes: a path to a PNG / JPEG / TIFF / BMP / WebP file or
        its encoded bytes (read by :func:`reglib.io.read_image`: grey or RGB, alpha dropped).
    transform : KernelWarp or dict
        Maps a's pixels (x, y) into b (a -> b, as :func:`reglib.match_images` returns it).
    shape_a : tuple
        (H_a, W_a) of the output.
    interpolation : {"linear", "nearest"}
        "nearest" keeps values exactly (label maps, segmentations).

    Returns
    -------
    warped : (H_a, W_a[, C]) ndarray
        b's dtype and channels; 0 where f(p) falls outside b.
    valid : (H_a, W_a) bool ndarray
        True where f(p) falls inside b.

    Raises
    ------
    InputError
        ``image_b`` neither an array nor a readable image file or bytes (named), an empty array, a
        bad ``transform`` or ``shape_a``, or another ``interpolation``.
    """
    interpolation = as_choice(interpolation, "interpolation", ("linear", "nearest"))
    if isinstance(image_b, (str, os.PathLike, bytes, bytearray, memoryview)):
        from ..io import read_image

        image_b = read_image(image_b, name="image_b")
    elif not isinstance(image_b, np.ndarray):
        raise InputError(f"`image_b` must be an image array, a path or encoded bytes, got {type(image_b).__name__}")
    img = image_b
    if img.ndim not in (2, 3) or img.shape[0] == 0 or img.shape[1] == 0 or (img.ndim == 3 and img.shape[2] == 0):
        raise InputError(f"`image_b` must be a non-empty (H, W) or (H, W, C) array, got shape {img.shape}")
    if img.dtype.kind not in "biuf":
        raise InputError(f"`image_b` must have a real or boolean dtype, got {img.dtype}")
    f = as_transform(transform)
    h, w = as_shape(shape_a, "shape_a")
    pos = sample_positions(f, (h, w))
    return remap_image(img, pos, interpolation)


def _linear_map(pos: np.ndarray, hb: int, wb: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions as one float32 two-channel map for ``cv2.remap`` (no split into x and y copies), and
    the uint8 mask (255 / 0) of those inside an (hb, wb) image for linear sampling: both neighbours
    must exist (pixel centres span 0..W-1), float32 round-off tolerated; the bounds test in one pass."""
    eps = 1e-3
    xy = pos if pos.dtype == np.float32 and pos.flags.c_contiguous else np.ascontiguousarray(pos, np.float32)
    return xy, cv2.inRange(xy, (-eps, -eps), (wb - 1 + eps, hb - 1 + eps))


def remap_image(img: np.ndarray, pos: np.ndarray, interpolation: str) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``img`` at (H, W, 2) float positions (x, y); zero and invalid outside."""
    hb, wb = img.shape[:2]
    mx, my = pos[..., 0], pos[..., 1]
    if interpolation == "nearest":
        ix = np.floor(mx + 0.5)
        iy = np.floor(my + 0.5)
        valid = (ix >= 0) & (ix <= wb - 1) & (iy >= 0) & (iy <= hb - 1)
        ixc = np.clip(ix, 0, wb - 1).astype(np.intp)
        iyc = np.clip(iy, 0, hb - 1).astype(np.intp)
        out = img[iyc, ixc]
        out[~valid] = 0
        return out, valid
    xy, inside = _linear_map(pos, hb, wb)
    valid = inside.astype(bool)
    work = img
    back = None
    if img.dtype == bool:
        work, back = img.astype(np.float32), "bool"
    elif img.dtype.type not in _REMAP_DTYPES:
        work, back = img.astype(np.float64), "cast"
    channels = 1 if work.ndim == 2 else work.shape[2]
    planes = [work] if channels <= 4 else [work[:, :, k] for k in range(channels)]
    outs = [cv2.remap(np.ascontiguousarray(p), xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            for p in planes]
    out = outs[0] if len(outs) == 1 else np.stack(outs, axis=2)
    if work.ndim == 3 and out.ndim == 2:  # OpenCV drops a single channel axis
        out = out[:, :, None]
    if back == "bool":
        out = out >= 0.5
    elif back == "cast":
        if img.dtype.kind in "iu":
            info = np.iinfo(img.dtype)
            out = np.clip(np.round(out), info.min, info.max)
        out = out.astype(img.dtype)
    if out.dtype.type in _REMAP_DTYPES and (out.ndim == 2 or out.shape[2] <= 4):
        plane = cast("cv2.typing.MatLike", out)  # of a dtype OpenCV takes (checked above)
        out = cv2.bitwise_and(plane, plane, mask=inside).reshape(out.shape)  # a bit-exact copy inside, 0 outside
    else:
        out[~valid] = 0
    return out, valid


def remap_planes(field: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`remap_image` of a float32 (H, W, C) field, linear, returned channel-first: (C, H', W'), and valid.

    The same values as ``remap_image(field, pos, "linear")`` (moved to the channel axis first), without
    stacking the planes back into (H', W', C): per-channel work then slices contiguous rows.
    """
    xy, inside = _linear_map(pos, *field.shape[:2])
    out = np.zeros((field.shape[2],) + xy.shape[:2], np.float32)  # a masked copy leaves the rest as it is: 0
    for k in range(field.shape[2]):
        plane = cv2.remap(np.ascontiguousarray(field[:, :, k], np.float32), xy, None, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
        cv2.bitwise_and(plane, plane, dst=out[k], mask=inside)
    return out, inside.astype(bool)
