"""CPD-Net (Wang et al. [1]): a learned displacement field, run with numpy alone.

A network trained without correspondences (Chamfer distance plus coherence, by
``tools/train_cpd_net.py``, on synthetic outlines that are not the test sets) predicts each model
point's motion in one forward pass; there is no per-pair optimisation. This version keeps the
paper's idea (an order-invariant network learns the displacement function, kept coherent by a
smooth field) in a form that generalizes to new shapes: a cascade of ``n_steps`` steps, each of
which

1. describes every model point by its current offsets to its ``k`` nearest target points (sorted
   by distance), its distances to them, the offsets to its ``k_model`` nearest model neighbours
   and its position, plus a max-pooled (order-invariant) summary of all model points;
2. predicts with a small MLP (linear + ReLU) attention weights over those ``k`` offsets, a
   residual and a confidence c_i in (0, 1);
3. makes the displacements coherent: the Gaussian-kernel field U W that solves
   (U^T C U + lam_s K) W = U^T C v for the raw displacements v and confidences C = diag(c), the
   M-step of CPD [2] with the network in place of the E-step, on ``n_centers`` farthest-point
   samples of the model as kernel centres (a Nystrom field: O(N n_centers^2) whatever N).

The fields of all steps share one kernel and its centres on the original model, so their sum is one
Gaussian-kernel warp: the :class:`~reglib.robust.Model` returned. ``refine`` > 0 continues with
that many CPD EM iterations [2] started from the network's field.

Everything works in normalized coordinates (each set centered, RMS radius 1) on trusted arrays;
:func:`reglib.register_points` validates and maps back. Points are (x, y) rows, 2-D only.

The weights are package data (``cpd_net_weights.npz``, under 200 kilobytes) with their
provenance (``cpd_net_weights.json``: seed, data recipe, commit, training time, final loss).

References
----------
.. [1] L. Wang, X. Li, J. Chen, Y. Fang, "Coherent Point Drift Networks: Unsupervised Learning of
       Non-Rigid Point Set Registration", arXiv:1906.03039, 2019. :doi:`10.48550/arXiv.1906.03039`
.. [2] A. Myronenko, X. Song, "Point Set Registration: Coherent Point Drift", IEEE TPAMI 32(12),
       2010. :doi:`10.1109/TPAMI.2010.46`
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np
from scipy.linalg import lapack
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from .._verdict import POOR_FIT, fit_reason
from ..errors import InputError
from ..options import check_declared, declared, option
from ..robust import Model, farthest_point_centers
from ._cpd import cpd_posterior
from ._result import WarpFit
from ._support import chamfer_spacings

__all__ = ["CPDNetOptions", "CPDNetWeights", "cpd_net_register", "load_weights"]

WEIGHTS_FILE = "cpd_net_weights.npz"
PROVENANCE_FILE = "cpd_net_weights.json"
_SIGMA2_MIN = 1e-10
_MATRIX_POINTS = 1500  # up to this many model points, one (N, N) distance matrix gives neighbours and centres


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class CPDNetOptions:
    """Options of ``register_points(method="cpd-net")``.

    Lengths are in normalized units (each set centered, RMS radius 1). The kernel width of the
    fitted warp is the one the network was trained with (``CPDNetWeights.kbeta``).

    Parameters
    ----------
    smoothness : float
        Factor on the trained smoothness weights lam_s of the cascade's steps (1: as trained;
        larger: a stiffer field).
    n_centers : int or None
        Kernel centres of the coherent field, farthest-point samples of the model (all its points
        when it has fewer); None: as many as in training (``CPDNetWeights.n_centers``, 40).
    refine : int
        CPD EM iterations [2] run after the network, started from its field (0: none).
    refine_lam : float
        Smoothness weight (lambda in [2]) of the refinement.
    refine_outlier_weight : float
        Weight w of the refinement's uniform outlier component, in [0, 1).
    """

    smoothness: float = option(1.0, kind="float", low=0, low_open=True,
                               doc="factor on the trained smoothness weights of the cascade")
    n_centers: int | None = option(None, kind="int", low=3, high=2000, optional=True,
                                   doc="kernel centres of the field (None: as trained)")
    refine: int = option(0, kind="int", low=0, high=1000, doc="CPD iterations after the network (0: none)")
    refine_lam: float = option(2.0, kind="float", low=0, low_open=True, doc="smoothness weight of the refinement")
    refine_outlier_weight: float = option(0.1, kind="float", low=0, high=1, high_open=True,
                                          doc="outlier weight w of the refinement, in [0, 1)")

    def __post_init__(self) -> None:
        check_declared(self)


@dataclass(frozen=True, eq=False)
class CPDNetWeights:
    """The trained network: ``n_steps`` MLPs of three linear layers, and the cascade's constants.

    Attributes
    ----------
    k, k_model : int
        Target neighbours and model neighbours of each model point's description.
    n_centers : int
        Kernel centres of the field in training (farthest-point samples of the model).
    ridge : float
        The small ridge on the diagonal of every field solve.
    kbeta : float
        The kernel exp(-kbeta |u - c|^2) of the coherent field (normalized units).
    lam : (n_steps,) ndarray
        Smoothness weight of each step.
    layers : tuple of tuple of ndarray
        Per step (w1, b1, w2, b2, w3, b3); w2 takes each point's hidden vector and the max over
        all points of it.
    """

    k: int
    k_model: int
    n_centers: int
    ridge: float
    kbeta: float
    lam: np.ndarray
    layers: tuple[tuple[np.ndarray, ...], ...]

    @property
    def n_steps(self) -> int:
        return len(self.layers)

    @classmethod
    def from_arrays(cls, arrays: Any) -> CPDNetWeights:
        """Read the npz form written by ``tools/train_cpd_net.py`` (``step{s}_w1`` ... ``step{s}_b3``)."""
        n = int(arrays["n_steps"])
        names = ("w1", "b1", "w2", "b2", "w3", "b3")
        layers = tuple(tuple(np.ascontiguousarray(arrays[f"step{s}_{k}"], dtype=np.float64) for k in names)
                       for s in range(n))
        return cls(k=int(arrays["k"]), k_model=int(arrays["k_model"]), n_centers=int(arrays["n_centers"]),
                   ridge=float(arrays["ridge"]), kbeta=float(arrays["kbeta"]),
                   lam=np.asarray(arrays["lam"], dtype=np.float64).reshape(n), layers=layers)


@functools.cache
def load_weights() -> CPDNetWeights:
    """The shipped weights (package data), read once."""
    with resources.files(__package__).joinpath(WEIGHTS_FILE).open("rb") as fh, np.load(fh) as arrays:
        return CPDNetWeights.from_arrays(arrays)


def provenance() -> dict[str, Any]:
    """The shipped weights' provenance: seed, data recipe, commit, training time, final loss."""
    return json.loads(resources.files(__package__).joinpath(PROVENANCE_FILE).read_text(encoding="utf-8"))


def _knn_offsets(points: np.ndarray, tree: cKDTree, source: np.ndarray, k: int) -> np.ndarray:
    """(N, k, D) offsets from each of ``points`` to its ``k`` nearest rows of ``source`` (``tree``'s),
    nearest first; the last neighbour repeats when ``source`` has fewer than ``k`` rows."""
    kk = min(k, len(source))
    _, idx = tree.query(points, k=kk)
    idx = idx.reshape(len(points), kk)
    if kk < k:
        idx = np.concatenate([idx, np.repeat(idx[:, -1:], k - kk, axis=1)], axis=1)
    return source[idx] - points[:, None, :]


def model_neighbours(u: np.ndarray, k_model: int, d2: np.ndarray | None = None) -> np.ndarray:
    """(N, k_model) indices of each model point's nearest other model points, nearest first (the
    farthest one repeated if the model has too few); ``d2``: the (N, N) squared distances if made."""
    n = len(u)
    kk = min(k_model + 1, n)
    if d2 is None:
        _, idx = cKDTree(u).query(u, k=kk)
        idx = idx.reshape(n, kk)
    else:
        idx = np.argpartition(d2, kk - 1, axis=1)[:, :kk] if kk < n else np.tile(np.arange(n), (n, 1))
        idx = np.take_along_axis(idx, np.argsort(np.take_along_axis(d2, idx, 1), axis=1, kind="stable"), 1)
    idx = idx[:, 1:]
    if idx.shape[1] < k_model:
        fill = idx[:, -1:] if idx.shape[1] else np.arange(n)[:, None]
        idx = np.concatenate([idx, np.repeat(fill, k_model - idx.shape[1], axis=1)], axis=1)
    return idx


def step_features(x: np.ndarray, offsets: np.ndarray, x_nbrs: np.ndarray) -> np.ndarray:
    """The (N, 3 k + 2 k_model + 2) description of each model point at current positions ``x``:
    target offsets, their lengths, model-neighbour offsets, position."""
    n = len(x)
    dist = np.sqrt((offsets * offsets).sum(-1))
    return np.concatenate([offsets.reshape(n, -1), dist, (x_nbrs - x[:, None, :]).reshape(n, -1), x], axis=1)


def _mlp(feat: np.ndarray, layer: tuple[np.ndarray, ...]) -> np.ndarray:
    w1, b1, w2, b2, w3, b3 = layer
    h1 = np.maximum(feat @ w1 + b1, 0.0)
    pooled = h1.max(0)
    h = w1.shape[1]
    h2 = np.maximum(h1 @ w2[:h] + (pooled @ w2[h:] + b2), 0.0)
    return h2 @ w3 + b3


def _softmax_rows(z: np.ndarray) -> np.ndarray:
    z = z - z.max(1, keepdims=True)
    np.exp(z, out=z)
    z /= z.sum(1, keepdims=True)
    return z


def field_centers(u: np.ndarray, m: int, d2: np.ndarray | None = None) -> np.ndarray:
    """(min(m, N), D) farthest-point samples of the centered model ``u``, the first its point farthest
    from the origin (so that the choice does not depend on the order of the points); ``d2``: the
    (N, N) squared distances if made."""
    start = int((u * u).sum(1).argmax())
    if d2 is None:
        return farthest_point_centers(u, m, None, start=start)
    chosen = [start]
    near = d2[start].copy()
    for _ in range(1, min(m, len(u))):
        i = int(near.argmax())
        if near[i] <= 1e-24:
            break
        chosen.append(i)
        np.minimum(near, d2[i], out=near)
    return u[chosen].copy()


class _Field:
    """The coherent field U W on fixed centres (U the (N, M) kernel matrix at the model points, K
    the centres' Gram matrix): for raw displacements v and confidences C = diag(c) it solves
    (U^T C U + lam K + ridge I) W = U^T C v, the weighted, regularized least squares of [2]'s M-step."""

    def __init__(self, u: np.ndarray, centers: np.ndarray, kbeta: float, ridge: float):
        self.basis = np.exp(-kbeta * cdist(u, centers, "sqeuclidean"))  # (N, M)
        self.gram = np.exp(-kbeta * cdist(centers, centers, "sqeuclidean"))
        self.ridge = ridge

    def solve(self, v: np.ndarray, conf: np.ndarray, lam: float) -> np.ndarray:
        uc = self.basis * conf[:, None]
        a = uc.T @ self.basis
        a += lam * self.gram
        a.flat[:: a.shape[0] + 1] += self.ridge
        b = uc.T @ v
        _, z, info = lapack.dposv(a, b)
        if info != 0 or not np.isfinite(z).all():
            z = np.linalg.lstsq(a, b, rcond=None)[0]
        return z


def run_network(u: np.ndarray, y: np.ndarray, weights: CPDNetWeights, field: _Field, nbrs: np.ndarray,
                tree: cKDTree, smoothness: float = 1.0) -> np.ndarray:
    """The cascade: kernel weights (M, D) of the field on ``field``'s centres moving ``u`` onto ``y``
    (``tree`` its k-d tree), ``nbrs`` the model's neighbours (:func:`model_neighbours`)."""
    x = u.copy()
    total = np.zeros((field.basis.shape[1], u.shape[1]))
    k = weights.k
    for s, layer in enumerate(weights.layers):
        offsets = _knn_offsets(x, tree, y, k)
        out = _mlp(step_features(x, offsets, x[nbrs]), layer)
        attn = _softmax_rows(out[:, :k].copy())
        v = np.einsum("nk,nkd->nd", attn, offsets) + out[:, k:k + 2]
        conf = 1.0 / (1.0 + np.exp(-out[:, k + 2]))
        w = field.solve(v, conf, float(weights.lam[s]) * smoothness)
        total += w
        x += field.basis @ w
    return total


def _refine(u: np.ndarray, y: np.ndarray, field: _Field, w: np.ndarray,
            opts: CPDNetOptions) -> tuple[np.ndarray, float]:
    """``opts.refine`` CPD EM iterations [2] on the field's centres, from kernel weights ``w``."""
    n, d = y.shape
    ty = u + field.basis @ w
    # start at the network's residual scale (CPD's own start, the mean of all squared distances,
    # would begin the registration again from the coarsest scale)
    sigma2 = max(float(np.mean(cdist(ty, y, "sqeuclidean").min(1))) / d, 1e-4)
    basis, gram = field.basis, field.gram
    for _ in range(opts.refine):
        p = cpd_posterior(y, ty, sigma2, opts.refine_outlier_weight)
        p1 = p.sum(1)
        n_p = float(p1.sum())
        if n_p <= 1e-12:
            break
        px = p @ y
        # minimize sum_mn P_mn |y_n - u_m - U_m W|^2 + lam sigma^2 tr(W^T K W)
        ub = basis * p1[:, None]
        a = ub.T @ basis + opts.refine_lam * sigma2 * gram
        a.flat[:: a.shape[0] + 1] += 1e-10 * n_p
        b = basis.T @ (px - p1[:, None] * u)
        _, sol, info = lapack.dposv(a, b)
        if info != 0 or not np.isfinite(sol).all():
            break
        w = sol
        ty = u + basis @ w
        pt1 = p.sum(0)
        sigma2 = ((pt1 * (y * y).sum(1)).sum() - 2.0 * (px * ty).sum() + (p1 * (ty * ty).sum(1)).sum()) / (n_p * d)
        sigma2 = max(float(sigma2), _SIGMA2_MIN)
    return w, sigma2


def cpd_net_register(u: np.ndarray, y: np.ndarray, opts: CPDNetOptions, rng: np.random.Generator) -> WarpFit:
    """CPD-Net of the normalized model ``u`` onto the normalized target ``y`` (2-D).

    Raises
    ------
    InputError
        When the points are not 2-D (the shipped network is trained on planar outlines).
    """
    if u.shape[1] != 2:
        raise InputError(f"method 'cpd-net' registers 2-D points (D = 2), got D = {u.shape[1]}")
    weights = load_weights()
    d2 = cdist(u, u, "sqeuclidean") if len(u) <= _MATRIX_POINTS else None
    centers = field_centers(u, opts.n_centers or weights.n_centers, d2)
    field = _Field(u, centers, weights.kbeta, weights.ridge)
    tree = cKDTree(y)
    w = run_network(u, y, weights, field, model_neighbours(u, weights.k_model, d2), tree, opts.smoothness)
    moved = u + field.basis @ w
    if opts.refine:
        w, sigma2 = _refine(u, y, field, w, opts)
        moved = u + field.basis @ w
        reach = 3.0 * float(np.sqrt(sigma2))
    else:
        # reach: three times the robust residual scale of the moved model to its nearest targets
        dist = tree.query(moved)[0]
        reach = 3.0 * 1.4826 * float(np.median(dist))
    # The network answers in one pass whatever the input; its own fit says whether the answer is one.
    reason = fit_reason(chamfer_spacings(moved, y, tree)) if np.isfinite(moved).all() else POOR_FIT
    return WarpFit(model=Model(None, centers, weights.kbeta, w), n_iter=int(opts.refine), converged=reason is None,
                   reach=max(reach, 0.05), reason=reason)

