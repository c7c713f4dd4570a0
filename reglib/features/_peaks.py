"""Sub-pixel peaks: the vertex of the parabola through a sampled maximum and its two neighbours.

A response sampled on the integer grid (a detector's corner measure, a correlation surface) has
its maximum between samples; fitting a parabola through the sample ``c`` at the maximum and its
neighbours ``l`` (at -1) and ``r`` (at +1) along one axis puts the vertex at

    d = (r - l) / (2 (2 c - l - r)),

clipped to [-0.5, 0.5] (beyond, the neighbour would have been the maximum). This is the usual
three-point refinement of keypoint and template-matching positions (e.g. Lowe's 1-D analogue of
the quadratic fit in SIFT, D. G. Lowe, IJCV 60, 2004, :doi:`10.1023/B:VISI.0000029664.99615.94`).
Each axis is refined on its own.

Coordinates: (x, y), x the column.
"""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["parabola_vertex", "subpixel_peaks"]


def parabola_vertex(left: Any, centre: Any, right: Any, *, min_curvature: float = 0.0) -> np.ndarray:
    """Offset of the vertex of the parabola through (-1, left), (0, centre), (1, right), in [-0.5, 0.5].

    Trusted input, does not validate: arrays of one shape (or numbers), computed in their dtype.

    Parameters
    ----------
    left, centre, right : array_like
        Samples before, at and after the maximum along one axis.
    min_curvature : float
        The vertex is taken only where the curvature ``2 centre - left - right`` exceeds this;
        elsewhere (a flat or upward-opening parabola: no maximum) the offset is 0.

    Returns
    -------
    ndarray
        The offsets, of the samples' shape and dtype.

    Examples
    --------
    >>> x = np.array([-1.0, 0.0, 1.0])
    >>> y = -(x - 0.25) ** 2                   # vertex at 0.25
    >>> float(parabola_vertex(y[0], y[1], y[2]))
    0.25
    >>> float(parabola_vertex(1.0, 1.0, 1.0))  # flat: no vertex
    0.0
    """
    den = 2.0 * np.asarray(centre) - left - right
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(den > min_curvature, 0.5 * (np.asarray(right) - left) / den, 0.0)
    return np.clip(offset, -0.5, 0.5)


def subpixel_peaks(response: np.ndarray, rows_cols: np.ndarray) -> np.ndarray:
    """(x, y) positions of maxima of a 2-D response, refined by a parabola along each axis.

    Trusted input, does not validate. At the border the missing neighbour is the maximum itself
    (the vertex then lies half a pixel outwards where the inner neighbour is lower).

    Parameters
    ----------
    response : (H, W) float ndarray
    rows_cols : (K, 2) int ndarray
        (row, col) of the maxima.

    Returns
    -------
    (K, 2) float64 ndarray
        (x, y) = (col + dx, row + dy), dx and dy in [-0.5, 0.5].

    Examples
    --------
    >>> yy, xx = np.mgrid[0:9, 0:9]
    >>> r = -((xx - 4.25) ** 2) - (yy - 3.0) ** 2
    >>> subpixel_peaks(r, np.array([[3, 4]]))
    array([[4.25, 3.  ]])
    """
    h, w = response.shape
    r, c = rows_cols[:, 0], rows_cols[:, 1]
    rm, rp = np.clip(r - 1, 0, h - 1), np.clip(r + 1, 0, h - 1)
    cm, cp = np.clip(c - 1, 0, w - 1), np.clip(c + 1, 0, w - 1)
    v = response[r, c]
    dx = parabola_vertex(response[r, cm], v, response[r, cp], min_curvature=1e-12)
    dy = parabola_vertex(response[rm, c], v, response[rp, c], min_curvature=1e-12)
    return np.stack([c + dx, r + dy], axis=1).astype(np.float64)
