"""Rotation hypotheses of :mod:`reglib.registration._sc_l2e`: the candidates, their score, the map back.

In 2-D the candidates are the rotations by angle bins ranked by how well the rotated descriptors
agree; in 3-D the principal-axes frames of the two sets. Each is scored by the fit of the
registered model (:func:`_fit_score`); the winner's map, fitted in the rotated frame, is taken
back to the model's frame exactly by :func:`_unrotate`.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._transforms import LinearPart
from ..features import rotate_bins
from ..robust import Model
from ._sc_options import RegistrationOptions


def _fit_score(x: np.ndarray, y: np.ndarray, y_tree: cKDTree, sigma2: float) -> float:
    """Mean Gaussian weight of nearest-neighbor distances, model -> target and target -> model.

    The first term is the L2E criterion's data term for the registered model against its nearest
    targets; the second keeps a warp that folds the model onto one part of the target from winning.
    """
    to_y = y_tree.query(x)[0]
    to_x = cKDTree(x).query(y)[0]
    return float(np.exp(-to_y**2 / (2.0 * sigma2)).mean() + np.exp(-to_x**2 / (2.0 * sigma2)).mean())


def _rotation_candidates(us: np.ndarray, ys: np.ndarray, hx: np.ndarray, hy: np.ndarray,
                         opts: RegistrationOptions) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Initial rotations to try, the identity always first, each with the model's descriptors under it when known."""
    d = us.shape[1]
    if not opts.rotation:
        return [(np.eye(d), hx)]
    if d == 2:
        # rank the angle-bin rotations by the descriptors' mean best cost; rotating the set by one
        # angle bin shifts the histograms cyclically, so nothing is recomputed. A screen only: the
        # Hellinger distance |sqrt(a) - sqrt(b)|^2 = 2 - 2 sqrt(a).sqrt(b) (within a factor 2 of
        # chi^2) costs one matrix product for all angles.
        root_x, root_y = np.sqrt(hx), np.sqrt(hy)
        costs = []
        for k in range(opts.n_angle):
            sim = rotate_bins(root_x, k, n_angle=opts.n_angle) @ root_y.T
            costs.append(float(-sim.max(1).mean() - sim.max(0).mean()))
        order = [k for k in np.argsort(costs, kind="stable") if k != 0][:max(opts.n_hypotheses - 1, 0)]
        angles = 2 * np.pi * np.r_[0, order] / opts.n_angle
        return [(np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]), rotate_bins(hx, k, n_angle=opts.n_angle))
                for a, k in zip(angles, np.r_[0, order], strict=True)]
    # 3-D: the rotations taking the model's principal axes onto the target's (four sign choices
    # with determinant +1), after the identity
    _, _, vu = np.linalg.svd(us - us.mean(0), full_matrices=False)
    _, _, vy = np.linalg.svd(ys - ys.mean(0), full_matrices=False)
    out = [np.eye(3)]
    for signs in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        r = vy.T @ np.diag(signs) @ vu
        if np.linalg.det(r) < 0:
            r = vy.T @ np.diag(signs) @ np.diag([1.0, 1.0, -1.0]) @ vu
        out.append(r)
    return [(r, hx if i == 0 else None) for i, r in enumerate(out[:opts.n_hypotheses])]


def _affine(model: Model) -> np.ndarray:
    """[A | t] of the model's linear part (the registration's models are all affine)."""
    d = model.centers.shape[1]
    return model.linear.matrix if model.linear is not None else np.c_[np.eye(d), np.zeros(d)]


def _unrotate(model: Model, rot: np.ndarray) -> Model:
    """The map u -> g(R u) as a model on u: exact, since exp(-beta |R u - c|^2) = exp(-beta |u - R^T c|^2)."""
    lin = _affine(model)
    return Model(LinearPart("affine", np.c_[lin[:, :-1] @ rot, lin[:, -1]]), model.centers @ rot, model.beta,
                 model.weights)
