"""Density adaptive rigid registration (Lawin, Danelljan, Khan, Forssen, Felsberg [1]).

Probabilistic registration fits a mixture to the observed points, so it models where the sensor
*sampled* as much as where the surfaces *are*: a region scanned ten times more densely pulls ten
times harder, and two scans taken from different places disagree in density exactly where they
should agree in geometry. Lawin et al. instead treat the scene's structure as a latent density
q(x) and the observations as samples of q(x) modulated by the sampling density of the sensor,
p_s(x) proportional to q(x) f_s(x). Fitting the scene mixture by minimizing KL(q || p_theta)
then needs the expectation over q, estimated from the observations by importance weights
1 / f_s(x_i) [1, Sec. 4]: each point's posteriors in the M-step are multiplied by its weight,
so sparse regions count as much as dense ones. The mixture and motions are the joint EM of
Evangelidis et al. [2] (target motion held at the identity).

The sampling density is estimated per set from its own points, by k nearest neighbors: on a
scanned surface (intrinsic dimension ``dim``, by default D - 1) the density near x_i is about
k / (c r_i^dim) with r_i^2 the mean squared distance to the k neighbors, so the weight is
w_i = r_i^dim, clipped to within a factor ``max_weight`` of its median (isolated outliers would
otherwise weigh most) and scaled to mean 1.

Subsampling: EM runs on at most ``max_points`` points of each set drawn uniformly at random
(``rng``; deterministic for a given seed). Uniform draws keep the density variation that the
weights correct; a voxel grid or farthest-point sampling would flatten it and hide the method.
Memory O(max_points * n_components); the neighbor search is a k-d tree on the subsample.

References
----------
.. [1] F. Jaremo Lawin, M. Danelljan, F. S. Khan, P.-E. Forssen, M. Felsberg, "Density Adaptive
       Point Set Registration", CVPR 2018. :doi:`10.1109/CVPR.2018.00405`
.. [2] G. D. Evangelidis, R. Horaud, "Joint Alignment of Multiple Point Sets with Batch and
       Incremental Expectation-Maximization", IEEE TPAMI 40(6), 2018.
       :doi:`10.1109/TPAMI.2017.2717829`
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..options import declared, option
from ._em import SceneEMOptions, with_default
from ._icp_options import Init
from ._mixture import PerPoint, fit_scene, sample_pair, start_pose
from ._rigid import RigidFit

__all__ = ["DensityAdaptiveOptions", "density_adaptive_register", "observation_weights"]


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class DensityAdaptiveOptions(SceneEMOptions):
    """Options of ``register_points(method="density-adaptive")``.

    The fields of :class:`~reglib.registration._em.SceneEMOptions` (``max_iter``, ``tol``,
    ``max_points``, ``n_components``, ``outlier``; ``init`` and its settings: the start, here
    by default ``"features"``), and the density estimate. Lengths are in
    normalized units (each set centered on its mean, both divided by the larger RMS radius).
    Beyond ``max_points``, EM runs on a uniform random subsample (which keeps the density
    variation the weights correct).

    Parameters
    ----------
    init : {"features", "centroid", "given", "search"}
        The start (:class:`~reglib.registration._em.EMOptions`); ``"features"`` by default: on
        ``bench_rigid_probabilistic.py`` it raised the success rate with no case worse than the
        centroid start.
    n_neighbors : int
        Neighbors k of the sampling-density estimate (1 to 100). The estimate's noise biases
        the fit, the more so the fewer neighbors.
    dim : int or None
        Intrinsic dimension of the sampled structure, 1 to 3 and at most D; None (default):
        D - 1, i.e. surfaces for 3-D scans and curves for 2-D contours.
    max_weight : float
        Weights are clipped to [median / max_weight, median * max_weight] (>= 1; 1 turns the
        weighting off). The k-NN estimate is noisy, so a tight cap clips the sparse side.
    """

    init: Init = with_default("init", "features")
    n_neighbors: int = option(30, kind="int", low=1, high=100, doc="neighbors k of the sampling-density estimate")
    dim: int | None = option(None, kind="int", low=1, high=3, optional=True,
                             doc="intrinsic dimension of the sampled structure (None: D - 1)")
    max_weight: float = option(10.0, kind="float", low=1, doc="weights clipped to within this factor of their median")


def observation_weights(points: np.ndarray, n_neighbors: int, dim: int, max_weight: float) -> np.ndarray:
    """Importance weights (N,), mean 1, proportional to 1 / (estimated local sampling density).

    Parameters
    ----------
    points : (N, D) ndarray
        The set whose own sampling density is estimated.
    n_neighbors : int
        Neighbors k; fewer when the set has fewer other points.
    dim : int
        Intrinsic dimension of the sampled structure (2: surfaces).
    max_weight : float
        Weights are clipped to within this factor of their median before scaling to mean 1.

    Returns
    -------
    (N,) ndarray
        w_i proportional to r_i^dim, r_i^2 the mean squared distance to the k nearest others.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.r_[np.linspace(0, 1, 100), np.linspace(1.1, 2, 10)][:, None] * [1.0, 0.0]
    >>> w = observation_weights(x, 2, 1, 100.0)
    >>> bool(w[-5] > 5 * w[50])      # the sparse end weighs about ten times more
    True
    """
    n = len(points)
    k = min(n_neighbors, n - 1)
    if k < 1:
        return np.ones(n)
    dist, _ = cast(tuple[np.ndarray, np.ndarray], cKDTree(points).query(points, k=k + 1))  # (N, D) points: arrays
    r2 = (dist[:, 1:] ** 2).mean(1)
    w = r2 ** (dim / 2.0)
    med = float(np.median(w))
    if med <= 0:
        positive = w[w > 0]
        med = float(positive.min()) if len(positive) else 1.0
    w = np.clip(w, med / max_weight, med * max_weight)
    return w / w.mean()


def density_adaptive_register(model: np.ndarray, target: np.ndarray, opts: DensityAdaptiveOptions,
                              rng: np.random.Generator) -> RigidFit:
    """Rigidly register ``model`` onto ``target``, weighting points against their sampling density.

    Parameters
    ----------
    model, target : (N, D), (M, D) ndarray
        Trusted finite float64 points (x, y[, z]), D in {2, 3}, in the caller's units.
    opts : DensityAdaptiveOptions
        The method's options.
    rng : numpy.random.Generator
        Source of the subsampling's random choices (the same seed gives the same answer).

    Returns
    -------
    RigidFit
        ``matrix`` = ``[R | t]`` (D, D + 1) with x -> R x + t taking the model onto the target;
        ``reach`` three times the final RMS component width (at least 1 % of the scale).

    Raises
    ------
    InputError
        When ``opts.dim`` exceeds the points' dimension D.

    References
    ----------
    .. [1] F. Jaremo Lawin et al., "Density Adaptive Point Set Registration", CVPR 2018.
           :doi:`10.1109/CVPR.2018.00405`

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> def surface(n):             # (not symmetric: the feature start could take a half-turn twin)
    ...     xy = rng.uniform(-1, 1, (n, 2))
    ...     return np.c_[xy, 0.3 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1]) + 0.2 * xy[:, 0] ** 2]
    >>> a = np.deg2rad(20.0)
    >>> rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    >>> target = surface(800) @ rot.T + [0.5, 0.2, 0.1]   # another sample of the surface, moved
    >>> fit = density_adaptive_register(surface(1500), target, DensityAdaptiveOptions(), rng)
    >>> bool(np.allclose(fit.matrix, np.c_[rot, [0.5, 0.2, 0.1]], atol=0.03))
    True
    """
    d = model.shape[1]
    dim = d - 1 if opts.dim is None else opts.dim
    if dim > d:
        raise InputError(f"`dim` must be <= the points' dimension {d}, got {dim}")
    start = start_pose(model, target, opts, rng)
    norm = sample_pair(model, target, opts.max_points, rng, ("random", "random"))
    weights = PerPoint(observation_weights(norm.u, opts.n_neighbors, dim, opts.max_weight),
                       observation_weights(norm.v, opts.n_neighbors, dim, opts.max_weight))
    return fit_scene(norm, opts, rng, weights=weights, start=start)
