"""Closed-form weighted rigid (or similarity) alignment of corresponding point sets.

Both solvers minimize sum_i w_i |dst_i - (s R src_i + t)|^2 over rotations R (det R = +1),
translations t and, with ``scale=True``, a scale s > 0:

- :func:`umeyama`: the SVD of the weighted cross-covariance (Umeyama [1]), in 2-D and 3-D.
- :func:`fa3r`: the SVD- and eigen-decomposition-free fixed-point iteration of Wu, Liu, Zhou and
  Li [2] (their FA3R), 3-D only. With the cross-covariance H = [h_x h_y h_z] (columns) the
  iteration is h_x <- k (h_x + h_y x h_z), h_y <- k (h_y + h_z x h_x), h_z <- k (h_z + h_x x h_y)
  with k = 2 / (|H|_F^2 + 1), i.e. H <- k (H + cof H); its fixed point is the rotation nearest to
  H (the proper polar factor), the same R as the SVD gives. We start it from H scaled to
  |H|_F^2 = 3 (the value at a rotation), where it converges in at most about 20 steps, and run
  it to machine precision (at most 100 steps).

Both return the (D, D + 1) matrix ``[s R | t]``: a point x of ``src`` goes to ``s R x + t``.
Points are (N, D) arrays of (x, y[, z]) rows in the caller's units.

Which is faster: the cost of either is dominated by forming the weighted means and the 3 x 3
cross-covariance, O(N); the 3 x 3 step itself is microseconds. ``benchmarks/bench_rigid.py``
prints the measured times (the FA3R iteration runs on plain floats, avoiding LAPACK's call
overhead).

References
----------
.. [1] S. Umeyama, "Least-squares estimation of transformation parameters between two point
       patterns", IEEE TPAMI 13(4), 1991. :doi:`10.1109/34.88573`
.. [2] J. Wu, M. Liu, Z. Zhou, R. Li, "Fast Rigid 3D Registration Solution: A Simple Method Free
       of SVD and Eigen-Decomposition", IEEE Trans. Instrum. Meas. 69(10), 2020.
       :doi:`10.1109/TIM.2020.2987495`
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["fa3r", "umeyama"]

_FA3R_MAX_ITER = 100


def _moments(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None,
             dims: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Weighted means, cross-covariance H = sum w (dst - mu_d)(src - mu_s)^T / W and src variance."""
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
        mu_s = src.mean(0)
        mu_d = dst.mean(0)
        sc = src - mu_s
        h = (dst - mu_d).T @ sc / len(src)
        var = float((sc * sc).sum()) / len(src)
        return mu_s, mu_d, h, var
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (len(src),):
        raise InputError(f"`weights` must have shape ({len(src)},), got {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any():
        raise InputError("`weights` must be finite and non-negative")
    total = float(w.sum())
    if total <= 0.0:
        raise InputError("`weights` must have a positive sum, got all zeros")
    mu_s = w @ src / total
    mu_d = w @ dst / total
    sc = src - mu_s
    h = (w[:, None] * (dst - mu_d)).T @ sc / total
    var = float(w @ (sc * sc).sum(1)) / total
    return mu_s, mu_d, h, var


def _assemble(rot: np.ndarray, h: np.ndarray, var: float, mu_s: np.ndarray, mu_d: np.ndarray,
              scale: bool) -> np.ndarray:
    s = 1.0
    if scale:
        # s = tr(R^T H) / sigma_src^2 (Umeyama eq. 42, with the trace of the signed singular values).
        s = float(np.sum(rot * h)) / var if var > 0.0 else 1.0
    t = mu_d - s * (rot @ mu_s)
    return np.c_[s * rot, t]


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
    mu_s, mu_d, h, var = _moments(src, dst, weights, (2, 3))
    u, _, vt = np.linalg.svd(h)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        u[:, -1] = -u[:, -1]  # S = diag(1, ..., 1, -1): the nearest proper rotation
    return _assemble(u @ vt, h, var, mu_s, mu_d, scale)


def _fa3r_rotation(h: np.ndarray) -> np.ndarray:
    """The proper polar factor of a 3 x 3 matrix by the FA3R fixed-point iteration (on floats)."""
    norm = float(np.sqrt(np.sum(h * h)))
    if norm == 0.0 or not np.isfinite(norm):
        return np.eye(3)
    g = h * (np.sqrt(3.0) / norm)
    # Columns h_x, h_y, h_z of the scaled cross-covariance, as plain floats.
    ax, ay, az = float(g[0, 0]), float(g[1, 0]), float(g[2, 0])
    bx, by, bz = float(g[0, 1]), float(g[1, 1]), float(g[2, 1])
    cx, cy, cz = float(g[0, 2]), float(g[1, 2]), float(g[2, 2])
    for _ in range(_FA3R_MAX_ITER):
        k = 2.0 / (ax * ax + ay * ay + az * az + bx * bx + by * by + bz * bz + cx * cx + cy * cy + cz * cz + 1.0)
        nax, nay, naz = k * (ax + by * cz - bz * cy), k * (ay + bz * cx - bx * cz), k * (az + bx * cy - by * cx)
        nbx, nby, nbz = k * (bx + cy * az - cz * ay), k * (by + cz * ax - cx * az), k * (bz + cx * ay - cy * ax)
        ncx, ncy, ncz = k * (cx + ay * bz - az * by), k * (cy + az * bx - ax * bz), k * (cz + ax * by - ay * bx)
        change = max(abs(nax - ax), abs(nay - ay), abs(naz - az), abs(nbx - bx), abs(nby - by),
                     abs(nbz - bz), abs(ncx - cx), abs(ncy - cy), abs(ncz - cz))
        ax, ay, az, bx, by, bz, cx, cy, cz = nax, nay, naz, nbx, nby, nbz, ncx, ncy, ncz
        if change <= 4e-16:
            break
    return np.array([[ax, bx, cx], [ay, by, cy], [az, bz, cz]])


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
    mu_s, mu_d, h, var = _moments(src, dst, weights, (3,))
    return _assemble(_fa3r_rotation(h), h, var, mu_s, mu_d, scale)
