"""Whether an estimate explains the scene: the ``reason`` of a :class:`FilterResult` that failed.

The codes are :mod:`reglib._verdict`'s; the checks measure the estimate and name the first that fails.

An estimator always returns its best transformation; these checks say when that best is not an
answer, from the inliers and the transformation alone (no ground truth):

* ``TOO_FEW_INLIERS``: fewer inliers than twice the affine part's unknowns (``2 D (D + 1)``),
  than two per kernel centre of the transformation unless one affine map alone explains them (a
  field of M centres can pass through about M random matches, while true ones give several per
  centre; a set an affine map explains needs no field), or hardly more than false matches would put within 3 sigma of a
  fixed transformation by chance (the putative matches' density times that ball).
* ``SMALL_CLUSTER``: the inliers are one small cluster in both images (their median distance
  to their median under :data:`CLUSTER_SPREAD` of all matches' in src *and* in dst, about 1 % of
  the area; a median, so a few stray inliers elsewhere do not hide the cluster): a few false
  matches that happen to agree locally, as when a coarse level locks onto them. A true close-up
  (zoom) is small in one image only.
* ``FOLDING``: the transformation changes orientation inside the inliers' region (the sign of
  det df/dx differs from the majority at more than :data:`MAX_FOLDED` of them): no one-to-one
  motion does that; the field has bent to follow false matches.

Everything is in normalized coordinates on trusted arrays (validated upstream).
"""
from __future__ import annotations

from math import gamma as gamma_fn
from math import pi, sqrt

import numpy as np

from .._transforms import kernel_matrix
from .._verdict import FOLDING, SMALL_CLUSTER, TOO_FEW_INLIERS, Reason
from ._core import Model

__all__ = ["CLUSTER_SPREAD", "MAX_FOLDED", "failure_reason", "folded"]

CLUSTER_SPREAD = 0.1  # inliers spread less than this share of all matches' spread, in src and dst: one small cluster
MAX_FOLDED = 0.05  # share of the inliers at which the field may have the minority orientation, at most
_FOLD_SAMPLE = 128  # inliers the Jacobian is evaluated at, at most (evenly spaced)
_SPREAD_SAMPLE = 1000  # points the spreads are measured on, at most (evenly spaced)


def _median(a: np.ndarray) -> np.ndarray:
    """``np.median(a, 0)`` of a non-empty, finite array, by one partition (the same values: the
    middle element, or the mean of the two middle ones)."""
    n = len(a)
    h = n // 2
    if n % 2:
        return np.partition(a, h, axis=0)[h]
    part = np.partition(a, (h - 1, h), axis=0)
    return (part[h - 1] + part[h]) / 2.0


def _spreads(u: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Median distance of the points to their coordinate-wise median, in src and in dst (one
    partition for both sets' coordinates, one for both sets' distances)."""
    if not len(u):
        return 0.0, 0.0
    d = u.shape[1]
    both = np.concatenate((u, y), axis=1)
    both -= _median(both)
    both *= both
    dist = np.empty((len(u), 2))
    np.sum(both[:, :d], axis=1, out=dist[:, 0])
    np.sum(both[:, d:], axis=1, out=dist[:, 1])
    np.sqrt(dist, out=dist)
    su, sy = _median(dist)
    return float(su), float(sy)


def _affine_explains(u: np.ndarray, y: np.ndarray, sigma: float, share: float = 0.9) -> bool:
    """Whether one affine map fitted to the matches puts ``share`` of them within a tolerance.

    The tolerance is 3 sigma, or 5 % of the matches' RMS radius in y when that is larger: random
    matches leave affine residuals of the order of their spread, so this separates them whatever
    sigma is (the scale of a few matches, some repeated, can be far below their keypoints' noise).
    """
    design = np.c_[u, np.ones(len(u))]
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    e2 = ((design @ coef - y) ** 2).sum(1)
    radius = float(np.sqrt(((y - y.mean(0)) ** 2).sum(1).mean()))
    tol = max(3.0 * sigma, 0.05 * radius)
    return bool(np.mean(e2 <= tol * tol) >= share)


def _det_jacobian(model: Model, u: np.ndarray) -> np.ndarray:
    """det dg/du of the normalized model at ``u`` (its sign is that of the caller's units' map)."""
    n, d = u.shape
    jac = np.broadcast_to(np.eye(d), (n, d, d)).copy() if model.linear is None else model.linear.jacobian(u)
    if len(model.centers):
        k = kernel_matrix(u, model.centers, model.beta)  # (n, M)
        # d/du_j sum_m k_m w_mi = -2 beta sum_m k_m w_mi (u_j - c_mj)
        kw = k @ model.weights  # (n, D): sum_m k_m w_mi
        wc = (model.weights[:, :, None] * model.centers[:, None, :]).reshape(len(model.centers), d * d)
        kwc = (k @ wc).reshape(n, d, d)  # sum_m k_m w_mi c_mj
        jac += -2.0 * model.beta * (kw[:, :, None] * u[:, None, :] - kwc)
    if d == 2:  # in closed form (np.linalg.det factorizes each 2 x 2 matrix)
        return jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    return np.linalg.det(jac)


def failure_reason(u: np.ndarray, y: np.ndarray, inliers: np.ndarray, sigma: float, model: Model,
                   min_matches: int, volume: float | None = None) -> Reason | None:
    """The first check of the module's list that fails, or None.

    ``u``, ``y``: normalized matches; ``inliers``: the primary estimate's inliers (a secondary
    layer's matches are explained by their own motion, not by ``model``); ``sigma``: the
    inliers' residual scale; ``model``: the estimate (all normalized); ``volume``: the extent of
    all of ``y``, ``max(prod(ptp(y, 0)), 1)``, when the caller has it.
    """
    n, d = u.shape
    idx = np.flatnonzero(inliers)
    k = len(idx)
    # Medians and extents of evenly spaced samples (a spread needs no more).
    every = np.linspace(0, n - 1, min(n, _SPREAD_SAMPLE)).astype(np.intp) if n > _SPREAD_SAMPLE else None
    y_every = y if every is None else y[every]
    if every is not None or volume is None:  # (the extent of a sample, or of all matches)
        volume = max(float(np.prod(y_every.max(0) - y_every.min(0))), 1.0)
    chance = n * pi ** (d / 2) / gamma_fn(d / 2 + 1) * (3.0 * sigma) ** d / volume
    if k < max(min_matches, 2 * d * (d + 1), chance + 5.0 * sqrt(chance) + 1.0):
        return TOO_FEW_INLIERS
    if k < 2 * len(model.centers) and not _affine_explains(u[idx], y[idx], sigma):
        # the field's capacity (a field of M centres passes through about M random matches)
        # matters only when the inliers need the field: an affine motion alone is its own proof
        return TOO_FEW_INLIERS
    some = idx[np.linspace(0, k - 1, _SPREAD_SAMPLE).astype(np.intp)] if k > _SPREAD_SAMPLE else idx
    inner_u, inner_y = _spreads(u[some], y[some])
    outer_u, outer_y = _spreads(u, y) if every is None else _spreads(u[every], y_every)
    if inner_u < CLUSTER_SPREAD * outer_u and inner_y < CLUSTER_SPREAD * outer_y:
        return SMALL_CLUSTER
    sample = idx[np.linspace(0, k - 1, _FOLD_SAMPLE).astype(np.intp)] if k > _FOLD_SAMPLE else idx
    positive = float(np.mean(_det_jacobian(model, u[sample]) > 0))
    if min(positive, 1.0 - positive) > MAX_FOLDED:
        return FOLDING
    return None


def folded(u: np.ndarray, inliers: np.ndarray, model: Model) -> np.ndarray:
    """The inliers at which ``model`` has the minority orientation (the sign of det dg/du that
    fewer of them have): where it folds, as a (N,) mask."""
    idx = np.flatnonzero(inliers)
    out = np.zeros(len(inliers), dtype=bool)
    if not len(idx):
        return out
    positive = np.concatenate([_det_jacobian(model, u[idx[s:s + 4096]]) > 0 for s in range(0, len(idx), 4096)])
    out[idx] = positive if np.count_nonzero(positive) * 2 < len(idx) else ~positive
    return out
