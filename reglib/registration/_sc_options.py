"""Options of the shape-context + L2E registration, ``register_points(method="l2e")``: :class:`RegistrationOptions`.

Each field is declared once with :func:`reglib.options.option` (kind, bounds, meaning); lengths
are in normalized units (RMS radius 1). The loop the fields steer is described in
:mod:`reglib.registration._sc_l2e`.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..options import check_declared, declared, option

__all__ = ["RegistrationOptions"]


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
        as in :class:`reglib.robust._l2e.L2EOptions`.
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
