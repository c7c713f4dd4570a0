"""Guided matching: the matches a grid search found near a first estimate, and its public, validating form.

:func:`guided_matches` searches patches of a on a regular grid in b near the first estimate
(:func:`~reglib.dense._correlation.search_grid`) and returns the matches, as the guided dense sampling of the
L2E paper's dense step [1]_ does, with a patch correlation instead of per-candidate descriptors.
``_matched`` reads the matches of a search, which the dense stage's rounds and its guard run
themselves. Coordinates are (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0).

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of
       Transformation for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
"""
from __future__ import annotations

import numpy as np

from .._transforms import KernelWarp
from ._correlation import GridSearch, SearchSpec, Thresholds, search_grid
from ._fields import _as_fields

__all__ = ["guided_matches"]


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
