"""The options the probabilistic rigid methods share, each field declared once.

``bayes``, ``color-gmm`` and ``density-adaptive`` all run an EM-like loop (expectation-maximization,
or variational inference for ``bayes``) on a subsample of each point set, in normalized units
(each set centered on its mean, both divided by the larger RMS radius), and stop on the same test:
the model's motion changed by less than ``tol`` (radians of rotation plus normalized units of
translation) in two successive iterations. They also start from a place chosen by ``init`` as
for ``"icp"`` (:class:`~reglib.registration._icp_options.ICPLoopOptions`, whose declarations of the
start's fields are reused here, :data:`START_FIELDS`): ``"centroid"`` (the identity rotation with
the centroids aligned, where the normalized units start: the only start before ``init``, and still
the default of ``bayes``), ``"given"`` (the caller's pose), ``"search"`` (the rotation search of
:mod:`reglib.registration._start`) or ``"features"`` (FPFH matches and RANSAC over all rotations,
:mod:`reglib.registration._feature_start`; the default of ``color-gmm`` and ``density-adaptive``,
where the probabilistic benchmark's success rose with it and no case did worse).
:class:`EMOptions` declares those fields;
:class:`SceneEMOptions` adds the latent scene mixture of ``color-gmm`` and ``density-adaptive``
(the joint registration of Evangelidis and Horaud [1]_).

A method whose best default differs declares the field again with :func:`with_default`: same
kind, bounds and meaning, another default.

References
----------
.. [1] G. D. Evangelidis, R. Horaud, "Joint Alignment of Multiple Point Sets with Batch and
       Incremental Expectation-Maximization", IEEE TPAMI 40(6), 2018.
       :doi:`10.1109/TPAMI.2017.2717829`
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from ..options import check_declared, declared, option
from ._icp_options import FeatureEstimator, ICPLoopOptions, Init

__all__ = ["START_FIELDS", "EMOptions", "SceneEMOptions", "with_default"]

START_FIELDS = ("init", "n_rotations", "init_max_angle", "init_points", "init_iter", "init_keep", "init_margin",
                "feature_voxel", "feature_iter", "feature_estimator")
"""The fields of :class:`~reglib.registration._icp_options.ICPLoopOptions` that choose the start."""


def _start_field(name: str, default: Any = dataclasses.MISSING) -> Any:
    """The start field ``name`` of ``ICPLoopOptions``, declared again (same kind, bounds, meaning)."""
    field = ICPLoopOptions.__dataclass_fields__[name]
    value = field.default if default is dataclasses.MISSING else default
    return dataclasses.field(default=value, metadata=field.metadata)


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class EMOptions:
    """Iteration cap, stopping tolerance and subsample size of a probabilistic rigid method.

    Parameters
    ----------
    max_iter : int
        Iterations at most (1 to 1000).
    tol : float
        The loop stops (converged) when the motion changes by less than ``tol`` (radians plus
        normalized units) in two successive iterations; > 0.
    max_points : int
        Points of each set the loop uses at most (10 to 3000); beyond it a subsample, drawn as
        the method says (deterministic for a given ``rng``). Memory grows with its square (or
        with it times the components of a scene mixture).
    init : {"centroid", "given", "search", "features"}
        The pose the loop starts from: ``"centroid"`` the identity rotation with the centroids
        (of the subsamples) aligned, the method's start before ``init`` existed; ``"given"`` the
        caller's pose (the identity map); ``"search"`` the rotation search and ``"features"`` the
        FPFH feature start (3-D; the search where it finds nothing) of ``"icp"``, computed on
        the whole sets in the caller's units
        (:class:`~reglib.registration._icp_options.ICPLoopOptions`).
    n_rotations, init_max_angle, init_points, init_iter, init_keep, init_margin
        ``init="search"``: as for ``"icp"``.
    feature_voxel, feature_iter, feature_estimator
        ``init="features"``: as for ``"icp"``.
    """

    max_iter: int = option(100, kind="int", low=1, high=1000, doc="iterations at most")
    tol: float = option(1e-5, kind="float", low=0, low_open=True,
                        doc="stop when the motion changes less (radians plus normalized units) twice running")
    max_points: int = option(1000, kind="int", low=10, high=3000, doc="points of each set used at most")
    init: Init = _start_field("init", "centroid")
    n_rotations: int = _start_field("n_rotations")
    init_max_angle: float = _start_field("init_max_angle")
    init_points: int = _start_field("init_points")
    init_iter: int = _start_field("init_iter")
    init_keep: int = _start_field("init_keep")
    init_margin: float = _start_field("init_margin")
    feature_voxel: float | None = _start_field("feature_voxel")
    feature_iter: int = _start_field("feature_iter")
    feature_estimator: FeatureEstimator = _start_field("feature_estimator")

    def __post_init__(self) -> None:
        check_declared(self)

    def start_options(self) -> ICPLoopOptions:
        """The ``ICPLoopOptions`` whose start (``init`` and its settings) is this one's."""
        return ICPLoopOptions(**{name: getattr(self, name) for name in START_FIELDS})


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class SceneEMOptions(EMOptions):
    """:class:`EMOptions` and the latent scene mixture fitted to both sets at once [1]_.

    Parameters
    ----------
    n_components : int
        Components K of the scene mixture, placed initially on a voxel-grid sample of the target
        (2 to 3000). Fewer components widen the basin of convergence and blur the geometry.
    outlier : float
        Weight of the uniform outlier class over the bounding box of both sets, in [0, 1).
    """

    n_components: int = option(150, kind="int", low=2, high=3000, doc="components of the scene mixture")
    outlier: float = option(0.05, kind="float", low=0, high=1, high_open=True,
                            doc="weight of the uniform outlier class, in [0, 1)")


def with_default(name: str, default: Any) -> Any:
    """The :class:`EMOptions` field ``name`` declared again with another default (same kind, bounds, meaning).

    A method whose benchmark prefers another start declares ``init = with_default("init", "features")``.
    """
    field = EMOptions.__dataclass_fields__[name]
    return dataclasses.field(default=default, metadata=field.metadata)
