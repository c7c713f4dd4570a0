"""Options of rigid ICP: :class:`ICPLoopOptions` (shared with ``"icp-hmrf"``) and :class:`ICPOptions`.

Each field is declared once with :func:`reglib.options.option` (kind, bounds, meaning); lengths
are in the caller's units. Upper bounds on the counts keep every request finite in time and
memory. The algorithm the fields steer is described in :mod:`reglib.registration._icp` (the
loop), :mod:`reglib.registration._losses` (the robust functions) and
:mod:`reglib.registration._start` (the initial alignment).
"""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Literal

from ..options import check_declared, declared, option
from ._losses import LOSSES, Loss

__all__ = ["FEATURE_ESTIMATORS", "INITS", "SOLVERS", "VARIANTS", "ICPLoopOptions", "ICPOptions"]

Variant = Literal["point_to_point", "point_to_plane"]
Solver = Literal["svd", "fa3r"]
Init = Literal["features", "given", "centroid", "search"]

VARIANTS: tuple[Variant, ...] = ("point_to_point", "point_to_plane")
SOLVERS: tuple[Solver, ...] = ("svd", "fa3r")
INITS: tuple[Init, ...] = ("features", "given", "centroid", "search")
FeatureEstimator = Literal["ransac", "l2e"]
FEATURE_ESTIMATORS: tuple[FeatureEstimator, ...] = ("ransac", "l2e")


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class ICPLoopOptions:
    """The options ``"icp"`` and ``"icp-hmrf"`` share: the residual, the iteration and the start.

    Parameters
    ----------
    variant : {"point_to_plane", "point_to_point"}
        Residual: distance to the target point, or to the target point's tangent plane.
    max_iter : int
        ICP iterations at most (<= 1000).
    tol : float
        Stop when the RMS motion of the model samples in one iteration is below ``tol`` times
        the model's RMS radius. Formerly ``tolerance``.
    k_normals : int
        Neighbors for the PCA normals of the target (point-to-plane without ``target_normals``).
    solver : {"svd", "fa3r"}
        Closed-form point-to-point step: Umeyama's SVD or FA3R (3-D only).
    init : {"search", "features", "centroid", "given"}
        Initial alignment: ``"features"`` FPFH matches + RANSAC over all rotations
        (:mod:`reglib.registration._feature_start`; 3-D, falls back to the search), ``"search"``
        the rotation search of :mod:`reglib.registration._start`, ``"centroid"`` the centroids
        aligned, ``"given"`` the caller's pose.
    n_rotations : int
        Rotations sampled over all of SO(3) (2-D: over the full turn) by ``init="search"``.
    init_max_angle : float
        Degrees; rotation hypotheses beyond this angle from the identity are skipped.
    init_points, init_iter, init_keep : int
        Model samples, trimmed steps per hypothesis, and hypotheses kept for the second round of
        the search.
    init_margin : float
        The caller's pose wins the search when its score is at least (1 - init_margin) times the
        best.
    feature_voxel : float, optional
        ``init="features"``: voxel side of the downsampled sets (caller's units); None: 1/60 of
        the larger bounding-box diagonal.
    feature_iter : int
        ``init="features"``: RANSAC triples drawn.
    feature_estimator : {"ransac", "l2e"}
        ``init="features"``: the rigid estimate from the matches: RANSAC on triples, or L2E with a
        rigid linear part (:func:`reglib.robust.filter_matches`).
    """

    RENAMED_FIELDS: ClassVar[dict[str, str]] = {"tolerance": "tol"}

    variant: Variant = option("point_to_plane", kind="choice", choices=VARIANTS,
                              doc="residual: to the target point or to its tangent plane")
    max_iter: int = option(50, kind="int", low=1, high=1000, doc="ICP iterations at most")
    tol: float = option(1e-5, kind="float", low=0, low_open=True,
                        doc="stop when the RMS motion per iteration is below tol times the model's RMS radius")
    k_normals: int = option(10, kind="int", low=3, high=100, doc="neighbors for the PCA normals of the target")
    solver: Solver = option("svd", kind="choice", choices=SOLVERS,
                            doc="closed-form point-to-point step: SVD or FA3R (3-D only)")
    init: Init = option("search", kind="choice", choices=INITS, doc="initial alignment")
    n_rotations: int = option(512, kind="int", low=1, high=4096, doc="rotations sampled by the global search")
    init_max_angle: float = option(90.0, kind="float", low=0, high=180,
                                   doc="degrees; rotation hypotheses beyond it are skipped")
    init_points: int = option(200, kind="int", low=10, high=5000, doc="model samples of the global search")
    init_iter: int = option(10, kind="int", low=1, high=200, doc="trimmed ICP steps per search hypothesis")
    init_keep: int = option(6, kind="int", low=1, high=64,
                            doc="hypotheses kept for the second round of the search")
    init_margin: float = option(0.05, kind="float", low=0, high=1, high_open=True,
                                doc="the caller's pose wins within this share of the best score")
    feature_voxel: float | None = option(None, kind="float", low=0, low_open=True, optional=True,
                                         doc="voxel side of the feature start (None: 1/60 of the diagonal)")
    feature_iter: int = option(20000, kind="int", low=10, high=1_000_000,
                               doc="RANSAC triples drawn by the feature start")
    feature_estimator: FeatureEstimator = option("ransac", kind="choice", choices=FEATURE_ESTIMATORS,
                                                 doc="rigid estimate of the feature start from its matches")

    def __post_init__(self) -> None:
        check_declared(self)

    def loop_fields(self) -> dict[str, Any]:
        """The shared fields and their values (to build one kind of options from the other)."""
        return {f.name: getattr(self, f.name) for f in fields(ICPLoopOptions)}


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class ICPOptions(ICPLoopOptions):
    """Options of ``register_points(method="icp")``; lengths are in the caller's units.

    Parameters
    ----------
    loss : str
        Robust function, one of ``LOSSES`` (:mod:`reglib.registration._losses` for the formulas).
    tuning : float, optional
        Tuning constant k of the loss in units of the scale (``DEFAULT_TUNING[loss]`` when None).
    scale : float, optional
        Residual scale sigma (caller's units); None re-estimates it every iteration by the MAD.
    scale_quantile : float, optional
        The estimated scale is the ``scale_quantile`` quantile of |r| over that of unit Gaussian
        noise: 0.5 is the MAD; lower values tolerate more pairs from outside the overlap (at most
        1 - q of them), at some cost in efficiency. In [0.05, 0.95]. None (default): the MAD,
        taken over the VarTrimmed share of the pairs when that share is below one half
        (:mod:`reglib.registration._icp`).
    trim_ratio : float, optional
        Fraction of pairs kept by ``loss="trimmed"``, in (0, 1]; None chooses it every iteration
        (Babin's VarTrimmed, Chetverikov's xi minimizing RMS(xi) / xi^3 over [0.2, 1]).
    max_distance : float, optional
        Pairs farther apart than this (caller's units) are dropped, for every loss; with
        ``loss="max_distance"`` it is the threshold (``tuning`` times sigma when None).
    normal_angle : float
        Degrees; with ``model_normals`` given, pairs whose normals differ by more (sign ignored)
        are dropped.
    max_points : int
        Model points the robust ICP iterates on at most (a random sample beyond it).
    verify : bool
        With a searched start (``init`` "features" or "search"), check the answer: 3-D, reason
        ``underdetermined`` when a pose moved by 1 % of the target's extent along one of the overlap's
        principal directions is as well supported (:mod:`reglib.registration._pinned`); then, with a measured
        overlap under 65 % and no model points scattered through the volume, also register the target onto
        the model the same way, and answer ``converged=False`` with reason ``inconsistent`` when the two answers
        disagree: composed, they move the target's points by more than 1 % of its extent on average. About twice the
        time where the backward run runs.
    init : {"features", "search", "centroid", "given"}
        Initial alignment, as :class:`ICPLoopOptions`'s, but ``"features"`` by default.
    variant, max_iter, tol, k_normals, solver, n_rotations, init_max_angle, init_points, \
init_iter, init_keep, init_margin, feature_voxel, feature_iter, feature_estimator
        The residual, the iteration and the initial alignment: :class:`ICPLoopOptions`.
    """

    init: Init = option("features", kind="choice", choices=INITS, doc="initial alignment")
    loss: Loss = option("cauchy", kind="choice", choices=LOSSES, doc="robust function")
    tuning: float | None = option(None, kind="float", low=0, low_open=True, optional=True,
                                  doc="tuning constant k in units of the scale (None: the loss's default)")
    scale: float | None = option(None, kind="float", low=0, low_open=True, optional=True,
                                 doc="residual scale sigma (None: re-estimated every iteration)")
    scale_quantile: float | None = option(None, kind="float", low=0.05, high=0.95, optional=True,
                                          doc="quantile of |r| the scale is estimated from (None: adaptive MAD)")
    trim_ratio: float | None = option(0.7, kind="float", low=0, high=1, low_open=True, optional=True,
                                      doc="fraction of pairs kept by the trimmed loss (None: VarTrimmed)")
    max_distance: float | None = option(None, kind="float", low=0, low_open=True, optional=True,
                                        doc="pairs farther apart are dropped (caller's units)")
    normal_angle: float = option(60.0, kind="float", low=0, high=90, low_open=True,
                                 doc="degrees; pairs whose model and target normals differ more are dropped")
    max_points: int = option(10000, kind="int", low=10, high=1_000_000,
                             doc="model points the robust ICP iterates on at most")
    verify: bool = option(True, kind="bool",
                          doc="say an answer the data do not pin down or (below 65 % overlap) that "
                              "the target registered onto the model disagrees with")

    def unused_extras(self, given: Collection[str]) -> dict[str, str]:
        """The extras among the ``given`` argument names that ICP with these options leaves unused.

        Target normals serve the point-to-plane residual and the normal check of ``model_normals``;
        point-to-point without model normals reads neither (the method record's ``unused``).

        Parameters
        ----------
        given : collection of str
            Argument names of :data:`~reglib.registration._methods.EXTRAS` that are given.

        Returns
        -------
        dict
            {argument: the condition under which it is unused, in words}; empty when all are used.
        """
        if self.variant == "point_to_point" and "target_normals" in given and "model_normals" not in given:
            return {"target_normals": "with variant='point_to_point' unless `model_normals` are given too"}
        return {}
