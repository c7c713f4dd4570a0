"""The shape-context + L2E registration loop: ``register_points(method="l2e")``.

This is the loop of Ma et al. [1] (Sec. 4): describe both sets by shape context
(2-D: :func:`reglib.features._shape_context.shape_context`; 3-D:
:func:`reglib.features._shape_context_3d.shape_context_3d`), match them one-to-one by an
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
:func:`reglib.robust._l2e.l2e_fit`, the one :func:`reglib.filter_matches` uses, at its coarse
level), restarted from the published annealing every round as in the published demo.

The options are :class:`~reglib.registration._sc_options.RegistrationOptions`; the stages live in
private modules: ``_sc_match`` (shape-context description and assignment), ``_sc_rounds`` (the
rounds and the EM refinement of one hypothesis) and ``_sc_rotation`` (the rotation candidates,
their score and the map back). This module runs the hypotheses and the outlier passes.

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of
       Transformation for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
.. [2] A. Myronenko, X. Song, "Point Set Registration: Coherent Point Drift", IEEE TPAMI 32(12),
       2010. :doi:`10.1109/TPAMI.2010.46`
"""
from __future__ import annotations

from typing import cast

import numpy as np
from scipy.spatial import cKDTree

from .._transforms import LinearPart
from ..features import chi2_cost
from ..robust import L2EOptions, Model, farthest_point_centers
from ._result import WarpFit
from ._sc_match import _Describer, _hellinger_cost
from ._sc_options import RegistrationOptions
from ._sc_rotation import _affine, _fit_score, _rotation_candidates, _unrotate
from ._sc_rounds import _Loop, _refine, _rounds, _Target, _Track

__all__ = ["RegistrationOptions", "sc_l2e_register"]


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
        explained = cast(np.ndarray, cKDTree(best.x).query(ys_cur)[0]) < max(3.0 * best.sigma, opts.support_min)
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
