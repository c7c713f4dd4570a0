"""Closed-form weighted rigid (or similarity) alignment of corresponding point sets.

Both solvers minimize sum_i w_i |dst_i - (s R src_i + t)|^2 over rotations R (det R = +1),
translations t and, with ``scale=True``, a scale s > 0, and validate their input; the
arithmetic is :func:`reglib._geometry.umeyama_similarity`'s:

- :func:`umeyama`: the SVD of the weighted cross-covariance (Umeyama), in 2-D and 3-D.
- :func:`fa3r`: the SVD- and eigen-decomposition-free fixed-point iteration of Wu, Liu, Zhou and
  Li (their FA3R, :func:`reglib._geometry.fa3r_rotation`), 3-D only; the same R as the SVD.

Both return the (D, D + 1) matrix ``[s R | t]``: a point x of ``src`` goes to ``s R x + t``.
Points are (N, D) arrays of (x, y[, z]) rows in the caller's units.

The cost of either is dominated by forming the weighted means and the cross-covariance, O(N);
the 3 x 3 step itself is microseconds (``benchmarks/bench_rigid.py`` prints the measured times).

The papers (Umeyama, TPAMI 1991; Wu et al., IEEE TIM 2020) are cited in :mod:`reglib._geometry`.
"""
from __future__ import annotations

import numpy as np

from .._geometry import umeyama_similarity
from ..errors import InputError

__all__ = ["fa3r", "umeyama"]


def _checked(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None,
             dims: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``src``, ``dst`` and ``weights`` as float64 arrays, or an ``InputError`` naming what is wrong."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] not in dims:
        shapes = " or ".join(f"(N, {d})" for d in dims)
        raise InputError(f"`src` must have shape {shapes}, got {src.shape}")
    if dst.shape != src.shape:
        raise InputError(f"`dst` must have the same shape as `src` {src.shape}, got {dst.shape}")
    if weights is None:
        if len(src) == 0:
            raise InputError("`src` must hold at least one point, got 0")
        return src, dst, None
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (len(src),):
        raise InputError(f"`weights` must have shape ({len(src)},), got {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any():
        raise InputError("`weights` must be finite and non-negative")
    if float(w.sum()) <= 0.0:
        raise InputError("`weights` must have a positive sum, got all zeros")
    return src, dst, w


def umeyama(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None, *,
            scale: bool = False) -> np.ndarray:
    """Weighted least-squares rigid (or similarity) map of ``src`` onto ``dst`` by SVD.

    Parameters
    ----------
    src, dst : (N, D) array_like
        Corresponding points (row i of ``src`` goes to row i of ``dst``), D in {2, 3}, as
        (x, y[, z]) rows.
    weights : (N,) array_like, optional
        Non-negative weights w_i with a positive sum; all ones when omitted.
    scale : bool
        Also estimate a global scale s (c in [1]); otherwise s = 1.

    Returns
    -------
    (D, D + 1) ndarray
        ``[s R | t]`` minimizing sum_i w_i |dst_i - s R src_i - t|^2 with det R = +1.

    Raises
    ------
    InputError
        On shapes other than (N, 2) / (N, 3), mismatched shapes, no points, or negative,
        non-finite or all-zero weights.

    References
    ----------
    S. Umeyama, IEEE TPAMI 13(4), 1991. :doi:`10.1109/34.88573`

    Examples
    --------
    >>> import numpy as np
    >>> src = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]])
    >>> rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    >>> m = umeyama(src, src @ rot.T + [1.0, 2.0, 3.0])
    >>> np.allclose(m, np.c_[rot, [1.0, 2.0, 3.0]])
    True
    """
    return umeyama_similarity(*_checked(src, dst, weights, (2, 3)), scale=scale)


def fa3r(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None, *,
         scale: bool = False) -> np.ndarray:
    """Weighted least-squares rigid (or similarity) map of ``src`` onto ``dst`` in 3-D by FA3R.

    The same minimizer as :func:`umeyama` (to about 1e-12), without SVD or eigen-decomposition:
    the rotation is the fixed point of FA3R's iteration on the cross-covariance (module docstring).

    Parameters
    ----------
    src, dst : (N, 3) array_like
        Corresponding points, (x, y, z) rows.
    weights : (N,) array_like, optional
        Non-negative weights with a positive sum; all ones when omitted.
    scale : bool
        Also estimate a global scale s; otherwise s = 1.

    Returns
    -------
    (3, 4) ndarray
        ``[s R | t]`` minimizing sum_i w_i |dst_i - s R src_i - t|^2 with det R = +1.

    Raises
    ------
    InputError
        On shapes other than (N, 3), mismatched shapes, no points, or bad weights.

    References
    ----------
    J. Wu, M. Liu, Z. Zhou, R. Li, IEEE Trans. Instrum. Meas. 69(10), 2020.
    :doi:`10.1109/TIM.2020.2987495`

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> src = rng.normal(size=(50, 3))
    >>> dst = 2.0 * src @ np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]).T + 5.0
    >>> np.allclose(fa3r(src, dst, scale=True), umeyama(src, dst, scale=True), atol=1e-12)
    True
    """
    return umeyama_similarity(*_checked(src, dst, weights, (3,)), scale=scale, solver="fa3r")
