"""The initial alignment of rigid ICP (``init``), and the global search behind ``init="search"``.

``"given"`` starts from the caller's pose; ``"centroid"`` from the identity rotation with the
centroids aligned; ``"search"`` (the default) adds a global start, since plain local ICP fails
beyond a few tens of degrees:

1. A deterministic super-Fibonacci set of ``n_rotations`` rotations covering SO(3) (Alexa [1];
   in 2-D, equally spaced angles) up to ``init_max_angle``, each with the centroids aligned, and
   the caller's pose, are all refined at once by ``init_iter`` trimmed point-to-point steps on
   ``init_points`` model samples against a target sample (one batched nearest-target lookup,
   :class:`VoxelNearest`, and one batched 3 x 3 SVD per step), and scored by a smooth
   largest-common-point-set measure mean(max(0, 1 - (d / tau)^2)), tau = twice the target
   sample's spacing.
2. The best ``init_keep`` go through more steps on more points against the whole target; the
   winner starts the robust ICP, except that the caller's pose is kept whenever it scores
   within ``init_margin`` of the winner (so scans that are roughly aligned stay so).
3. The caller's pose and the runner-up are handed on as well (:attr:`Start.others`): the robust
   ICP's coarse stage (:mod:`reglib.registration._icp`) converges from each and keeps the best,
   since after ten trimmed steps the search's score can still prefer a wrong pose that the
   converged one does not.

A hypothesis whose refinement drifted more than 20 degrees beyond ``init_max_angle`` cannot win:
the default range, 90 degrees, is a prior, and a deliberate one. Searching all of SO(3)
(``init_max_angle=180``) finds, for partial views of near-symmetric shapes (boxes, faces, height
fields seen from the front), a 180-degree twin that covers more of the target than the true,
partially overlapping pose, and the largest-common-point-set score then prefers the twin.

Points are (N, D) rows (x, y[, z]), D in {2, 3}, in the caller's units; everything here trusts
its input (validated by :func:`reglib.registration._icp.icp_register`).

References
----------
.. [1] M. Alexa, "Super-Fibonacci Spirals: Fast, Low-Discrepancy Sampling of SO(3)", CVPR 2022.
       :doi:`10.1109/CVPR52688.2022.00811`
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .._geometry import nearest_rotation, rotation_angle
from ._icp_options import ICPLoopOptions
from ._steps import point_spacing, sample_rows

__all__ = ["ANGLE_SLACK", "Start", "VoxelNearest", "batch_trimmed_icp", "initial_alignment", "rotation_hypotheses"]

ANGLE_SLACK = 20.0     # degrees a hypothesis may drift beyond init_max_angle and still win
_RUNNERS = 1           # runners-up of the search (besides the caller's pose) the coarse stage also tries
_PSI = 1.533751168755204288118041  # Alexa's super-Fibonacci constant (psi^4 = psi + 4)


def rotation_hypotheses(dim: int, n: int, max_angle_deg: float) -> np.ndarray:
    """Deterministic rotations (K, D, D) covering SO(D) up to ``max_angle_deg`` from the identity.

    3-D: Alexa's super-Fibonacci spiral of ``n`` unit quaternions; 2-D: ``n`` equally spaced
    angles. The identity is always first.
    """
    limit = np.deg2rad(max_angle_deg) + 1e-12
    if dim == 2:
        ang = 2.0 * np.pi * np.arange(1, n) / n
        ang = np.where(ang > np.pi, ang - 2.0 * np.pi, ang)
        ang = ang[np.abs(ang) <= limit]
        c, s = np.cos(ang), np.sin(ang)
        rots = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
        return np.concatenate([np.eye(2)[None], rots])
    s = np.arange(n) + 0.5
    r = np.sqrt(s / n)
    big_r = np.sqrt(1.0 - s / n)
    alpha = 2.0 * np.pi * s / np.sqrt(2.0)
    beta = 2.0 * np.pi * s / _PSI
    q = np.stack([r * np.sin(alpha), r * np.cos(alpha), big_r * np.sin(beta), big_r * np.cos(beta)], 1)
    w, x, y, z = q[:, 3], q[:, 0], q[:, 1], q[:, 2]
    angle = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    keep = (angle <= limit) & (angle > 1e-9)
    w, x, y, z = w[keep], x[keep], y[keep], z[keep]
    rots = np.empty((len(w), 3, 3))
    rots[:, 0, 0] = 1 - 2 * (y * y + z * z)
    rots[:, 0, 1] = 2 * (x * y - z * w)
    rots[:, 0, 2] = 2 * (x * z + y * w)
    rots[:, 1, 0] = 2 * (x * y + z * w)
    rots[:, 1, 1] = 1 - 2 * (x * x + z * z)
    rots[:, 1, 2] = 2 * (y * z - x * w)
    rots[:, 2, 0] = 2 * (x * z - y * w)
    rots[:, 2, 1] = 2 * (y * z + x * w)
    rots[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return np.concatenate([np.eye(3)[None], rots])


class VoxelNearest:
    """Approximate nearest target point by a voxel distance transform (for the global search).

    The target's bounding box, grown by half its size on every side, is cut into ``cells`` voxels along
    its longest side; every voxel stores the index of a target point in the nearest occupied voxel
    (``scipy.ndimage.distance_transform_edt``). A lookup is O(1) and exact to about a voxel
    diagonal, also for points far from the target, where a k-d tree query is slow.
    """

    def __init__(self, target: np.ndarray, cells: int = 64) -> None:
        lo, hi = target.min(0), target.max(0)
        size = np.maximum(hi - lo, 1e-12 * max(float(np.max(hi - lo)), 1e-300))
        self.lo = lo - 0.5 * size
        self.voxel = float(np.max(2.0 * size)) / cells
        self.shape = np.maximum(np.ceil(2.0 * size / self.voxel).astype(int), 1)
        cell = self._cells(target)
        flat = np.ravel_multi_index(cell.T, self.shape)
        owner = np.full(int(np.prod(self.shape)), -1, dtype=np.int64)
        owner[flat] = np.arange(len(target))
        empty = (owner < 0).reshape(self.shape)
        idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        nearest_cell = np.ravel_multi_index(tuple(idx.reshape(len(self.shape), -1)), self.shape)
        self.nearest = owner[nearest_cell]
        self.target = target

    def _cells(self, x: np.ndarray) -> np.ndarray:
        c = np.floor((x - self.lo) / self.voxel).astype(np.int64)
        return np.clip(c, 0, self.shape - 1)

    def query(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices) of the approximate nearest target points of ``x`` (K, D)."""
        j = self.nearest[np.ravel_multi_index(self._cells(x).T, self.shape)]
        return np.linalg.norm(x - self.target[j], axis=1), j


def batch_trimmed_icp(src: np.ndarray, target: np.ndarray, lookup: VoxelNearest | cKDTree, rots: np.ndarray,
                      trans: np.ndarray, n_iter: int, keep: float, bound: float = np.inf,
                      floor: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run ``n_iter`` trimmed point-to-point ICP steps from every pose (rots[h], trans[h]) at once.

    ``lookup`` answers nearest-target queries: a :class:`VoxelNearest` (all poses in one lookup),
    or a k-d tree queried per pose with a bound that starts at ``bound`` and then follows 1.5
    times the pose's trimming threshold (at least ``floor``): pairs beyond the threshold are
    trimmed anyway, and bounded queries are fast. Returns the refined rotations (H, D, D),
    translations (H, D) and the final nearest-target distances (H, S) of the ``src`` samples
    (inf beyond the bound).
    """
    h, s, dim = len(rots), len(src), src.shape[1]
    n_keep = min(max(int(keep * s), dim + 1), s)
    m = len(target)
    bounds = np.full(h, bound)

    def distances(r: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.einsum("hij,sj->hsi", r, src) + t[:, None, :]
        if isinstance(lookup, VoxelNearest):
            d, j = lookup.query(x.reshape(-1, dim))
            return d.reshape(h, s), j.reshape(h, s)
        d = np.empty((h, s))
        j = np.empty((h, s), dtype=np.int64)
        for k in range(h):
            dk, jk = lookup.query(x[k], distance_upper_bound=bounds[k])
            d[k], j[k] = dk, np.minimum(jk, m - 1)
        return d, j

    for _ in range(n_iter):
        d, j = distances(rots, trans)
        thr = np.partition(d, n_keep - 1, axis=1)[:, n_keep - 1]
        w = ((d <= thr[:, None]) & np.isfinite(d)).astype(np.float64)
        total = w.sum(1)
        ok = total >= dim + 1
        total = np.maximum(total, 1.0)
        y = target[j]                                               # (H, S, D)
        mu_x = w @ src / total[:, None]
        mu_y = np.einsum("hs,hsd->hd", w, y) / total[:, None]
        xc = src[None, :, :] - mu_x[:, None, :]
        cov = np.einsum("hs,hsi,hsj->hij", w, y - mu_y[:, None, :], xc)
        new_rots = nearest_rotation(cov)
        new_trans = mu_y - np.einsum("hij,hj->hi", new_rots, mu_x)
        rots = np.where(ok[:, None, None], new_rots, rots)
        trans = np.where(ok[:, None], new_trans, trans)
        bounds = np.where(np.isfinite(thr), np.clip(1.5 * thr, floor, bound), bounds)
    d, _ = distances(rots, trans)
    return rots, trans, d


@dataclass(frozen=True, eq=False)
class Start:
    """The initial pose of the robust ICP and what the search learnt about the scale of the problem.

    Attributes
    ----------
    matrix : (D, D + 1) ndarray
        ``[R | t]`` taking model points near their target partners.
    bound : float
        Distance (caller's units) within which the right pairs lie after the start; inf when
        unknown. The first ICP iteration bounds its nearest-target queries by it.
    others : tuple of (D, D + 1) ndarray
        Runner-up poses of the search (the caller's pose first), tried by the coarse stage too.
    """

    matrix: np.ndarray
    bound: float
    others: tuple[np.ndarray, ...] = ()


def initial_alignment(model: np.ndarray, target: np.ndarray, tree: cKDTree, opts: ICPLoopOptions,
                      rng: np.random.Generator) -> Start:
    """The start chosen by ``opts.init`` (module docstring), with a tree built on ``target``.

    Trusted input: ``model`` (N, D) and ``target`` (M, D) validated, ``tree`` on ``target``.
    Draws the samples of the search from ``rng``.
    """
    dim = model.shape[1]
    eye = np.c_[np.eye(dim), np.zeros(dim)]
    if opts.init == "given":
        return Start(eye, np.inf)
    mu_m = model.mean(0)
    mu_t = target.mean(0)
    if opts.init == "centroid":
        return Start(np.c_[np.eye(dim), mu_t - mu_m], np.inf)
    rots = rotation_hypotheses(dim, opts.n_rotations, opts.init_max_angle)
    trans = mu_t[None, :] - np.einsum("hij,j->hi", rots, mu_m)
    # the caller's pose (identity, no shift) as its own hypothesis, first
    rots = np.concatenate([np.eye(dim)[None], rots])
    trans = np.concatenate([np.zeros((1, dim)), trans])
    t_small = target[sample_rows(len(target), 20 * opts.init_points, rng)]
    voxels = VoxelNearest(t_small)
    t_tree = cKDTree(t_small)
    src = model[sample_rows(len(model), opts.init_points, rng)]
    rots, trans, _ = batch_trimmed_icp(src, t_small, voxels, rots, trans, opts.init_iter, 0.5)
    # score with exact distances, queries bounded by tau (beyond it a pair scores 0 anyway)
    tau = 2.0 * max(point_spacing(t_tree, t_small, rng), voxels.voxel)
    x = (np.einsum("hij,sj->hsi", rots, src) + trans[:, None, :]).reshape(-1, dim)
    d = np.asarray(t_tree.query(x, distance_upper_bound=tau)[0]).reshape(len(rots), -1)
    score = np.maximum(0.0, 1.0 - (d / tau) ** 2).mean(1)
    # a pose that drifted beyond the searched range is not a candidate (the prior of init_max_angle)
    score = np.where(np.rad2deg(rotation_angle(rots)) <= opts.init_max_angle + ANGLE_SLACK, score, -1.0)
    order = np.argsort(-score, kind="stable")
    best = [int(i) for i in order[:opts.init_keep]]
    if 0 not in best:
        best.append(0)
    # second round: more points, the whole target (k-d tree, bounded queries), more steps
    src2 = model[sample_rows(len(model), 3 * opts.init_points, rng)]
    spacing = point_spacing(tree, target, rng)
    bound = tau
    rots2, trans2, d2 = batch_trimmed_icp(src2, target, tree, rots[best], trans[best], opts.init_iter, 0.5,
                                          bound=bound, floor=2.0 * spacing)
    tau2 = 2.0 * spacing
    score2 = np.maximum(0.0, 1.0 - (d2 / tau2) ** 2).mean(1)
    score2 = np.where(np.rad2deg(rotation_angle(rots2)) <= opts.init_max_angle + ANGLE_SLACK, score2, -1.0)
    win = int(np.argmax(score2))
    given = best.index(0)
    if score2[given] >= (1.0 - opts.init_margin) * score2[win]:
        win = given
    ranked = [int(i) for i in np.argsort(-score2, kind="stable") if i != win and score2[i] >= 0.0]
    runners = ([given] if given != win else []) + [i for i in ranked if i != given][:_RUNNERS]
    return Start(np.c_[rots2[win], trans2[win]], bound, tuple(np.c_[rots2[i], trans2[i]] for i in runners))
