"""The verdict of every result with ``converged``: the reason codes, named once, and the decisions.

``converged=True`` means the answer is supported by the data and may be used; ``converged=False``
comes with a ``reason``, one of :data:`REASONS`. The codes are written here only: every other module
reads these names, and the service's schema (``reason``'s enum and ``x-reasons``) carries them to its
page and clients. The measurements a decision needs stay where their data are (the fold test
needs the kernel model, :mod:`reglib.robust._verdict`; the images' evidence the images,
:mod:`reglib.dense`; a rigid answer's support the point sets, :mod:`reglib.registration._support`);
what is decided from the measured figures is decided here.

This module imports nothing else from reglib.
"""
from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Final, Literal

__all__ = ["FILTER_REASONS", "FOLDING", "IMAGE_REASONS", "INCONSISTENT", "LARGE_RESIDUAL", "NOT_SETTLED", "POOR_FIT",
           "REASONS", "REGISTRATION_REASONS", "SMALL_CLUSTER", "SMALL_OVERLAP", "TOO_FEW_INLIERS", "TOO_FEW_MATCHES",
           "UNDERDETERMINED", "UNSUPPORTED", "WEAK_FEATURES", "Reason", "fit_reason", "image_verdict", "pinned_reason",
           "polish_reason", "rigid_reason", "settled_reason"]

Reason = Literal["too_few_matches", "too_few_inliers", "small_cluster", "folding", "unsupported",
                 "small_overlap", "large_residual", "weak_features", "inconsistent", "underdetermined", "poor_fit",
                 "not_settled"]

# The estimator's (filter_matches, and every path that filters matches).
TOO_FEW_MATCHES: Final = "too_few_matches"
TOO_FEW_INLIERS: Final = "too_few_inliers"
SMALL_CLUSTER: Final = "small_cluster"
FOLDING: Final = "folding"
# match_images' own: the images rate the answer worse than no motion.
UNSUPPORTED: Final = "unsupported"
# A rigid registration's: what its support (or the reverse registration) says.
SMALL_OVERLAP: Final = "small_overlap"
LARGE_RESIDUAL: Final = "large_residual"
WEAK_FEATURES: Final = "weak_features"
INCONSISTENT: Final = "inconsistent"
UNDERDETERMINED: Final = "underdetermined"
# A non-rigid registration's that measures its own fit (CPD-Net).
POOR_FIT: Final = "poor_fit"
# An iterative registration's (and the shape-context image path's): its cap stopped it before it settled.
# The filter's cap is not a reason: its capped answers score like the others on the labelled real pairs;
# a registration's capped answers are much more often wrong (benchmarks/README.md).
NOT_SETTLED: Final = "not_settled"

FILTER_REASONS: Final[tuple[Reason, ...]] = (TOO_FEW_MATCHES, TOO_FEW_INLIERS, SMALL_CLUSTER, FOLDING)
"""Why a :class:`~reglib.FilterResult` says ``converged=False``."""
IMAGE_REASONS: Final[tuple[Reason, ...]] = (*FILTER_REASONS, UNSUPPORTED, NOT_SETTLED)
"""Why an :class:`~reglib.ImageMatch` says ``converged=False``."""
REGISTRATION_REASONS: Final[tuple[Reason, ...]] = (SMALL_OVERLAP, LARGE_RESIDUAL, WEAK_FEATURES, INCONSISTENT,
                                                   UNDERDETERMINED, POOR_FIT, NOT_SETTLED)
"""Why a registration says ``converged=False`` (the first five: a rigid one's; the last: any method's cap)."""
REASONS: Final[Mapping[Reason, str]] = MappingProxyType({
    TOO_FEW_MATCHES: "too few putative matches (fewer than the estimator needs)",
    TOO_FEW_INLIERS: "too few of the matches agree with one smooth transformation",
    SMALL_CLUSTER: "the matches that agree lie in one small cluster of both images",
    FOLDING: "the transformation folds the image over itself",
    UNSUPPORTED: "the images do not look clearly more alike under the transformation found than with no motion",
    SMALL_OVERLAP: "too little of the model lands on the target",
    LARGE_RESIDUAL: "the overlapping points lie too far from the target",
    WEAK_FEATURES: "the pose keeps too few of the local feature matches it started from",
    INCONSISTENT: "registering the target onto the model gives a different answer",
    UNDERDETERMINED: "a pose a small move away fits the data as well: the data do not pin the answer down",
    POOR_FIT: "the registered model lies too far from the target's points for the answer to be used",
    NOT_SETTLED: "the method reached its iteration cap while its answer was still changing",
})
"""Every reason code (in the order of the lists above, each once) and what it tells a user, in words (the service's
schema carries these, and its page shows them)."""

# A rigid answer's support (reglib.registration._support.Support) at which it is not an answer; chosen on the
# global case of benchmarks/bench_rigid.py --global (its tuning seeds).
MIN_OVERLAP = 0.1        # share of the model within 3 target spacings of the target, at least
MAX_RESIDUAL = 1.5       # median distance of those points, in target spacings, at most
MIN_FEATURES = 0.3       # share of the feature start's inliers kept by the final pose ...
FEATURE_RESIDUAL = 1.0   # ... counts against it when the residual is above this many spacings too


def rigid_reason(overlap: float, residual: float, features: float | None) -> Reason | None:
    """The first of :data:`SMALL_OVERLAP`, :data:`LARGE_RESIDUAL`, :data:`WEAK_FEATURES` that a rigid
    answer's measured support meets, or None when it is enough.

    ``overlap``: the share of the model within reach of the target; ``residual``: their median
    distance in target spacings; ``features``: the share of the feature start's inliers kept (None
    without a feature start). Few kept counts only with a residual above a spacing as well: a
    symmetric shape's best feature hypothesis may be its twin, which the true pose does not keep.
    """
    if overlap < MIN_OVERLAP:
        return SMALL_OVERLAP
    if residual > MAX_RESIDUAL:
        return LARGE_RESIDUAL
    if features is not None and features < MIN_FEATURES and residual > FEATURE_RESIDUAL:
        return WEAK_FEATURES
    return None


# A rigid answer's neighbours (reglib.registration._pinned.neighbour_support): the best support of a pose moved
# by a share of the extent, over the answer's, at which the data do not pin the answer down. At 1 a neighbour is
# as well supported as the answer; a direction the data do not constrain at all measures 1 up to the sampling
# noise of the two sets, hence a little under 1 (chosen on the global case's tuning seeds, in the gap between the
# successes and the failures there: benchmarks/README.md).
MAX_NEIGHBOUR_SUPPORT = 0.99


def pinned_reason(neighbour_support: float) -> Reason | None:
    """:data:`UNDERDETERMINED` when a neighbour pose of a rigid answer is supported at least
    :data:`MAX_NEIGHBOUR_SUPPORT` times as well as the answer (the data do not pin it down), else None."""
    return UNDERDETERMINED if neighbour_support >= MAX_NEIGHBOUR_SUPPORT else None


# A probabilistic method's rigid answer (register_points' _polish_shift): the mean displacement of the registered
# model, in target spacings, by a robust ICP from it, above which the answer is not where the data put it: a spacing
# is the resolution of the data, and a right answer's polish moves it by a fraction of one (benchmarks/README.md).
MAX_POLISH_SHIFT = 1.0


def polish_reason(shift_spacings: float) -> Reason | None:
    """:data:`POOR_FIT` when a robust fit from a rigid answer moves the registered model by more than
    :data:`MAX_POLISH_SHIFT` target spacings on average, else None."""
    return POOR_FIT if not shift_spacings <= MAX_POLISH_SHIFT else None


def image_verdict(reason: Reason | None, converged: bool, dense: str, evidence: float | None,
                  threshold: float, *, short_of_margin: bool = False) -> tuple[bool, Reason | None]:
    """``converged`` and ``reason`` of an image match, from its estimate's and the images' evidence.

    ``reason``, ``converged``: the estimate's (the sparse fit's reason; the dense fit's convergence
    when one was kept); ``dense``: the dense stage's outcome (``"kept"``, ...); ``evidence``: the
    images' sign-test z of the transform against no motion (None: not measured); ``threshold``: the
    z that counts as clear; ``short_of_margin``: the transform moves the images, yet the evidence does
    not rate it over no motion by the margin a usable answer reaches. An answer the images clearly rate
    worse than no motion is :data:`UNSUPPORTED`, and so is one short of the margin that would otherwise be
    usable; one from too few inliers that the dense stage kept and the images clearly rate over no
    motion has no reason left. ``converged`` is True only without a reason.
    """
    if evidence is not None:
        if evidence <= -threshold:
            return False, UNSUPPORTED
        if reason is not None and dense == "kept" and evidence >= threshold:
            reason = None
        if reason is None and short_of_margin:
            return False, UNSUPPORTED
    return converged and reason is None, reason


# The registered model's symmetric mean nearest-point distance to the target, in target spacings (median
# nearest-neighbour distance), above which a non-rigid answer is not one; chosen on CPD-Net's answers to the
# Chui-Rangarajan deformation series, levels 2-5 (benchmarks/README.md).
MAX_CHAMFER_SPACINGS = 0.33


def fit_reason(chamfer_spacings: float) -> Reason | None:
    """:data:`POOR_FIT` when a non-rigid answer's measured fit (the symmetric mean nearest-point distance
    between the registered model and the target, in target spacings) is over :data:`MAX_CHAMFER_SPACINGS`."""
    return POOR_FIT if not chamfer_spacings <= MAX_CHAMFER_SPACINGS else None


def settled_reason(converged: bool, reason: Reason | None) -> Reason | None:
    """A registration's reason: its method's own, else :data:`NOT_SETTLED` when its cap stopped it (``converged``
    False: the method's tolerance was not reached), else None."""
    if reason is not None or converged:
        return reason
    return NOT_SETTLED
