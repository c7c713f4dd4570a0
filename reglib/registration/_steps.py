"""What every rigid ICP loop of the package shares: one weighted step, point samples, the spacing.

- :func:`plane_step`: the weighted linearized point-to-plane step (Chen & Medioni [1]; Low [2]):
  the 6 x 6 (2-D: 3 x 3) normal equations of the residuals n_j . (x_i - y_j) with the rotation
  linearized about the matched points' weighted centroid, applied as an exact rotation
  (Rodrigues' formula, :func:`rotation_from_vector`).
- :func:`point_step`: the closed-form weighted point-to-point step (Umeyama's SVD or FA3R,
  :mod:`reglib._geometry`).
- :func:`sample_rows` and :func:`point_spacing`: seeded row samples and the median
  nearest-neighbor distance of a point set.

Used by :mod:`reglib.registration._icp`, :mod:`reglib.registration._start` and
:mod:`reglib.registration._hmrf`. Trusted input: (K, D) float64 arrays, D in {2, 3}, weights
non-negative with a positive sum; nothing here validates.

References
----------
.. [1] Y. Chen, G. Medioni, "Object modelling by registration of multiple range images", Image
       and Vision Computing 10(3), 1992. :doi:`10.1016/0262-8856(92)90066-C`
.. [2] K.-L. Low, "Linear Least-Squares Optimization for Point-to-Plane ICP Surface
       Registration", Tech. Rep. TR04-004, UNC Chapel Hill, 2004.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._geometry import fa3r_rotation, nearest_rotation

__all__ = ["plane_step", "point_spacing", "point_step", "rotation_from_vector", "sample_rows"]


def rotation_from_vector(omega: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation exp([omega]_x) (3-D, omega (3,)) or by the angle omega[0] (2-D, omega (1,))."""
    if len(omega) == 1:
        c, s = np.cos(omega[0]), np.sin(omega[0])
        return np.array([[c, -s], [s, c]])
    theta = float(np.linalg.norm(omega))
    kx = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]])
    if theta < 1e-12:
        return np.eye(3) + kx
    return np.eye(3) + np.sin(theta) / theta * kx + (1.0 - np.cos(theta)) / theta**2 * (kx @ kx)


def plane_step(x: np.ndarray, y: np.ndarray, n: np.ndarray,
               w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One weighted linearized point-to-plane step of the points ``x`` toward the planes (y, n).

    Trusted input; does not validate.

    Parameters
    ----------
    x, y, n : (K, D) ndarray
        Moved model points, their matched target points and the unit normals there.
    w : (K,) ndarray
        Weights of the pairs.

    Returns
    -------
    rotation : (D, D) ndarray
        The step's rotation R.
    center : (D,) ndarray
        The weighted centroid c of ``x`` the rotation is linearized about.
    shift : (D,) ndarray
        The step's translation: x goes to R (x - c) + c + shift.
    """
    dim = x.shape[1]
    total = float(w.sum())
    c = w @ x / total
    p = x - c
    if dim == 3:
        a_rot = np.cross(p, n)
    else:
        a_rot = (p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0])[:, None]
    a = np.concatenate([a_rot, n], axis=1)
    b = ((y - x) * n).sum(1)
    aw = a * w[:, None]
    lhs = aw.T @ a
    rhs = aw.T @ b
    lhs[np.diag_indices_from(lhs)] += 1e-12 * max(float(np.trace(lhs)), 1e-300)
    try:
        xi = np.linalg.solve(lhs, rhs)
    except np.linalg.LinAlgError:
        xi = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    n_rot = a_rot.shape[1]
    return rotation_from_vector(xi[:n_rot]), c, xi[n_rot:]


def point_step(src: np.ndarray, dst: np.ndarray, w: np.ndarray, solver: str) -> np.ndarray:
    """The weighted least-squares rigid map ``[R | t]`` (D, D + 1) of ``src`` onto ``dst``.

    The rotation of the (unnormalized) weighted cross-covariance, by SVD (``solver="svd"``) or
    FA3R (``"fa3r"``, 3-D). Trusted input; does not validate (see
    :func:`reglib.registration._procrustes.umeyama` for the validating form).
    """
    total = float(w.sum())
    mu_s = w @ src / total
    mu_d = w @ dst / total
    h = (w[:, None] * (dst - mu_d)).T @ (src - mu_s)
    rot = fa3r_rotation(h) if solver == "fa3r" else nearest_rotation(h)
    return np.c_[rot, mu_d - rot @ mu_s]


def sample_rows(n: int, k: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of ``k`` of ``n`` rows drawn without replacement (all ``n`` when n <= k)."""
    if n <= k:
        return np.arange(n)
    return np.sort(rng.choice(n, size=k, replace=False))


def point_spacing(tree: cKDTree, points: np.ndarray, rng: np.random.Generator) -> float:
    """Median distance from a point of ``points`` to its nearest other point (on 1000 samples).

    Trusted input: ``tree`` is built on ``points``. Returns 0 when all points coincide.
    """
    probe = points[sample_rows(len(points), 1000, rng)]
    d, _ = tree.query(probe, k=2)
    d = np.asarray(d)[:, 1]
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 0.0
