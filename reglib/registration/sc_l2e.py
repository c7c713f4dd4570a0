"""The shape-context + L2E registration loop: ``register_points(method="l2e")``.

This is the loop of Ma et al. [1] (Sec. 4): describe both sets by shape context
(2-D: :func:`reglib.features.shape_context.shape_context`; 3-D:
:func:`reglib.features.shape_context_3d.shape_context_3d`), match them one-to-one by an
assignment with dummy partners, estimate an affine + Gaussian-kernel map from the matches with
the L2E criterion, warp the model, describe it again, and repeat.

Additions of ours to the published loop, each addressing a failure of it:

- Rotation hypotheses (``rotation=True``): in 2-D the rotations by multiples of 2 pi / n_angle
  are screened by how well the descriptors agree (a rotation by one angle bin is a cyclic shift of
  the histograms, so nothing is recomputed); in 3-D the principal-axes frames of the two sets give
  four proper rotations. The identity and the best others each run ``n_probe_rounds`` rounds and
  are scored by the fit of the registered model (mean Gaussian weight of nearest-neighbor
  distances, model to target and back). The given orientation is the prior: another rotation is
  taken only when it removes at least ``rotation_margin`` of the misfit the identity leaves, so
  noisy, roughly aligned data keep their orientation while a true rotation, which fits nearly
  exactly, is found.
- Support masking: from the second round, a point only counts in the other points' descriptors
  when the current warp puts it near the other set (within a radius that shrinks each round), so
  outliers in the target and parts missing from it stop corrupting the descriptors.
- Outliers: after the rounds, EM steps of a Gaussian mixture on the registered model with a
  uniform outlier term refine the fit with every target point; when much of the target is still
  unexplained, another pass restarts from the result with the explained part of the target as
  its normalization and support, matching only target points near the warped model.
- Large sets: descriptors and assignment run on at most ``max_points`` farthest-point samples of
  each set; the kernel has ``n_centers`` centers; the warp is evaluated on all points in blocks.
  Memory is O((N + M) K).

Each round's matches go to the library's L2E estimator (the re-weighted solver and annealing of
:func:`reglib.robust.l2e.l2e_fit`, the one :func:`reglib.filter_matches` uses, at its coarse
level), restarted from the published annealing every round as in the published demo.

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of
       Transformation for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
.. [2] A. Myronenko, X. Song, "Point Set Registration: Coherent Point Drift", IEEE TPAMI 32(12),
       2010. :doi:`10.1109/TPAMI.2010.46`
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..features.shape_context import chi2_cost, rotate_bins, shape_context
from ..features.shape_context import match_shape_contexts as match_descriptors
from ..features.shape_context_3d import shape_context_3d
from ..options import check_declared, declared, option
from ..robust import L2EOptions, Model, WeightedSolver, farthest_point_centers, l2e_scale, reweighted_fit
from ..transforms import LinearPart
from .cpd import cpd_posterior
from .result import WarpFit

__all__ = ["RegistrationOptions", "sc_l2e_register"]


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class RegistrationOptions:
    """Options of ``register_points(method="l2e")``; lengths are in normalized units (RMS radius 1).

    Parameters
    ----------
    n_rounds : int
        Describe-match-estimate rounds (the published demo runs 10).
    rotation : bool
        Search rotation hypotheses so that any initial rotation (up to 180 degrees) is recovered.
    n_hypotheses : int
        Rotations tried, the identity included: 2-D, the identity and the angle-bin rotations
        whose descriptors agree best; 3-D, the identity and up to four principal-axes frames.
    dummy_cost : float
        Cost of leaving a point unmatched in the assignment; raised to the median of each
        model point's best chi^2 cost when that is higher, so half the points can always match.
    n_angle, n_radius : int
        2-D shape context bins. 3-D uses ``n_radius`` radius, 4 elevation and 8 azimuth bins.
    n_centers : int
        Gaussian kernel centers (farthest-point samples of the model; M in [1]).
    beta : float
        Kernel width, k(x, c) = exp(-beta |x - c|^2) (beta in [1]).
    lam : float
        RKHS regularization (lambda in [1]); the ridge on tr(W^T K W) is lam * sigma^2 * sum_i phi_i,
        as in :class:`reglib.robust.l2e.L2EOptions`.
    sigma2_init, anneal_rate, n_anneal : float, float, int
        Scales of the L2E estimate in every round: sigma2_init * anneal_rate**k, k < n_anneal
        (the last one also scores the rotation hypotheses).
    max_iter : int
        Re-weighting iterations per scale at most.
    support_radius, support_decay, support_min : float
        From round 2, points farther than support_radius * support_decay**(round - 2) (but at
        least support_min) from the other set are left out of the descriptors.
    max_points : int
        Points of each set used for descriptors and assignment at most (farthest-point samples).
    n_probe_rounds : int
        Rounds each rotation hypothesis runs before they are compared.
    rotation_margin : float
        2-D: share of the identity's misfit another rotation must remove to be taken, in [0, 1)
        (3-D takes the best-scoring frame).
    n_refine : int
        EM steps after the rounds (Gaussian mixture centered on the registered model with a uniform
        outlier term, CPD-style, seeded by the L2E result); 0 turns them off.
    outlier_weight : float
        Weight of the uniform outlier term in those EM steps, in [0, 1).
    outlier_passes : int
        Further passes at most while a share above ``outlier_share`` of the target stays farther
        than 3 sigma from the registered model: the explained part then sets the target's
        normalization and descriptors, and only target points near the model may be matched.
    outlier_share : float
        Share of unexplained target points that starts another pass.

    Upper bounds on the counts keep every request finite in time and memory, far beyond any use;
    :func:`reglib.options.option_specs` lists every bound.
    """

    n_rounds: int = option(6, kind="int", low=1, high=100, doc="describe-match-estimate rounds")
    rotation: bool = option(True, kind="bool", doc="search rotation hypotheses (any initial rotation)")
    n_hypotheses: int = option(8, kind="int", low=1, high=64, doc="rotations tried, the identity included")
    dummy_cost: float = option(0.2, kind="float", low=0, low_open=True,
                               doc="cost of leaving a point unmatched in the assignment")
    n_angle: int = option(12, kind="int", low=1, high=360, doc="2-D shape context angle bins")
    n_radius: int = option(5, kind="int", low=1, high=50, doc="shape context radius bins")
    n_centers: int = option(15, kind="int", low=1, high=1000, doc="Gaussian kernel centers (M)")
    beta: float = option(0.8, kind="float", low=0, low_open=True, doc="kernel width, exp(-beta |x - c|^2)")
    lam: float = option(0.5, kind="float", low=0, doc="RKHS regularization (lambda)")
    sigma2_init: float = option(0.05, kind="float", low=0, low_open=True, doc="first L2E annealing scale sigma^2")
    anneal_rate: float = option(0.5, kind="float", low=0, high=1, low_open=True,
                                doc="factor of sigma^2 per annealing step")
    n_anneal: int = option(4, kind="int", low=1, high=60, doc="L2E annealing scales per round")
    max_iter: int = option(3, kind="int", low=1, high=1000, doc="re-weighting iterations per scale at most")
    support_radius: float = option(0.3, kind="float", low=0, low_open=True,
                                   doc="support radius of the descriptors from round 2")
    support_decay: float = option(0.7, kind="float", low=0, high=1, low_open=True,
                                  doc="factor of the support radius per round")
    support_min: float = option(0.05, kind="float", low=0, low_open=True, doc="smallest support radius")
    max_points: int = option(800, kind="int", low=10, high=3000,
                             doc="points of each set used for descriptors and assignment at most")
    n_probe_rounds: int = option(2, kind="int", low=1, high=100,
                                 doc="rounds each rotation hypothesis runs before they are compared")
    rotation_margin: float = option(0.5, kind="float", low=0, high=1, high_open=True,
                                    doc="2-D: share of the identity's misfit another rotation must remove")
    n_refine: int = option(10, kind="int", low=0, high=1000, doc="EM refinement steps after the rounds (0: none)")
    outlier_weight: float = option(0.5, kind="float", low=0, high=1, high_open=True,
                                   doc="weight of the uniform outlier term of the EM steps, in [0, 1)")
    outlier_passes: int = option(2, kind="int", low=0, high=10,
                                 doc="further passes at most while much of the target is unexplained")
    outlier_share: float = option(0.2, kind="float", low=0, high=1, high_open=True,
                                  doc="share of unexplained target points that starts another pass")

    def __post_init__(self) -> None:
        check_declared(self)


class _Describer:
    """Shape context of a (sub)set in 2-D or 3-D with the options' binning."""

    def __init__(self, opts: RegistrationOptions, dim: int):
        self.opts, self.dim = opts, dim

    def __call__(self, pts: np.ndarray, support: np.ndarray | None = None) -> np.ndarray:
        o = self.opts
        if self.dim == 2:
            return shape_context(pts, n_angle=o.n_angle, n_radius=o.n_radius, support=support)
        return shape_context_3d(pts, n_radius=o.n_radius, support=support)


def _assign(cost: np.ndarray, dummy: float) -> tuple[np.ndarray, np.ndarray]:
    # raised to the median best cost so that at least about half the points can always match
    return match_descriptors(cost, max(dummy, float(np.median(cost.min(1)))))


@dataclass
class _Track:
    """One rotation hypothesis followed through the rounds.

    The fits run in the rotated frame ``ur = us R^T``; ``x`` is the warped model subset.
    """

    rot: np.ndarray
    ur: np.ndarray
    x: np.ndarray
    hx0: np.ndarray | None = None  # descriptors of x before the first round, when known
    model: Model | None = None
    resid2: np.ndarray | None = None  # squared residuals of the last fit's matches
    sigma2_fit: float = np.inf  # the last annealing scale of that fit
    scale: float | None = None  # residual scale, once asked for (set by the EM refinement)
    rounds: int = 0
    moved: float = np.inf

    @property
    def sigma(self) -> float:
        """Residual scale of the last fit: partial-L2E estimate, computed on first use."""
        if self.scale is None:
            self.scale = (float(np.sqrt(l2e_scale(self.resid2, self.sigma2_fit, self.x.shape[1])))
                          if self.resid2 is not None else np.inf)
        return self.scale


def _fit(u: np.ndarray, y: np.ndarray, opts: L2EOptions,
         rng: np.random.Generator) -> tuple[Model, np.ndarray, float]:
    """L2E estimate of an affine + kernel map from the matches ``u -> y``, its squared residuals and last scale.

    The coarse level of :func:`reglib.robust.l2e.l2e_fit` (the published annealing, by the same
    re-weighted solver), without its finer levels and inlier classification, which a round of the
    loop does not use.
    """
    centers = farthest_point_centers(u, opts.n_centers, rng)
    solver = WeightedSolver(u, y, centers, opts.beta, "affine")
    model = Model(LinearPart("affine", np.c_[np.eye(u.shape[1]), np.zeros(u.shape[1])]), centers, opts.beta,
                  np.zeros((len(centers), u.shape[1])))
    sigma2 = opts.sigma2_init
    for k in range(opts.n_anneal + 1):
        sigma2 = opts.sigma2_init * opts.anneal_rate**k
        model, _, _ = reweighted_fit(solver, model, sigma2, opts, opts.lam if opts.lam is not None else 0.0)
    e2 = ((y - model.predict(u, solver.basis)) ** 2).sum(1)
    return model, e2, sigma2


def _hellinger_cost(ha: np.ndarray, hb: np.ndarray) -> np.ndarray:
    """Squared Hellinger distance sum_k (sqrt(a_k) - sqrt(b_k))^2 of normalized histograms: one matrix product.

    It agrees with chi^2 to first order for similar histograms and lies within a factor 2 of it
    elsewhere; used where many hypotheses are screened, chi^2 where the final matches are made.
    """
    return np.maximum(2.0 - 2.0 * (np.sqrt(ha) @ np.sqrt(hb).T), 0.0)


def _fit_score(x: np.ndarray, y: np.ndarray, y_tree: cKDTree, sigma2: float) -> float:
    """Mean Gaussian weight of nearest-neighbor distances, model -> target and target -> model.

    The first term is the L2E criterion's data term for the registered model against its nearest
    targets; the second keeps a warp that folds the model onto one part of the target from winning.
    """
    to_y = y_tree.query(x)[0]
    to_x = cKDTree(x).query(y)[0]
    return float(np.exp(-to_y**2 / (2.0 * sigma2)).mean() + np.exp(-to_x**2 / (2.0 * sigma2)).mean())


@dataclass(frozen=True, eq=False)
class _Loop:
    """What every round of one registration shares: the descriptor, the options, a round's L2E options, the rng."""

    describe: _Describer
    opts: RegistrationOptions
    l2e_opts: L2EOptions
    rng: np.random.Generator


@dataclass(frozen=True, eq=False)
class _Target:
    """The target of one pass: its (sub)sampled points, their descriptors (of the first round) and k-d tree."""

    points: np.ndarray
    descriptors: np.ndarray
    tree: cKDTree


def _rounds(track: _Track, n: int, target: _Target, loop: _Loop,
            cost: Callable[[np.ndarray, np.ndarray], np.ndarray] = chi2_cost, restrict: bool = False) -> _Track:
    """``n`` more describe-match-estimate rounds of one hypothesis, matching descriptors by ``cost``.

    From the second round, points the current warp leaves far from the other set do not count in
    the descriptors (support); with ``restrict`` such target points cannot be matched either.
    """
    ys, hy_all, y_tree = target.points, target.descriptors, target.tree
    describe, opts, l2e_opts, rng = loop.describe, loop.opts, loop.l2e_opts, loop.rng
    d = ys.shape[1]
    for r in range(track.rounds, track.rounds + n):
        hy, sx = hy_all, None
        if r > 0:
            # support: only points the current warp puts near the other set count in descriptors
            radius = max(opts.support_min, opts.support_radius * opts.support_decay ** (r - 1))
            sx = y_tree.query(track.x)[0] < radius
            to_x = cKDTree(track.x).query(ys)[0]
            sy = to_x < radius
            if sy.sum() >= 3:
                hy = describe(ys, sy)
            if sx.sum() < 3:
                sx = None
            if restrict and sy.sum() >= 3:  # only supported target points may be matched
                ia, ib = _assign(cost(describe(track.x, sx), hy[sy]), opts.dummy_cost)
                ib = np.flatnonzero(sy)[ib]
            else:
                ia, ib = _assign(cost(describe(track.x, sx), hy), opts.dummy_cost)
        elif track.hx0 is not None:
            ia, ib = _assign(cost(track.hx0, hy), opts.dummy_cost)
        else:
            ia, ib = _assign(cost(describe(track.x, sx), hy), opts.dummy_cost)
        track.rounds = r + 1
        if len(ia) < max(d + 2, 5):  # nothing to estimate from: keep the current map
            continue
        model, track.resid2, track.sigma2_fit = _fit(track.ur[ia], ys[ib], l2e_opts, rng)
        new = model.predict(track.ur)
        track.moved = float(np.abs(new - track.x).max(initial=0.0))
        track.x, track.model, track.scale = new, model, None
    return track


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


def _refine(track: _Track, ys: np.ndarray, opts: RegistrationOptions, sigma2_floor: float) -> _Track:
    """EM steps of a Gaussian mixture with a uniform outlier term, seeded by the L2E result.

    The registered model points are the mixture's centroids (as in CPD [2]);
    each target point spreads its responsibility over the centroids near it, or over the outlier
    term (weight ``outlier_weight``), so target outliers and model parts the target lacks pull on
    nothing. The M-step is the weighted kernel regression of the L2E solver with each centroid's
    total responsibility as its weight and the responsibility-weighted mean of the targets as its
    goal. This uses every target point rather than one assigned partner, which the
    one-to-one shape-context assignment cannot offer once outliers crowd the target.
    """
    if track.model is None or opts.n_refine == 0:
        return track
    ur, model = track.ur, track.model
    d = ur.shape[1]
    sigma2 = max(track.sigma**2, sigma2_floor)
    w = opts.outlier_weight
    x = track.x
    y2 = (ys * ys).sum(1)
    for _ in range(opts.n_refine):
        p = cpd_posterior(ys, x, sigma2, w)  # (model, target): the CPD E-step, the model as centroids
        p1 = p.sum(1)
        sp = float(p1.sum())
        if sp <= 1e-12:
            break
        py = p @ ys
        goal = py / np.maximum(p1, 1e-300)[:, None]
        solver = WeightedSolver(ur, goal, model.centers, model.beta, "affine")
        old = x
        model = solver.solve(p1, model, opts.lam * sigma2 * sp)
        new = model.predict(ur, solver.basis)
        track.moved = float(np.abs(new - x).max(initial=0.0))
        x = new
        # the scale only shrinks: grown, the Gaussians would start to take in the outliers
        # sum_mn p_mn |y_n - x_m|^2 (with the pre-step centroids x), without an (N, M) distance array
        spread = float(p.sum(0) @ y2 - 2.0 * np.einsum("md,md->", old, py) + p1 @ (old * old).sum(1))
        sigma2 = max(min(spread / (d * sp), sigma2), sigma2_floor)
    track.x, track.model, track.scale = x, model, float(np.sqrt(sigma2))
    return track


def _affine(model: Model) -> np.ndarray:
    """[A | t] of the model's linear part (the registration's models are all affine)."""
    d = model.centers.shape[1]
    return model.linear.matrix if model.linear is not None else np.c_[np.eye(d), np.zeros(d)]


def _unrotate(model: Model, rot: np.ndarray) -> Model:
    """The map u -> g(R u) as a model on u: exact, since exp(-beta |R u - c|^2) = exp(-beta |u - R^T c|^2)."""
    lin = _affine(model)
    return Model(LinearPart("affine", np.c_[lin[:, :-1] @ rot, lin[:, -1]]), model.centers @ rot, model.beta,
                 model.weights)


_GOOD_ENOUGH = 0.05  # misfit (2 - score) below which no further rotation hypothesis is tried


def sc_l2e_register(u: np.ndarray, y: np.ndarray, opts: RegistrationOptions, rng: np.random.Generator) -> WarpFit:
    """Register the normalized model ``u`` onto the normalized target ``y`` (the module's loop).

    Returns the map, the rounds run, whether the last round settled (moved no point by more than
    1e-3), and the reach for correspondences (normalized units).
    """
    d = u.shape[1]
    us = farthest_point_centers(u, opts.max_points, rng) if len(u) > opts.max_points else u
    ys = farthest_point_centers(y, opts.max_points, rng) if len(y) > opts.max_points else y
    describe = _Describer(opts, d)
    y_tree = cKDTree(ys)
    l2e_opts = L2EOptions(n_centers=opts.n_centers, beta=opts.beta, lam=opts.lam, sigma2_init=opts.sigma2_init,
                          anneal_rate=opts.anneal_rate, n_anneal=opts.n_anneal - 1, max_iter=opts.max_iter,
                          max_centers=0, min_matches=1)
    loop = _Loop(describe, opts, l2e_opts, rng)
    sigma2_score = opts.sigma2_init * opts.anneal_rate ** (opts.n_anneal - 1)
    hx, hy = describe(us), describe(ys)
    target = _Target(ys, hy, y_tree)
    rots = _rotation_candidates(us, ys, hx, hy, opts)  # (rotation, model descriptors under it)
    probe = min(opts.n_probe_rounds, opts.n_rounds) if len(rots) > 1 else opts.n_rounds
    # The given orientation is the prior: another rotation must explain at least a share
    # ``rotation_margin`` of what the identity leaves unexplained (a score is at most 2). On noisy,
    # unrotated data every hypothesis fits loosely and a wrong one can score a little higher by
    # folding the model over the noise; a true rotation fits nearly exactly, after enough rounds.
    # In 3-D the candidates are the data's own principal-axes frames, and on subsampled surfaces
    # no fit scores near 2 (two samplings of one surface are not point-for-point close): there the
    # best score wins.
    margin = opts.rotation_margin if d == 2 else 0.0

    def beats(score: float, identity_score: float) -> bool:
        return 2.0 - score < (1.0 - margin) * (2.0 - identity_score)

    scored: list[tuple[float, _Track]] = []
    for rot, hx0 in rots:
        ur = us @ rot.T
        track = _rounds(_Track(rot, ur, ur.copy(), hx0), probe, target, loop,
                        _hellinger_cost if len(rots) > 1 else chi2_cost)
        scored.append((_fit_score(track.x, ys, y_tree, sigma2_score), track))
        if 2.0 - scored[-1][0] < _GOOD_ENOUGH:  # nearly everything explained: no rotation can do better
            break
    identity_score, best = scored[0]
    other_score, other = max(scored[1:], key=lambda st: st[0], default=(-np.inf, None))
    if other is not None and beats(other_score, identity_score):
        best = other
    elif other is not None and other_score > identity_score:
        # undecided after the probe rounds: finish both and compare again
        finals = []
        for track in (best, other):
            track = _rounds(track, opts.n_rounds - track.rounds, target, loop)
            finals.append((_fit_score(track.x, ys, y_tree, sigma2_score), track))
        best = finals[1][1] if beats(finals[1][0], finals[0][0]) else finals[0][1]
    best = _rounds(best, opts.n_rounds - best.rounds, target, loop)
    best = _refine(best, ys, opts, sigma2_score / 16.0)
    reach = 3.0 * float(np.sqrt(sigma2_score))
    if best.model is None:  # no round found enough matches: the best rotation alone
        return WarpFit(model=Model(LinearPart("affine", np.c_[best.rot, np.zeros(d)]), np.zeros((0, d)), opts.beta,
                                   np.zeros((0, d))), n_iter=best.rounds, converged=False, reach=reach)
    n_rounds = best.rounds
    # Further passes while much of the target is left unexplained (outliers): the explained part
    # sets the target's normalization, alone enters the first round's target descriptors, and
    # from the second round only target points near the warped model may be matched.
    # ``ys_cur = (ys - center) / scale`` is the target in the current pass's frame.
    center, scale, ys_cur = np.zeros(d), 1.0, ys
    fitted = best.model
    for _ in range(opts.outlier_passes):
        explained = cKDTree(best.x).query(ys_cur)[0] < max(3.0 * best.sigma, opts.support_min)
        if explained.mean() >= 1.0 - opts.outlier_share or explained.sum() < 5:
            break
        c = ys_cur[explained].mean(0)
        sc = float(np.sqrt(((ys_cur[explained] - c) ** 2).sum(1).mean()))
        if sc <= 1e-9:
            break
        ys_next = (ys_cur - c) / sc
        again = _Track(best.rot, best.ur, (best.x - c) / sc)
        again = _rounds(again, opts.n_rounds, _Target(ys_next, describe(ys_next, explained), cKDTree(ys_next)), loop,
                        restrict=True)
        again = _refine(again, ys_next, opts, sigma2_score / 16.0)
        if again.model is None:  # no round of the pass found enough matches: keep the previous result
            break
        ys_cur, center, scale = ys_next, center + scale * c, scale * sc
        best, fitted = again, again.model
        n_rounds += best.rounds
    g = _unrotate(fitted, best.rot)
    lin = _affine(g)
    g = Model(LinearPart("affine", np.c_[scale * lin[:, :-1], scale * lin[:, -1] + center]), g.centers, g.beta,
              scale * g.weights)
    return WarpFit(model=g, n_iter=n_rounds, converged=best.moved < 1e-3, reach=reach)
