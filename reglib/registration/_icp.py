"""Robust rigid ICP: point-to-point and point-to-plane, with the robust functions of Babin et al. [1].

Each iteration pairs every (sampled) model point x_i, moved by the current motion, with its
nearest target point y_j (a k-d tree; memory O(N + M), never an N x M matrix), computes the
residual r_i, a scale sigma and weights w_i = w(|r_i| / sigma), and solves one weighted
least-squares step (iteratively re-weighted least squares, IRLS; :mod:`reglib.registration._steps`):

- ``"point_to_point"``: r_i = |x_i - y_j|; the step is the closed-form weighted rigid map
  (Umeyama's SVD or the SVD-free FA3R, ``solver``).
- ``"point_to_plane"``: r_i = n_j . (x_i - y_j) with the target normal n_j (given, or from the
  PCA of its ``k_normals`` nearest neighbors, computed only for target points that get matched);
  the step solves the normal equations of the rotation linearized about the matched points'
  centroid (Chen & Medioni [2]; Low [3]) and applies it as an exact rotation.

The robust functions (``loss``, ``tuning``) and the MAD scale are those of
:mod:`reglib.registration._losses`. The scale sigma is ``scale`` when given (caller's units);
otherwise it is re-estimated every iteration from the residuals. At low overlap or with many
outliers most pairs are wrong, the median lies among them and the scale grows until the robust
function rejects nothing. So by default (``scale_quantile=None``) the share xi of right pairs is
estimated every iteration too, as VarTrimmed's xi of the point distances (Chetverikov et al. [4]);
when xi < 1/2 the MAD is taken over the xi closest pairs only, and so are the query bounds below.

The start is chosen by ``init``: by default FPFH feature matches and RANSAC over all rotations
(:mod:`reglib.registration._feature_start`), or :func:`reglib.registration._start.initial_alignment`'s
rotation search, the centroids, or the caller's pose. After the ICP, an answer that too little of
the data supports (overlap, residual against the target's spacing, feature inliers kept) says so
(:mod:`reglib.registration._support`): ``converged=False`` and a ``reason``. With ``verify`` (default)
and a searched start, a 3-D answer that a pose a small move away fits as
well is ``underdetermined`` (:mod:`reglib.registration._pinned`: a slide), and under 65 % measured overlap
without volume outliers found it is checked against the target registered onto the model the same way
(:func:`disagreement`): reason ``inconsistent`` when they disagree, as a slide or a twin that the
support figures cannot tell from a success does. Before any of that, a searched 3-D answer is polished by
the score at one target spacing (:func:`reglib.registration._pinned.tight_polish`): at low overlap the
robust ICP's own minimum can be a slide that this score does not favour.

Large sets: the robust ICP iterates on at most ``max_points`` model points (a random sample, from
``rng``), against the whole target; with the feature start, only on the model points in the cubes
its downsampling kept as surface (when they are at least a tenth of the model): points scattered
through the volume are outliers whose queries cost most and pull the fit. It first converges (to
10 x ``tol``) on a fifth of that sample, where iterations are cheap, from the start and from its
runners-up, and the pose that brings most of that sample within two target spacings goes on to
refine on the whole sample. With more than three starts, each first runs 20 iterations, and
only the first start (the best by the feature evidence or the search) and the two best by that
share go on converging (a wrong start otherwise runs to ``max_iter``). A finalist that the cap stops
while it still raises that share goes on in rounds (:mod:`reglib.registration._coarse`): on a wide flat
part of a scene a right start can be slow, and cut off it loses to a wrong pose that settled nearby.
The answer's support is measured on the same surface points. k-d tree queries are bounded, because
a query far from the target visits many cells and is slow: after the first iteration pairs farther
apart than max(8 max(k, 3) sigma_d, 4 x the target's spacing) are dropped (sigma_d the MAD scale
of the point distances, over the same pairs as the residual scale; the bound only shrinks), where
every redescending loss gives weight below 2 % anyway.

References
----------
.. [1] P. Babin, P. Giguere, F. Pomerleau, "Analysis of Robust Functions for Registration
       Algorithms", ICRA 2019. :doi:`10.1109/ICRA.2019.8793791`
.. [2] Y. Chen, G. Medioni, "Object modelling by registration of multiple range images", Image
       and Vision Computing 10(3), 1992. :doi:`10.1016/0262-8856(92)90066-C`
.. [3] K.-L. Low, "Linear Least-Squares Optimization for Point-to-Plane ICP Surface
       Registration", Tech. Rep. TR04-004, UNC Chapel Hill, 2004.
.. [4] D. Chetverikov, D. Stepanov, P. Krsek, "Robust Euclidean alignment of 3D point sets: the
       trimmed iterative closest point algorithm", Image and Vision Computing 23(3), 2005.
       :doi:`10.1016/j.imavis.2004.05.007`
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import cast

import numpy as np
from scipy.spatial import cKDTree

from .._geometry import rotation_angle
from .._verdict import INCONSISTENT, Reason, pinned_reason
from ..errors import InputError
from ._coarse import coarse_winner
from ._feature_start import FeatureEvidence, Prepared, choose_start
from ._icp_options import VARIANTS, ICPLoopOptions, ICPOptions
from ._losses import DEFAULT_TUNING, LOSSES, mad_scale, robust_weights, trim_fraction
from ._normals import LazyNormals
from ._pinned import neighbour_support, surface_normals, tight_polish
from ._rigid import RigidFit
from ._start import ANGLE_SLACK, Start
from ._steps import plane_step, point_spacing, point_step, sample_rows
from ._support import Support, measure_support, point_scores, support_reason

__all__ = ["DEFAULT_TUNING", "LOSSES", "VARIANTS", "ICPLoopOptions", "ICPOptions", "IndexedTarget",
           "disagreement", "icp_register", "refine_icp", "robust_icp"]

_SIGMA_FLOOR = 1e-9   # relative to the model's RMS radius
_COARSE_FRACTION = 5  # the first pass runs on max_points / 5 samples
_BOUND_FACTOR = 8.0   # queries reach 8 max(k, 3) point-distance scales (module docstring)
_ADAPTIVE_BELOW = 0.5  # scale_quantile=None: the MAD of the VarTrimmed share when it is below this
_MIN_SURFACE = 0.1     # the ICP iterates on the model's surface points when they are at least this share
# verify: forward and backward answers disagree beyond this mean displacement of the target (share of its extent);
# chosen on the global case's tuning seeds to flag the failures that answered converged=True at little cost in
# successes
_VERIFY_SHARE = 0.01
# ... and it runs only below this measured overlap (Support.overlap): on those seeds the failures it flags lie below
# it and many successes above (there a second registration only costs time)
_VERIFY_BELOW = 0.65


@dataclass(frozen=True, eq=False)
class IndexedTarget:
    """The target of a robust ICP with what the loop looks up in it.

    Attributes
    ----------
    points : (M, D) ndarray
        Target points.
    tree : scipy.spatial.cKDTree
        Built on ``points``.
    normals : LazyNormals or None
        Target normals (point-to-plane, or model normals given); None when not needed.
    spacing : float
        Median nearest-neighbor distance of the target (0 when unknown).
    """

    points: np.ndarray
    tree: cKDTree
    normals: LazyNormals | None
    spacing: float


def robust_icp(model: np.ndarray, target: IndexedTarget, start: Start, opts: ICPOptions, *,
               model_normals: np.ndarray | None = None, radius: float = 1.0) -> RigidFit:
    """IRLS ICP of ``model`` (the iterated sample) onto ``target`` from ``start`` (module docstring).

    Queries are bounded: by ``opts.max_distance``, by ``start.bound`` in the first iteration,
    and then by max(8 max(k, 3) sigma_d, 4 ``target.spacing``) with sigma_d the MAD scale of the
    previous iteration's point distances. Trusted input: ``target.normals`` is set for
    point-to-plane and with ``model_normals`` (unit rows, as ``model``); does not validate.

    Returns
    -------
    RigidFit
        ``[R | t]``, the iterations, whether the RMS motion fell below ``opts.tol`` times
        ``radius``, and the reach max(3 sigma, ``target.spacing``) with the last scale sigma.
    """
    dim = model.shape[1]
    points, tree, normals = target.points, target.tree, target.normals
    rot, t = start.matrix[:, :dim].copy(), start.matrix[:, dim].copy()
    k = DEFAULT_TUNING[opts.loss] if opts.tuning is None else float(opts.tuning)
    plane_normals = normals if opts.variant == "point_to_plane" else None
    dof = 1 if plane_normals is not None else dim
    user_bound = np.inf if opts.max_distance is None else float(opts.max_distance)
    bound = min(user_bound, start.bound)
    reach_factor = _BOUND_FACTOR * max(k, 3.0)
    cos_max = np.cos(np.deg2rad(opts.normal_angle))
    floor = _SIGMA_FLOOR * radius
    sigma = floor
    prev: np.ndarray | None = None
    converged = False
    it = 0
    for it in range(1, opts.max_iter + 1):
        x = model @ rot.T + t
        if prev is not None and np.sqrt(np.mean(np.sum((x - prev) ** 2, 1))) < opts.tol * radius:
            converged = True
            it -= 1
            break
        prev = x
        d, j = cast(tuple[np.ndarray, np.ndarray], tree.query(x, distance_upper_bound=bound))  # (N, D) x: arrays
        valid = np.isfinite(d)
        if model_normals is not None and normals is not None:
            tn = normals[np.minimum(j, len(points) - 1)]
            mn = model_normals @ rot.T
            valid &= np.abs((mn * tn).sum(1)) >= cos_max
        if valid.sum() < dim + 1:
            break
        dv = d[valid]
        # the pairs the scale is estimated from: all, or (scale_quantile=None) the VarTrimmed share
        # when it is below one half, so that the median of all would fall among the outliers
        core: slice | np.ndarray = slice(None)
        if opts.scale_quantile is None:
            xi = trim_fraction(dv)
            if xi < _ADAPTIVE_BELOW:
                core = dv <= np.quantile(dv, xi)
        bound = min(bound, user_bound, max(reach_factor * mad_scale(dv[core], dim), 4.0 * target.spacing))
        j = j[valid]
        xv = x[valid]
        y = points[j]
        if plane_normals is not None:
            n = plane_normals[j]
            r_abs = np.abs(((xv - y) * n).sum(1))
        else:
            r_abs = dv
        if opts.scale is not None:
            sigma = float(opts.scale)
        else:
            sigma = max(mad_scale(r_abs[core], dof, 0.5 if opts.scale_quantile is None else opts.scale_quantile), floor)
        w = robust_weights(r_abs, sigma, opts.loss, k, trim_ratio=opts.trim_ratio, max_distance=opts.max_distance)
        if not np.isfinite(w).all() or float(w.sum()) <= 0.0 or (w > 0).sum() < dim + 1:
            break
        if plane_normals is not None:
            step, c, shift = plane_step(xv, y, n, w)
            t = step @ (t - c) + c + shift
            rot = step @ rot
        else:
            m = point_step(model[valid], y, w, opts.solver)
            rot, t = m[:, :dim], m[:, dim]
    return RigidFit(matrix=np.c_[rot, t], n_iter=it, converged=converged, reach=max(3.0 * sigma, target.spacing))


def refine_icp(model: np.ndarray, target: np.ndarray, tree: cKDTree, start: Start, opts: ICPOptions,
               rng: np.random.Generator, *, model_normals: np.ndarray | None = None,
               target_normals: np.ndarray | None = None) -> RigidFit:
    """The robust ICP of :func:`icp_register` from a given ``start``, on a tree already built.

    For callers that have a start of their own (``"icp-hmrf"`` refines the same global search's
    start before its field). Trusted input: ``model`` (N, D) and ``target`` (M, D) validated,
    ``tree`` built on ``target``, normals of the right shapes; does not validate.

    Parameters
    ----------
    model, target : (N, D), (M, D) float64 ndarray
        Point sets, (x, y[, z]) rows, in the caller's units.
    tree : scipy.spatial.cKDTree
        Built on ``target``.
    start : Start
        The initial pose (and the search's runners-up, tried by the coarse stage too).
    opts : ICPOptions
        The loop's settings (``init`` and the search's fields are not used here).
    rng : numpy.random.Generator
        Draws the point samples.
    model_normals, target_normals : (N, D), (M, D) ndarray, optional
        As for :func:`icp_register`.

    Returns
    -------
    RigidFit
        As :func:`icp_register`'s.
    """
    dim = model.shape[1]
    radius = float(np.sqrt(np.mean(np.sum((model - model.mean(0)) ** 2, 1)))) or 1.0
    need_normals = opts.variant == "point_to_plane" or model_normals is not None
    normals = LazyNormals(target, tree, opts.k_normals, target_normals) if need_normals else None
    mn_all = None
    if model_normals is not None:
        mn_all = np.asarray(model_normals, dtype=np.float64)
        mn_all = mn_all / np.maximum(np.linalg.norm(mn_all, axis=1, keepdims=True), 1e-300)
    spacing = point_spacing(tree, target, rng)
    indexed = IndexedTarget(points=target, tree=tree, normals=normals, spacing=spacing)
    # coarse to fine: converge on a small sample first (cheap iterations), then on max_points
    idx = sample_rows(len(model), opts.max_points, rng)
    n_small = max(opts.max_points // _COARSE_FRACTION, 10)
    n_iter = 0
    if len(idx) > 2 * n_small or start.others:
        small = idx[sample_rows(len(idx), n_small, rng)] if len(idx) > 2 * n_small else idx
        coarse = replace(opts, tol=opts.tol * 10.0)
        tau = 2.0 * spacing if spacing > 0 else radius * 1e-3
        small_normals = None if mn_all is None else mn_all[small]

        def run(matrix: np.ndarray, n: int) -> RigidFit:
            return robust_icp(model[small], indexed, Start(matrix, start.bound), replace(coarse, max_iter=n),
                              model_normals=small_normals, radius=radius)

        def scores_of(m0: np.ndarray) -> np.ndarray:
            return point_scores(tree, model[small] @ m0[:, :dim].T + m0[:, dim], tau)

        def allowed(i: int, m0: np.ndarray) -> bool:                # a runner-up beyond the prior is not
            return i == 0 or opts.init == "features" or \
                np.rad2deg(rotation_angle(m0[:, :dim])) <= opts.init_max_angle + ANGLE_SLACK

        # the search's winner and its runners-up (the caller's pose first) each converge on the
        # small sample, the one that brings most of it within two target spacings goes on (_coarse)
        won = coarse_winner((start.matrix, *start.others), run, scores_of, allowed, coarse.max_iter)
        start, n_iter = Start(won.matrix, start.bound), won.n_iter
    fine = robust_icp(model[idx], indexed, start, opts, model_normals=None if mn_all is None else mn_all[idx],
                      radius=radius)
    return RigidFit(matrix=fine.matrix, n_iter=n_iter + fine.n_iter, converged=fine.converged, reach=fine.reach)


def icp_register(model: np.ndarray, target: np.ndarray, opts: ICPOptions, rng: np.random.Generator, *,
                 model_normals: np.ndarray | None = None, target_normals: np.ndarray | None = None,
                 prepared: Prepared | None = None) -> RigidFit:
    """Rigidly register ``model`` onto ``target`` by robust ICP (module docstring).

    Parameters
    ----------
    model, target : (N, D), (M, D) float64 ndarray
        Validated finite point sets, (x, y[, z]) rows, D in {2, 3}, in the caller's units.
    opts : ICPOptions
        Variant, robust function, scale, iteration limits, solver and initial alignment.
    rng : numpy.random.Generator
        Draws the point samples; the same seed gives the same answer.
    model_normals : (N, D) ndarray, optional
        Normals of the model; when given, pairs whose normals disagree by more than
        ``opts.normal_angle`` are dropped.
    target_normals : (M, D) ndarray, optional
        Normals of the target for point-to-plane (estimated from ``opts.k_normals`` neighbors
        when omitted).
    prepared : Prepared, optional
        What a feature start on these sets computed (the backward run of ``verify`` reuses it).

    Returns
    -------
    RigidFit
        ``[R | t]`` (D, D + 1) taking model points onto the target, the robust ICP's iterations,
        whether it met ``opts.tol``, and the reach 3 sigma (at least the target's spacing);
        ``converged=False`` with a ``reason`` when the data support the answer too little
        (:mod:`reglib.registration._support`).

    Raises
    ------
    InputError
        ``solver="fa3r"`` with 2-D points; normals of the wrong shape.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> target = rng.uniform(-1.0, 1.0, size=(500, 3)) * [1.0, 0.6, 0.3]
    >>> c, s = np.cos(0.3), np.sin(0.3)
    >>> rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    >>> model = (target - [0.1, 0.0, 0.2]) @ rot     # target = rot @ model + [0.1, 0, 0.2]
    >>> fit = icp_register(model, target, ICPOptions(variant="point_to_point"), rng)
    >>> bool(np.allclose(fit.matrix, np.c_[rot, [0.1, 0.0, 0.2]], atol=1e-6))
    True
    """
    _check_inputs(model, target, opts, model_normals, target_normals)
    tree = cKDTree(target)
    start, evidence = choose_start(model, target, tree, opts, rng, prepared=prepared)
    model, model_normals, scattered = _surface_only(model, model_normals, evidence)
    fit = refine_icp(model, target, tree, start, opts, rng, model_normals=model_normals,
                     target_normals=target_normals)
    surface = surface_normals(tree) if model.shape[1] == 3 else None  # read by the polish and the neighbours' check
    if surface is not None and opts.init in ("features", "search"):
        # a searched answer at low overlap can be the robust ICP's slide, which the score at one spacing is not
        # (a kept polish that settled gives a settled answer: the capped ICP before it is not what is returned)
        polished, settled = tight_polish(model, tree, fit.matrix, surface)
        fit = replace(fit, matrix=polished, converged=fit.converged or settled)
    support, reason = _judge_support(model, target, tree, fit, evidence, rng)
    searched = reason is None and opts.verify and opts.init in ("features", "search")
    # a pose a small move away fitting as well: the data do not pin it down (at any overlap: a slide can raise the
    # measured overlap over the reverse run's gate below)
    if searched and surface is not None:
        reason = pinned_reason(neighbour_support(model, tree, fit.matrix, surface))
    checked = searched and reason is None and support.overlap < _VERIFY_BELOW
    # (the backward run not where the model had points scattered through the volume: it lands off more often
    # there, and flags right answers)
    if checked and not scattered:
        backward = replace(opts, verify=False)
        swapped = None if evidence is None or evidence.prepared is None else evidence.prepared.swapped()
        for _ in range(2):  # a backward run that says it is unsupported itself gets a second try
            back = icp_register(target, model, backward, rng, model_normals=target_normals,
                                target_normals=model_normals, prepared=swapped)
            agree = disagreement(fit.matrix, back.matrix, target) <= _VERIFY_SHARE
            if agree or back.reason is None:
                break
        if not agree:
            reason = INCONSISTENT
    return replace(fit, converged=False, reason=reason) if reason is not None else fit


def _check_inputs(model: np.ndarray, target: np.ndarray, opts: ICPOptions, model_normals: np.ndarray | None,
                  target_normals: np.ndarray | None) -> None:
    """Raise :class:`~reglib.errors.InputError` for what :func:`icp_register` cannot run on: its Raises.

    Parameters
    ----------
    model, target, opts, model_normals, target_normals
        As for :func:`icp_register`.
    """
    dim = model.shape[1]
    if opts.solver == "fa3r" and dim != 3:
        raise InputError(f"`solver`='fa3r' needs 3-D points, got D = {dim}")
    for name, nrm, pts in (("model_normals", model_normals, model), ("target_normals", target_normals, target)):
        if nrm is not None and np.shape(nrm) != pts.shape:
            raise InputError(f"`{name}` must have shape {pts.shape}, got {np.shape(nrm)}")


def _surface_only(model: np.ndarray, model_normals: np.ndarray | None,
                  evidence: FeatureEvidence | None) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """The model (and its normals) on the surface the feature start kept, when points lie off it.

    Only when those surface points are enough to iterate on (``_MIN_SURFACE`` of the model and
    10 points) and not the whole model; otherwise the inputs unchanged.

    Parameters
    ----------
    model, model_normals : (N, D) ndarray, (N, D) array_like or None
        The model points, (x, y[, z]) rows, and their normals.
    evidence : FeatureEvidence or None
        The feature start's evidence (None for the other starts), with ``surface`` (N,) bool.

    Returns
    -------
    (K, D) ndarray, (K, D) ndarray or None, bool
        The rows kept and whether points were scattered through the volume (rows dropped).
    """
    surface = None if evidence is None else evidence.surface
    scattered = surface is not None and surface.sum() >= max(_MIN_SURFACE * len(model), 10) and not surface.all()
    if scattered:
        model = model[surface]
        model_normals = None if model_normals is None else np.asarray(model_normals)[surface]
    return model, model_normals, scattered


def _judge_support(model: np.ndarray, target: np.ndarray, tree: cKDTree, fit: RigidFit,
                   evidence: FeatureEvidence | None, rng: np.random.Generator) -> tuple[Support, Reason | None]:
    """How much of the data supports ``fit``, and the reason it is too little, if it is.

    Parameters
    ----------
    model, target, tree : (N, D) ndarray, (M, D) ndarray, scipy.spatial.cKDTree
        The sets the ICP ran on, (x, y[, z]) rows, and the tree built on ``target``.
    fit : RigidFit
        The robust ICP's answer.
    evidence : FeatureEvidence or None
        The feature start's evidence: the matches the answer keeps count when it had inliers.
    rng : numpy.random.Generator
        Draws the samples of the target's spacing and of the measures.

    Returns
    -------
    Support, str or None
        :func:`~reglib.registration._support.measure_support`'s figures and
        :func:`~reglib.registration._support.support_reason`'s verdict on them.
    """
    matched = evidence is not None and evidence.best_inliers > 0
    support = measure_support(model, tree, point_spacing(tree, target, rng), fit.matrix, rng,
                              features=evidence.kept(fit.matrix) if matched and evidence is not None else None)
    return support, support_reason(support)


def disagreement(forward: np.ndarray, backward: np.ndarray, target: np.ndarray) -> float:
    """How far ``forward`` (model -> target) after ``backward`` (target -> model), both [R | t], moves the
    target's points: their mean displacement over the target's extent (its bounding-box diagonal)."""
    dim = target.shape[1]
    rot = forward[:, :dim] @ backward[:, :dim]
    shift = forward[:, :dim] @ backward[:, dim] + forward[:, dim]
    moved = target @ rot.T + shift
    extent = float(np.linalg.norm(target.max(0) - target.min(0)))
    return float(np.linalg.norm(moved - target, axis=1).mean() / max(extent, 1e-300))
