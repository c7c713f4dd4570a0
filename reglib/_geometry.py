"""Rotations and rigid (or similarity) maps in 2-D and 3-D, shared by :mod:`reglib.robust` and
:mod:`reglib.registration`.

- :func:`signed_svd` and :func:`nearest_rotation`: the rotation nearest (in the Frobenius norm)
  to a square matrix H, the proper polar factor R = U diag(1, ..., 1, det(U V^T)) V^T of its SVD
  H = U S V^T (Umeyama [1], Lemma), which is never a reflection;
- :func:`fa3r_rotation`: the same rotation in 3-D without SVD or eigen-decomposition, by the
  fixed-point iteration of Wu, Liu, Zhou and Li [2] (FA3R);
- :func:`rotation_angle`: the angle of a rotation from its trace;
- :func:`umeyama_similarity`: the weighted least-squares map ``[s R | t]`` of corresponding
  points, minimizing sum_i w_i |dst_i - (s R src_i + t)|^2 (Umeyama [1]).

Points are (N, D) rows (x, y[, z]), D in {2, 3}. Every function here trusts its input (float64
arrays of the stated shapes, finite, weights non-negative with a positive sum) and does not
validate it; :mod:`reglib.registration._procrustes` is the validating public front of the last one.

References
----------
.. [1] S. Umeyama, "Least-squares estimation of transformation parameters between two point
       patterns", IEEE TPAMI 13(4), 1991. :doi:`10.1109/34.88573`
.. [2] J. Wu, M. Liu, Z. Zhou, R. Li, "Fast Rigid 3D Registration Solution: A Simple Method Free
       of SVD and Eigen-Decomposition", IEEE Trans. Instrum. Meas. 69(10), 2020.
       :doi:`10.1109/TIM.2020.2987495`
"""
from __future__ import annotations

from typing import Literal

import numpy as np

__all__ = ["fa3r_rotation", "nearest_rotation", "rotation_angle", "signed_svd", "umeyama_similarity"]

_FA3R_MAX_ITER = 100


def signed_svd(h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SVD of (..., D, D) matrices with the sign fix that makes ``u @ vt`` a proper rotation.

    Trusted input: finite float arrays; does not validate.

    Parameters
    ----------
    h : (..., D, D) ndarray
        Matrices (typically cross-covariances sum_i w_i dst_i src_i^T of centered points).

    Returns
    -------
    u : (..., D, D) ndarray
        Left singular vectors, the last column negated where det(U V^T) < 0.
    s : (..., D) ndarray
        Singular values, the last negated likewise (so sum(s) = tr(R^T H), the trace in
        Umeyama's scale, eq. 42 of [1]).
    vt : (..., D, D) ndarray
        Right singular vectors (transposed), as :func:`numpy.linalg.svd` gives them.

    Examples
    --------
    >>> import numpy as np
    >>> u, s, vt = signed_svd(np.diag([2.0, 1.0, -0.5]))          # a reflection
    >>> bool(np.isclose(np.linalg.det(u @ vt), 1.0)), s.round(3).tolist()
    (True, [2.0, 1.0, -0.5])
    """
    u, s, vt = np.linalg.svd(h)
    d = np.where(np.linalg.det(u @ vt) < 0.0, -1.0, 1.0)
    u[..., :, -1] *= d[..., None]
    s[..., -1] *= d
    return u, s, vt


def nearest_rotation(h: np.ndarray) -> np.ndarray:
    """The proper rotations nearest to (..., D, D) matrices: R = U diag(1, .., det(U V^T)) V^T.

    For a cross-covariance H = sum_i w_i (dst_i - mu_d)(src_i - mu_s)^T this is the rotation of
    the weighted least-squares rigid map of src onto dst ([1]). Trusted input; does not validate.

    Parameters
    ----------
    h : (..., D, D) ndarray
        Matrices, one or a stack.

    Returns
    -------
    (..., D, D) ndarray
        Rotations, det = +1 (a reflection is never returned).

    Examples
    --------
    >>> import numpy as np
    >>> r = nearest_rotation(np.array([[0.0, -2.0], [1.0, 0.0]]))
    >>> r.round(12).tolist()
    [[0.0, -1.0], [1.0, 0.0]]
    """
    u, _, vt = signed_svd(h)
    return u @ vt


def rotation_angle(rot: np.ndarray) -> np.ndarray:
    """Angles in radians, in [0, pi], of (..., D, D) rotations, from the trace.

    cos(theta) = (tr R - 1) / 2 in 3-D and tr R / 2 in 2-D, clipped to [-1, 1]. Trusted input
    (rotations, or near-rotations); does not validate.

    Parameters
    ----------
    rot : (..., D, D) ndarray
        Rotations, D in {2, 3}.

    Returns
    -------
    (...) ndarray
        Angles (a 0-d value for one matrix).

    Examples
    --------
    >>> import numpy as np
    >>> c, s = np.cos(0.5), np.sin(0.5)
    >>> round(float(rotation_angle(np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]))), 12)
    0.5
    """
    dim = rot.shape[-1]
    tr = np.trace(rot, axis1=-2, axis2=-1)
    cos = (tr - 1.0) / 2.0 if dim == 3 else tr / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def fa3r_rotation(h: np.ndarray) -> np.ndarray:
    """The rotation nearest to a 3 x 3 matrix by the FA3R fixed-point iteration [2].

    With the columns h_x, h_y, h_z of H the iteration is h_x <- k (h_x + h_y x h_z),
    h_y <- k (h_y + h_z x h_x), h_z <- k (h_z + h_x x h_y) with k = 2 / (|H|_F^2 + 1), i.e.
    H <- k (H + cof H); its fixed point is the proper polar factor of H, the rotation
    :func:`nearest_rotation` gives. It starts from H scaled to |H|_F^2 = 3 (the value at a
    rotation), runs on plain floats (no LAPACK call) and stops at machine precision or after 100
    steps. Trusted input; does not validate.

    Parameters
    ----------
    h : (3, 3) ndarray
        A cross-covariance.

    Returns
    -------
    (3, 3) ndarray
        The rotation; the identity for a zero or non-finite ``h``.

    Examples
    --------
    >>> import numpy as np
    >>> h = np.random.default_rng(0).normal(size=(3, 3))
    >>> bool(np.allclose(fa3r_rotation(h), nearest_rotation(h), atol=1e-12))
    True
    """
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


def umeyama_similarity(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None, *,
                       scale: bool = False, solver: Literal["svd", "fa3r"] = "svd") -> np.ndarray:
    """Weighted least-squares rigid (or similarity) map ``[s R | t]`` of ``src`` onto ``dst`` [1].

    The rotation is that of the weighted cross-covariance H = sum_i w_i (dst_i - mu_d)
    (src_i - mu_s)^T / W: by SVD (:func:`nearest_rotation`) or by FA3R (:func:`fa3r_rotation`,
    3-D only); with ``scale`` the scale is s = tr(R^T H) / sigma_src^2 (eq. 42 of [1]) and
    t = mu_d - s R mu_s. Trusted input; does not validate.

    Parameters
    ----------
    src, dst : (N, D) float64 ndarray
        Corresponding points (row i of ``src`` goes to row i of ``dst``), N >= 1, D in {2, 3}.
    weights : (N,) float64 ndarray, optional
        Non-negative weights with a positive sum; all ones when omitted.
    scale : bool
        Also estimate the scale s (c in [1]); otherwise s = 1.
    solver : {"svd", "fa3r"}
        How the rotation is found ("fa3r": D = 3 only).

    Returns
    -------
    (D, D + 1) ndarray
        ``[s R | t]``: a point x of ``src`` goes to ``s R x + t``, det R = +1.

    Examples
    --------
    >>> import numpy as np
    >>> src = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    >>> dst = 3.0 * src[:, ::-1] * [-1.0, 1.0] + 1.0       # rotated by 90 degrees, scaled by 3, shifted
    >>> bool(np.allclose(umeyama_similarity(src, dst, scale=True), [[0.0, -3.0, 1.0], [3.0, 0.0, 1.0]]))
    True
    """
    if weights is None:
        mu_s = src.mean(0)
        mu_d = dst.mean(0)
        sc = src - mu_s
        h = (dst - mu_d).T @ sc / len(src)
        var = float((sc * sc).sum()) / len(src)
    else:
        w = weights
        total = float(w.sum())
        mu_s = w @ src / total
        mu_d = w @ dst / total
        sc = src - mu_s
        h = (w[:, None] * (dst - mu_d)).T @ sc / total
        var = float(w @ (sc * sc).sum(1)) / total
    rot = fa3r_rotation(h) if solver == "fa3r" else nearest_rotation(h)
    s = 1.0
    if scale:
        # s = tr(R^T H) / sigma_src^2 (Umeyama eq. 42, with the trace of the signed singular values).
        s = float(np.sum(rot * h)) / var if var > 0.0 else 1.0
    t = mu_d - s * (rot @ mu_s)
    return np.c_[s * rot, t]
