"""Pictures to look at: flow colouring, match drawings, overlays and checkerboards.

Every function returns an RGB uint8 image; inputs are (H, W) or (H, W, 3) RGB arrays of any real
dtype. 8-bit images are shown as they are; any other dtype is stretched by the rule the features use
(:func:`reglib.features.intensity_range`: the 0.5 and 99.5 percentiles of the pixels become black and
white), so 12-bit data in uint16 or a float image in any range is seen as the matcher saw it.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ._validation import check_int, check_range
from .errors import InputError
from .features import intensity_range

if TYPE_CHECKING:  # pragma: no cover
    from .matching import ImageMatch

__all__ = ["flow_to_color", "draw_matches", "overlay", "checkerboard", "to_rgb_uint8"]


def to_rgb_uint8(image: Any, name: str = "image") -> np.ndarray:
    """(H, W, 3) uint8 RGB copy of an (H, W) or (H, W, C) image: its first three bands, or its first band
    shown grey when it has fewer (the bands :func:`reglib.features.feature_bands` shows the features)."""
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] >= 1:
        arr = arr[:, :, 0] if arr.shape[2] < 3 else arr[:, :, :3]
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise InputError(f"`{name}` must be a non-empty (H, W) or (H, W, 3) image, got shape {np.shape(image)}")
    if arr.dtype == bool:
        arr = arr.astype(np.uint8) * 255
    if arr.dtype.kind not in "uif":
        raise InputError(f"`{name}` must have a real dtype, got {arr.dtype}")
    u8 = _display_uint8(arr)
    if u8.ndim == 2:
        u8 = np.repeat(u8[:, :, None], 3, axis=2)
    return np.ascontiguousarray(u8)


def _display_uint8(arr: np.ndarray) -> np.ndarray:
    """uint8 of a (H, W) or (H, W, 3) image for a picture: 8 bits kept, any other dtype stretched from its
    0.5 to its 99.5 percentile over all its bands (one range, so colours keep their balance)."""
    if arr.dtype == np.uint8:
        return arr
    values = np.nan_to_num(np.asarray(arr, dtype=np.float32))
    lo, hi = intensity_range(values.reshape(values.shape[0], -1), arr.dtype)
    if not hi > lo:
        return np.zeros(values.shape, np.uint8)
    out = np.clip((values - np.float32(lo)) * np.float32(255.0 / (hi - lo)), 0.0, 255.0)
    return np.round(out).astype(np.uint8)


def _color_wheel() -> np.ndarray:
    """The Middlebury colour wheel (Baker et al.): (55, 3) RGB in [0, 255]."""
    ry, yg, gc, cb, bm, mr = 15, 6, 4, 11, 13, 6
    cols: list[tuple[float, float, float]] = []
    cols += [(255, 255 * i / ry, 0) for i in range(ry)]
    cols += [(255 - 255 * i / yg, 255, 0) for i in range(yg)]
    cols += [(0, 255, 255 * i / gc) for i in range(gc)]
    cols += [(0, 255 - 255 * i / cb, 255) for i in range(cb)]
    cols += [(255 * i / bm, 0, 255) for i in range(bm)]
    cols += [(255, 0, 255 - 255 * i / mr) for i in range(mr)]
    return np.asarray(cols, dtype=np.float64)


def flow_to_color(flow: Any, *, max_flow: float | None = None) -> np.ndarray:
    """Colour-code a flow field with the Baker et al. (Middlebury) wheel.

    Hue is the direction of (dx, dy), saturation the magnitude relative to ``max_flow`` (the
    largest magnitude when None); zero flow is white.

    Parameters
    ----------
    flow : (H, W, 2) array_like
        (dx, dy) per pixel.
    max_flow : float, optional
        Magnitude shown fully saturated.

    Returns
    -------
    (H, W, 3) uint8 ndarray, RGB.

    References
    ----------
    .. [1] S. Baker, D. Scharstein, J. P. Lewis, S. Roth, M. J. Black, R. Szeliski, "A Database and
           Evaluation Methodology for Optical Flow", IJCV 92, 2011. :doi:`10.1007/s11263-010-0390-2`
    """
    f = np.asarray(flow, dtype=np.float64)
    if f.ndim != 3 or f.shape[2] != 2:
        raise InputError(f"`flow` must have shape (H, W, 2), got {f.shape}")
    u, v = f[..., 0], f[..., 1]
    bad = ~(np.isfinite(u) & np.isfinite(v))
    u, v = np.where(bad, 0.0, u), np.where(bad, 0.0, v)
    mag = np.hypot(u, v)
    if max_flow is None:
        max_flow = float(mag.max()) if mag.size else 0.0
    else:
        check_range("max_flow", max_flow, 0.0, low_open=True)
    scale = 1.0 / max_flow if max_flow > 0 else 0.0
    rad = np.minimum(mag * scale, 1.0)
    wheel = _color_wheel()
    n = len(wheel)
    ang = np.arctan2(-v, -u) / np.pi  # in [-1, 1]
    fk = (ang + 1.0) / 2.0 * (n - 1)
    k0 = np.floor(fk).astype(np.intp)
    k1 = (k0 + 1) % n
    t = (fk - k0)[..., None]
    col = ((1 - t) * wheel[k0] + t * wheel[k1]) / 255.0
    col = 1.0 - rad[..., None] * (1.0 - col)
    out = np.round(col * 255.0).astype(np.uint8)
    out[bad] = 0
    return out


def draw_matches(image_a: Any, image_b: Any, match: ImageMatch, *, max_lines: int = 2000,
                 thickness: int = 1) -> np.ndarray:
    """a and b side by side with every putative match drawn: inliers green, outliers red.

    Returns an RGB uint8 image of height max(H_a, H_b) and width W_a + W_b. At most
    ``max_lines`` matches are drawn (an even subsample beyond, outliers first so inliers stay on top).
    """
    a, b = to_rgb_uint8(image_a, "image_a"), to_rgb_uint8(image_b, "image_b")
    h = max(a.shape[0], b.shape[0])
    canvas = np.zeros((h, a.shape[1] + b.shape[1], 3), np.uint8)
    canvas[:a.shape[0], :a.shape[1]] = a
    canvas[:b.shape[0], a.shape[1]:] = b
    src, dst = np.asarray(match.src, float), np.asarray(match.dst, float)
    inl = np.asarray(match.inliers, bool)
    order = np.r_[np.flatnonzero(~inl), np.flatnonzero(inl)]
    if len(order) > max_lines:
        order = order[np.linspace(0, len(order) - 1, max_lines).round().astype(int)]
    shift = 4  # sub-pixel line ends
    k = float(1 << shift)
    for i in order:
        color = (0, 200, 0) if inl[i] else (230, 0, 0)
        p = (int(round(src[i, 0] * k)), int(round(src[i, 1] * k)))
        q = (int(round((dst[i, 0] + a.shape[1]) * k)), int(round(dst[i, 1] * k)))
        cv2.line(canvas, p, q, color, thickness, cv2.LINE_AA, shift)
        cv2.circle(canvas, p, 2 << shift, color, thickness, cv2.LINE_AA, shift)
        cv2.circle(canvas, q, 2 << shift, color, thickness, cv2.LINE_AA, shift)
    return canvas


def overlay(image_a: Any, warped_b: Any, alpha: float = 0.5) -> np.ndarray:
    """Blend a and b warped into a's frame: (1 - alpha) a + alpha b, RGB uint8."""
    check_range("alpha", alpha, 0.0, 1.0)
    a, b = to_rgb_uint8(image_a, "image_a"), to_rgb_uint8(warped_b, "warped_b")
    if a.shape != b.shape:
        raise InputError(f"`warped_b` must have image_a's size {a.shape[:2]}, got {b.shape[:2]}")
    return cv2.addWeighted(a, 1.0 - alpha, b, alpha, 0.0)


def checkerboard(image_a: Any, warped_b: Any, tiles: int = 8) -> np.ndarray:
    """Alternate square tiles of a and of b warped into a's frame (``tiles`` along the longer side)."""
    check_int("tiles", tiles)
    a, b = to_rgb_uint8(image_a, "image_a"), to_rgb_uint8(warped_b, "warped_b")
    if a.shape != b.shape:
        raise InputError(f"`warped_b` must have image_a's size {a.shape[:2]}, got {b.shape[:2]}")
    size = max(1, int(np.ceil(max(a.shape[:2]) / tiles)))
    yy, xx = np.indices(a.shape[:2])
    pick_b = ((yy // size + xx // size) % 2).astype(bool)
    out = a.copy()
    out[pick_b] = b[pick_b]
    return out
