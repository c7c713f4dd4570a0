"""Options of the robust estimators: :class:`L2EOptions` and :class:`VFCOptions`.

Each field is declared once with :func:`reglib.options.option` (kind, bounds, meaning); lengths
are in normalized units (the matches are centred and scaled to an RMS radius of 1).

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of Transformation
       for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
.. [2] J. Ma, J. Zhao, J. Tian, A. L. Yuille, Z. Tu, "Robust Point Matching via Vector Field
       Consensus", IEEE Trans. Image Processing 23(4), 2014. :doi:`10.1109/TIP.2014.2307478`
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from ..errors import InputError
from ..options import check_declared, declared, option
from ._core import LINEAR_KINDS

__all__ = ["L2EOptions", "VFCOptions"]

_LINEAR = tuple(LINEAR_KINDS)


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class L2EOptions:
    """Options of the L2E estimator [1]_; all lengths are in normalized units (RMS radius 1).

    Parameters
    ----------
    linear : {"affine", "none", "homography", "rigid", "similarity"}
        Global part estimated jointly with the kernel field. "homography" is 2-D only; "rigid"
        (rotation + translation, in the caller's units) and "similarity" (and one scale) are
        solved by weighted Umeyama steps; with ``n_centers=0, max_centers=0`` they are the whole
        model, a robust rigid / similarity estimate from putative matches (2-D or 3-D).
    n_centers : int
        Basis size of the coarse stage (M in [1]; published 15).
    beta : float
        Kernel width of the coarse stage, k(x, c) = exp(-beta |x - c|^2) (beta in [1]; published 0.8).
    max_centers : int
        Upper bound on the fine stage's basis; it uses about one centre per ``matches_per_center``
        candidate matches, with beta grown in proportion to M. 0 turns the fine stage off.
    matches_per_center : float
        Candidate matches needed per fine-stage centre.
    lam : float, optional
        RKHS regularization (lambda in [1]). The ridge on tr(W^T K W) is lam * sigma^2 * sum_i phi_i,
        so, as in the stationarity condition of the criterion, it weakens as sigma is annealed; finer
        levels scale it by n_centers / M. None (default): 1.0 with a linear part; without one the
        kernel must carry the global motion as well, and it is 0.1 (:attr:`regularization` is the
        value in use).
    sigma2_init, anneal_rate, n_anneal : float, float, int
        Annealing of sigma^2: sigma2_init * anneal_rate**k for k = 0..n_anneal (published 0.05, 0.5, 3;
        n_anneal at most 60).
    max_iter : int
        Cap on re-weighting iterations at the last annealing step of the coarse level (each step
        starts from the previous estimate; the earlier ones take at most 3). At most 1000.
    fine_iter : int
        Re-weighting iterations at each finer level after its first solve (which weighs the
        matches by the previous level's residuals). At most 100.
    tol : float
        An annealing step stops when no prediction moves by more than ``tol`` (normalized units);
        ``converged`` reports whether the last one did.
    score_scale : float
        Scores are the posterior of a match being true under a Gaussian-inlier / uniform-outlier
        mixture fitted to the residuals; the final posterior widens the Gaussian's sigma by this
        factor (true feature-match residuals have heavier tails than a Gaussian). 1 disables it.
    inlier_threshold : float
        Score above which a match is an inlier (published 0.5).
    max_fit_points : int
        Matches the coarse level fits on, at most (a seeded random subset beyond it); a finer
        level with M centres fits on up to ``max(max_fit_points, 1.5 * matches_per_center * M)``
        of its candidates. The cost of a level's solve grows with its rows times M squared.
    max_work_points : int
        Matches the levels look at, at most (candidates are drawn from these); all N are scored at
        the end with the final transformation.
    min_matches : int
        Fewer putative matches than this give the "too few matches" answer.
    max_levels : int
        Finer levels at most after the coarse one (at most 20).
    regrow : int
        Fits at most after the finer levels that take in the matches far from the field whose residuals
        agree with their neighbours' (a steep local deformation the smoother levels missed:
        :func:`reglib.robust._locality.agreeing_far`); each is kept only if it keeps nearly every match the
        field explained and explains more. 0: none. At most 5.
    max_layers : int
        Independently moving layers to look for: 1 is one smooth field (the published method);
        2 (default) then searches the rejected matches for one more coherent layer (a part of the
        scene moving differently from its surroundings, e.g. across a depth discontinuity; see
        :mod:`reglib.robust._layers`) and keeps its matches as inliers, scored by their own affine
        fit. The transform stays the primary layer's.
    min_layer_matches : int
        Fewest matches a secondary layer may have (and many more than chance would give).
    start : {"locality", "identity"}
        First estimate of the coarse level. "locality" (default): the best, by the L2E criterion,
        of the identity, a solve weighted by how well each match's src and dst neighbourhoods
        agree (:mod:`reglib.robust._locality`) and one weighted by the best similarity through
        pairs of the most consistent matches (:mod:`reglib.robust._start`): no start near the
        answer is needed (any rotation, a large scale change, a small share of true matches).
        "identity": from the identity, as published.

    Upper bounds on the counts keep a request finite (each step costs up to a few ms) and are far
    beyond any use; :func:`reglib.options.option_specs` lists every bound.
    """

    linear: Literal["affine", "none", "homography", "rigid", "similarity"] = option(
        "affine", kind="choice", choices=_LINEAR, doc="global part estimated jointly with the kernel field")
    n_centers: int = option(15, kind="int", low=0, doc="basis size of the coarse stage (M)")
    beta: float = option(0.8, kind="float", low=0, low_open=True, doc="kernel width of the coarse stage")
    max_centers: int = option(300, kind="int", low=0, doc="basis size of the fine stage at most (0: no fine stage)")
    matches_per_center: float = option(4.0, kind="float", low=0, low_open=True,
                                       doc="candidate matches needed per fine-stage centre")
    lam: float | None = option(None, kind="float", low=0, optional=True,
                               doc="RKHS regularization lambda (None: 1.0 with a linear part, else 0.1)")
    sigma2_init: float = option(0.05, kind="float", low=0, low_open=True, doc="first annealing scale sigma^2")
    anneal_rate: float = option(0.5, kind="float", low=0, high=1, low_open=True,
                                doc="factor of sigma^2 per annealing step")
    n_anneal: int = option(3, kind="int", low=0, high=60, doc="annealing steps after the first")
    max_iter: int = option(10, kind="int", low=0, high=1000,
                           doc="re-weighting iterations at the coarse level's last step, at most")
    fine_iter: int = option(1, kind="int", low=0, high=100, doc="re-weighting iterations per finer level")
    tol: float = option(3e-4, kind="float", low=0, low_open=True,
                        doc="an annealing step stops when no prediction moves more (normalized units)")
    score_scale: float = option(1.5, kind="float", low=0, low_open=True,
                                doc="widening of the inlier Gaussian in the final posterior")
    inlier_threshold: float = option(0.5, kind="float", low=0, high=1, low_open=True, high_open=True,
                                     doc="score above which a match is an inlier")
    max_fit_points: int = option(1000, kind="int", low=10, doc="matches the coarse level fits on, at most")
    max_work_points: int = option(20000, kind="int", low=0, doc="matches the levels look at, at most")
    min_matches: int = option(6, kind="int", low=1, doc="fewer putative matches give the too-few-matches answer")
    max_levels: int = option(4, kind="int", low=0, high=20, doc="finer levels after the coarse one, at most")
    regrow: int = option(1, kind="int", low=0, high=5,
                         doc="fits taking in far matches that agree with their neighbours, at most")
    max_layers: int = option(2, kind="int", low=1, high=2,
                             doc="independently moving layers to look for (1 or 2)")
    min_layer_matches: int = option(8, kind="int", low=4, doc="fewest matches of a secondary layer")
    start: Literal["locality", "identity"] = option("locality", kind="choice", choices=("locality", "identity"),
                                                    doc="first estimate of the coarse level")

    def __post_init__(self) -> None:
        check_declared(self)
        if self.linear == "none" and self.n_centers == 0:
            raise InputError("`n_centers` must be >= 1 when `linear` is 'none': the kernel is then the whole model")

    @property
    def regularization(self) -> float:
        """The lambda in use: ``lam``, or its default for ``linear`` when ``lam`` is None."""
        if self.lam is not None:
            return self.lam
        return 1.0 if self.linear != "none" else 0.1


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class VFCOptions:
    """Options of VFC [2]_, published defaults (normalized units).

    Parameters
    ----------
    linear : {"none", "affine", "homography", "rigid", "similarity"}
        Global part fitted jointly (the published method has none).
    n_centers : int
        Sparse basis size (SparseVFC: 16).
    beta : float
        Kernel width, exp(-beta |x - c|^2) (published 0.1).
    lam : float
        Regularization lambda (published 3).
    theta : float
        Posterior above which a match is an inlier (published 0.75).
    outlier_volume : float
        Volume of the outliers' uniform density, the paper's a (published 10). Formerly ``a``.
    gamma : float
        Initial inlier share (published 0.9).
    max_iter : int
        EM iterations at most (published 500; at most 10000, which keeps a request finite).
    tol : float
        Stop when the relative change of the energy is below this (published 1e-5).
    min_matches : int
        Fewer putative matches give the "too few matches" answer.
    """

    RENAMED_FIELDS: ClassVar[dict[str, str]] = {"a": "outlier_volume"}

    linear: Literal["none", "affine", "homography", "rigid", "similarity"] = option(
        "none", kind="choice", choices=_LINEAR, doc="global part fitted jointly")
    n_centers: int = option(16, kind="int", low=1, doc="sparse basis size")
    beta: float = option(0.1, kind="float", low=0, low_open=True, doc="kernel width")
    lam: float = option(3.0, kind="float", low=0, doc="regularization lambda")
    theta: float = option(0.75, kind="float", low=0, high=1, low_open=True, high_open=True,
                          doc="posterior above which a match is an inlier")
    outlier_volume: float = option(10.0, kind="float", low=0, low_open=True,
                                   doc="volume of the outliers' uniform density (a)")
    gamma: float = option(0.9, kind="float", low=0, high=1, low_open=True, high_open=True,
                          doc="initial inlier share")
    max_iter: int = option(500, kind="int", low=1, high=10000, doc="EM iterations at most")
    tol: float = option(1e-5, kind="float", low=0, low_open=True, doc="relative change of the energy that stops EM")
    min_matches: int = option(6, kind="int", low=1, doc="fewer putative matches give the too-few-matches answer")

    def __post_init__(self) -> None:
        check_declared(self)
