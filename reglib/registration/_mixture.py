"""What the probabilistic rigid methods share: subsampling, normalization and the JRMPC-style EM.

``color-gmm`` (Danelljan et al. 2016) and ``density-adaptive`` (Lawin et al. 2018) both fit one
latent Gaussian mixture, the *scene*, to both point sets at once (the joint registration of
Evangelidis et al. [1]): each set is an observation of the scene after its own rigid motion, the
target's motion is held at the identity, and EM alternates the posteriors of the points over the
components with closed-form updates of the model's motion, the component means, variances and
weights. The two papers add to this core, respectively, a color distribution per component and
a weight per observed point; both arrive here as optional arguments of :func:`scene_em`
(:func:`fit_scene` runs it and answers in the caller's units).

The loop's start is chosen by ``init`` (:class:`~reglib.registration._em.EMOptions`):
:func:`start_pose` finds it in the caller's units (the start of ``"icp"``, on the whole sets) and
:meth:`Normalized.from_caller` carries it into the normalized units the loops run in.

Everything below works on trusted arrays in normalized coordinates (see :func:`normalize_pair`).
Memory is O((N + M) K) for N and M points and K components (plus O((N + M) L) for L color bins).

References
----------
.. [1] G. D. Evangelidis, R. Horaud, "Joint Alignment of Multiple Point Sets with Batch and
       Incremental Expectation-Maximization", IEEE TPAMI 40(6), 2018.
       :doi:`10.1109/TPAMI.2017.2717829`
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from ._em import EMOptions, SceneEMOptions
from ._feature_start import choose_start
from ._procrustes import umeyama
from ._rigid import RigidFit
from ._start import Start

__all__ = [
    "LoopStart",
    "Normalized",
    "PerPoint",
    "SceneFit",
    "color_basis",
    "equalize_colors",
    "fit_scene",
    "normalize_pair",
    "rotation_angle",
    "sample_pair",
    "scene_em",
    "start_pose",
    "subsample_indices",
    "subsample_with_means",
]

Subsampling = Literal["voxel", "random"]


def subsample_indices(points: np.ndarray, m: int, rng: np.random.Generator, how: Subsampling) -> np.ndarray:
    """Indices (ascending) of at most ``m`` rows of ``points``; all rows when there are no more.

    ``"voxel"``: a voxel grid whose edge is found by bisection (at most 30 halvings) so that about
    ``m`` voxels are occupied; one point per voxel, the one nearest the voxel's center; if more
    than ``m`` voxels remain, ``m`` of them drawn by ``rng``. It evens out the sampling density.
    ``"random"``: ``m`` rows drawn uniformly without replacement by ``rng``; it keeps the sampling
    density of the scan (what ``density-adaptive`` is built to correct).
    Both cost O(N log N) time and O(N) memory, deterministic for a given ``rng``.
    """
    return _subsample(points, m, rng, how)[0]


def subsample_with_means(points: np.ndarray, values: np.ndarray, m: int,
                         rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Voxel-grid indices as :func:`subsample_indices`, and the mean of ``values`` over each voxel.

    The kept point stands for its voxel; averaging its attribute (a color) over the voxel
    removes the aliasing of texture finer than the grid, so that two scans of one surface,
    sampled on different grids, carry comparable attributes.
    """
    idx, key = _subsample(points, m, rng, "voxel")
    if key is None:
        return idx, values[idx].copy()
    uniq, inverse = np.unique(key, return_inverse=True)
    counts = np.bincount(inverse, minlength=len(uniq)).astype(np.float64)
    means = np.stack([np.bincount(inverse, weights=values[:, j], minlength=len(uniq))
                      for j in range(values.shape[1])], 1) / counts[:, None]
    return idx, means[np.searchsorted(uniq, key[idx])]


def _subsample(points: np.ndarray, m: int, rng: np.random.Generator,
               how: Subsampling) -> tuple[np.ndarray, np.ndarray | None]:
    n = len(points)
    if n <= m:
        return np.arange(n), None
    if how == "random":
        return np.sort(rng.choice(n, size=m, replace=False)), None
    lo_pt = points.min(0)
    extent = float((points.max(0) - lo_pt).max())
    if extent <= 0:
        return np.sort(rng.choice(n, size=m, replace=False)), None
    d = points.shape[1]

    def occupied(edge: float) -> tuple[np.ndarray, np.ndarray]:
        cell = np.floor((points - lo_pt) / edge).astype(np.int64)
        dims = cell.max(0) + 1
        # The finest edge tried gives at most (4 n^(1/D) + 2)^D voxels: the key fits in int64.
        return np.ravel_multi_index(tuple(cell.T), tuple(dims)), cell

    # Bisection on the voxel edge between one voxel per point (tiny) and one voxel (the extent).
    hi, lo = extent, extent / (4.0 * n ** (1.0 / d) + 1.0)
    best = hi
    for _ in range(30):
        mid = np.sqrt(lo * hi)
        key, _ = occupied(mid)
        count = len(np.unique(key))
        if count > m:
            lo = mid
        else:
            hi = best = mid
        if hi / lo < 1.02:
            break
    edge = best
    key, cell = occupied(edge)
    offset = points - lo_pt - (cell + 0.5) * edge
    dist2 = (offset * offset).sum(1)
    order = np.lexsort((dist2, key))
    first = np.ones(n, dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    chosen = order[first]
    if len(chosen) > m:
        chosen = rng.choice(chosen, size=m, replace=False)
    return np.sort(chosen), key


def equalize_colors(colors: list[np.ndarray]) -> list[np.ndarray]:
    """Opponent color channels in [0, 1], the luminance equalized over all sets together.

    Channels: luminance (R + G + B) / 3, mapped through its empirical CDF over the sets joined
    (one monotone map shared by the sets, so colors that agree between them still agree);
    red-green (1 + R - G) / 2 and yellow-blue (1 + (R + G) / 2 - B) / 2, left as they are.
    Equalizing spreads the brightness levels that actually occur (a dark carpet, a grey wall)
    over [0, 1] so that the color basis tells them apart; the chroma channels are not
    stretched, as on the near-grey surfaces of indoor scenes they are mostly sensor noise.
    """
    joined = np.concatenate(colors)
    sizes = np.cumsum([len(c) for c in colors])[:-1]
    lum = joined.mean(1)
    # position of each value in the CDF, equal values sharing the middle of their step
    _, inverse, counts = np.unique(lum, return_inverse=True, return_counts=True)
    middle = (np.cumsum(counts) - 0.5 * counts) / len(lum)
    out = np.c_[middle[inverse], 0.5 * (1.0 + joined[:, 0] - joined[:, 1]),
                0.5 * (1.0 + 0.5 * (joined[:, 0] + joined[:, 1]) - joined[:, 2])]
    return np.split(out, sizes)


@dataclass(frozen=True, slots=True)
class LoopStart:
    """Where a loop starts, in normalized units: the model's motion ``v = rot u + trans``, and the
    components' initial variance ``var`` when the start knows how close it is (None: the data's
    spread about the start, as from the centroids)."""

    rot: np.ndarray
    trans: np.ndarray
    var: float | None = None


@dataclass(frozen=True, slots=True)
class Normalized:
    """Centered, commonly scaled copies of a pair: ``u = (model - model_mean) / scale``, likewise ``v``."""

    u: np.ndarray
    v: np.ndarray
    model_mean: np.ndarray
    target_mean: np.ndarray
    scale: float

    def from_caller(self, start: Start | None) -> LoopStart:
        """``start`` (caller's units; None: the centroids aligned) in these normalized units.

        A start that knows how close it is (a finite ``bound``: the search's or the feature
        start's) sets the components' initial standard deviation to half its bound: wide
        components would first pull the sets' centroids together and lose a partial overlap.
        """
        d = len(self.model_mean)
        if start is None:
            return LoopStart(np.eye(d), np.zeros(d))
        rot = start.matrix[:, :d]
        trans = (rot @ self.model_mean + start.matrix[:, d] - self.target_mean) / self.scale
        var = (start.bound / self.scale) ** 2 if np.isfinite(start.bound) else None
        return LoopStart(rot.copy(), trans, var)

    def to_caller(self, rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
        """``[R | t]`` in the caller's units for a motion ``v = R u + trans`` in normalized units."""
        t = self.target_mean + self.scale * trans - rot @ self.model_mean
        return np.c_[rot, t]

    def rigid_fit(self, rot: np.ndarray, trans: np.ndarray, sigma: float, n_iter: int, converged: bool) -> RigidFit:
        """The caller's :class:`RigidFit` of a normalized motion whose components have width ``sigma``
        (normalized units): ``reach`` three widths, at least 1 % of the scale."""
        return RigidFit(matrix=self.to_caller(rot, trans), n_iter=n_iter, converged=converged,
                        reach=self.scale * max(3.0 * sigma, 0.01))


def normalize_pair(model: np.ndarray, target: np.ndarray) -> Normalized:
    """Center each set on its mean and divide both by one scale, the larger RMS radius.

    One scale for both keeps a rigid motion rigid; starting from the identity in these units is
    starting from the alignment of the two centroids.
    """
    cm, ct = model.mean(0), target.mean(0)
    u, v = model - cm, target - ct
    scale = float(max(np.sqrt((u * u).sum(1).mean()), np.sqrt((v * v).sum(1).mean()), 1e-300))
    return Normalized(u / scale, v / scale, cm, ct, scale)


def sample_pair(model: np.ndarray, target: np.ndarray, max_points: int, rng: np.random.Generator,
                how: tuple[Subsampling, Subsampling]) -> Normalized:
    """At most ``max_points`` rows of each set (:func:`subsample_indices`, the model's first, by
    ``how[0]`` and ``how[1]``), as a :func:`normalize_pair`."""
    model_rows = subsample_indices(model, max_points, rng, how[0])
    target_rows = subsample_indices(target, max_points, rng, how[1])
    return normalize_pair(model[model_rows], target[target_rows])


def start_pose(model: np.ndarray, target: np.ndarray, opts: EMOptions,
               rng: np.random.Generator) -> Start | None:
    """The start that ``opts.init`` chooses, ``[R | t]`` (D, D + 1) in the caller's units.

    None for ``"centroid"`` (the identity in normalized units, i.e. the subsamples' centroids
    aligned; no draw from ``rng``); the identity for ``"given"``; otherwise the start of
    :func:`reglib.registration._feature_start.choose_start` on the whole sets (``"features"``
    falls back to the rotation search where it finds nothing), which draws from ``rng``, with
    the distance within which its right pairs lie (``bound``; the loops start their components
    that wide). Trusted input: validated (N, D) and (M, D) points.
    """
    if opts.init == "centroid":
        return None
    d = model.shape[1]
    if opts.init == "given":
        return Start(np.c_[np.eye(d), np.zeros(d)], np.inf)
    start, _ = choose_start(model, target, cKDTree(target), opts.start_options(), rng)
    return Start(np.asarray(start.matrix, dtype=np.float64), float(start.bound))


def rotation_angle(rot: np.ndarray) -> float:
    """Angle (radians) of a 2-D or 3-D rotation matrix."""
    if rot.shape[0] == 2:
        return float(abs(np.arctan2(rot[1, 0], rot[0, 0])))
    return float(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0)))


def color_basis(colors: np.ndarray, bins: tuple[int, int, int]) -> np.ndarray:
    """Soft color histogram basis, (N, L) with L = prod(bins): b_l(c) >= 0, sum_l b_l(c) = 1.

    Gaussian bumps on a regular grid over the color cube [0, 1]^3, ``bins[j]`` along channel j,
    each as wide as half the grid spacing along each channel, normalized over l at each color.
    ``L * b_l`` integrates to about one over the cube, so a uniform component weight gives the
    color density 1 (the uniform density).
    """
    logb = np.zeros((len(colors), 1))
    for j, nb in enumerate(bins):
        centers = (np.arange(nb) + 0.5) / nb
        lj = (colors[:, j:j + 1] - centers) ** 2 * (-0.5 / (0.5 / nb) ** 2)  # (N, nb)
        logb = (logb[:, :, None] + lj[:, None, :]).reshape(len(colors), -1)
    logb -= logb.max(1, keepdims=True)
    b = np.exp(logb)
    b /= b.sum(1, keepdims=True)
    return b


@dataclass(frozen=True, slots=True)
class PerPoint:
    """One array per point set, row for row with its points: ``model`` (N, ...) and ``target`` (M, ...)."""

    model: np.ndarray
    target: np.ndarray


@dataclass(frozen=True, slots=True)
class SceneFit:
    """What :func:`scene_em` returns (normalized units): ``v = rot u + trans``."""

    rot: np.ndarray
    trans: np.ndarray
    n_iter: int
    converged: bool
    sigma2: float  # weight-averaged variance of the scene components at the end


def _posteriors(points: np.ndarray, means: np.ndarray, var: np.ndarray, log_pi: np.ndarray,
                log_color: np.ndarray | None, log_beta: float) -> np.ndarray:
    """Posterior alpha (N, K) of component k for point i; the rest, 1 - row sum, is the outlier class."""
    d = points.shape[1]
    a = cdist(points, means, "sqeuclidean")
    a *= -0.5 / var
    a += log_pi - 0.5 * d * np.log(2.0 * np.pi * var)
    if log_color is not None:
        a += log_color
    top = np.maximum(a.max(1, keepdims=True), log_beta)
    np.exp(a - top, out=a)
    a /= a.sum(1, keepdims=True) + np.exp(log_beta - top)
    return a


def scene_em(u: np.ndarray, v: np.ndarray, opts: SceneEMOptions, rng: np.random.Generator, *,
             weights: PerPoint | None = None, colors: PerPoint | None = None,
             start: LoopStart | None = None, var_floor: float = 1e-6) -> SceneFit:
    """Fit the latent scene mixture to ``u`` (moving) and ``v`` (fixed, identity motion).

    Parameters
    ----------
    u, v : (N, D), (M, D) ndarray
        Normalized model and target points.
    opts : SceneEMOptions
        ``n_components`` scene components K (initialized on a voxel-grid sample of ``v``);
        ``max_iter`` and ``tol``: EM stops after ``max_iter`` iterations, or (converged) when the
        model's motion changes by less than ``tol`` (radians of rotation plus normalized units of
        translation) twice running; ``outlier``: weight of the uniform outlier class, in [0, 1),
        over the bounding box of both sets.
    rng : numpy.random.Generator
        Source of the voxel-grid sample's random choices.
    weights : PerPoint of (N,), (M,) ndarray, optional
        Observation weights (mean 1) multiplying each point's posteriors in the M-step.
    colors : PerPoint of (N, L), (M, L) ndarray, optional
        Color basis values (:func:`color_basis`); each component then has a color
        distribution sum_l rho_kl L b_l(c), learned by EM, whose density multiplies the spatial one.
    start : LoopStart, optional
        The model's motion to start from (the identity when omitted), and the components'
        initial variance (when None: the mean squared distance of both sets, the model so
        moved, to the initial means, over D; the outlier class's box is measured on them too).
    var_floor : float
        Smallest component variance (normalized units squared).
    """
    d = u.shape[1]
    k_idx = subsample_indices(v, opts.n_components, rng, "voxel")
    means = v[k_idx].copy()
    k = len(means)
    rot, trans = (np.eye(d), np.zeros(d)) if start is None else (start.rot.copy(), start.trans.copy())
    both = np.r_[u @ rot.T + trans, v] if start is not None else np.r_[u, v]
    var0 = float(cdist(both, means, "sqeuclidean").mean()) / d
    if start is not None and start.var is not None:
        var0 = min(var0, start.var)
    var = np.full(k, max(var0, var_floor))
    log_pi = np.full(k, -np.log(k))
    extent = both.max(0) - both.min(0)
    volume = float(np.prod(np.maximum(extent, 1e-3)))
    # Outlier class: weight outlier, density 1 / volume (and color density 1).
    outlier = opts.outlier
    log_beta = np.log(outlier / volume) - np.log1p(-outlier) if outlier > 0 else -np.inf
    use_color = colors is not None
    cb_u = colors.model if colors is not None else np.zeros((len(u), 0))
    cb_v = colors.target if colors is not None else np.zeros((len(v), 0))
    n_bins = cb_u.shape[1] if use_color else 0
    rho = np.full((k, n_bins), 1.0 / max(n_bins, 1))
    if use_color:
        # Start each component's color weights from the target points nearest to it (its cell),
        # the target being where the scene starts: color then guides the very first E-step.
        cell = cdist(v, means, "sqeuclidean").argmin(1)
        counts = np.zeros((k, n_bins))
        np.add.at(counts, cell, cb_v)
        counts += 0.1 * counts.sum(1, keepdims=True).clip(1.0) / n_bins
        rho = counts / counts.sum(1, keepdims=True)
    wu = np.ones(len(u)) if weights is None else weights.model
    wv = np.ones(len(v)) if weights is None else weights.target
    still = 0
    converged = False
    it = 0
    while it < opts.max_iter:
        it += 1
        tu = u @ rot.T + trans
        if use_color:
            # p(c | k) = L sum_l rho_kl b_l(c), (N, K); floor keeps the logarithm finite
            pc_u = np.maximum(cb_u @ rho.T * n_bins, 1e-12)
            pc_v = np.maximum(cb_v @ rho.T * n_bins, 1e-12)
            au = _posteriors(tu, means, var, log_pi, np.log(pc_u), log_beta)
            av = _posteriors(v, means, var, log_pi, np.log(pc_v), log_beta)
        else:
            au = _posteriors(tu, means, var, log_pi, None, log_beta)
            av = _posteriors(v, means, var, log_pi, None, log_beta)
        au *= wu[:, None]
        av *= wv[:, None]
        lam_u = au.sum(0)
        lam_v = av.sum(0)
        # Model motion: the posterior-weighted mean of u per component ("virtual point") should land
        # on the component mean, each with weight lambda_k / sigma_k^2 (JRMPC's M-step).
        live = lam_u > 1e-10
        if live.sum() >= d:
            virt = (au.T @ u)[live] / lam_u[live, None]
            step = umeyama(virt, means[live], lam_u[live] / var[live])
            new_rot, new_trans = step[:, :d], step[:, d]
        else:
            new_rot, new_trans = rot, trans
        change = rotation_angle(new_rot @ rot.T) + float(np.linalg.norm(new_trans - trans))
        rot, trans = new_rot, new_trans
        tu = u @ rot.T + trans
        # Scene: means, variances, weights (components no point explains keep their values).
        lam = lam_u + lam_v
        ok = lam > 1e-10
        sums = au.T @ tu + av.T @ v
        means[ok] = sums[ok] / lam[ok, None]
        sq = (au.T @ (tu * tu).sum(1) + av.T @ (v * v).sum(1) - 2.0 * (sums * means).sum(1)
              + lam * (means * means).sum(1))
        var[ok] = np.maximum(sq[ok] / (d * lam[ok]), var_floor)
        pi = np.maximum(lam, 1e-10)
        log_pi = np.log(pi / pi.sum())
        if use_color:
            # rho_kl proportional to sum_i alpha_ik rho_kl L b_l(c_i) / p(c_i | k)
            num = ((au / pc_u).T @ cb_u + (av / pc_v).T @ cb_v) * rho * n_bins
            tot = num.sum(1, keepdims=True)
            rho = np.where(tot > 1e-12, num / np.maximum(tot, 1e-300), rho)
        still = still + 1 if change < opts.tol else 0
        if still >= 2:
            converged = True
            break
    sigma2 = float((lam * var).sum() / max(lam.sum(), 1e-300))
    return SceneFit(rot, trans, it, converged, sigma2)


def fit_scene(norm: Normalized, opts: SceneEMOptions, rng: np.random.Generator, *,
              weights: PerPoint | None = None, colors: PerPoint | None = None,
              start: Start | None = None) -> RigidFit:
    """:func:`scene_em` on the normalized pair ``norm`` from ``start``, answered in the caller's units.

    ``start`` is in the caller's units (:func:`start_pose`; None: the centroids aligned).
    ``reach`` is three times the final RMS component width (at least 1 % of the scale).
    """
    pose = None if start is None else norm.from_caller(start)
    fit = scene_em(norm.u, norm.v, opts, rng, weights=weights, colors=colors, start=pose)
    return norm.rigid_fit(fit.rot, fit.trans, float(np.sqrt(fit.sigma2)), fit.n_iter, fit.converged)
