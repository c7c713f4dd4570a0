"""How much of a rigid registration the data support, and the ``reason`` when it is too little.

After the robust ICP, :func:`measure_support` looks at the answer from three sides:

- **overlap**: the share of (sampled) model points that land within ``_NEAR`` target spacings
  of the target;
- **residual**: the median distance of those points to the target, in target spacings (a right
  pose leaves the noise, about a spacing; a wrong one that still overlaps leaves more);
- **features** (``init="features"`` only): the share of the feature start's inlier matches that
  the final pose keeps within 1.5 voxels. A pose that slid or flipped away from what the local
  descriptors agreed on keeps few of them. Few kept counts only with a residual above a
  spacing as well: a symmetric shape's best RANSAC hypothesis may be its twin, and the ICP's
  choice, the true pose, then keeps few of the twin's inliers while fitting the noise.

:func:`support_reason` turns them into one of the rigid reasons (or None) by
:func:`reglib._verdict.rigid_reason`, where the thresholds are: the answer is then returned with
``converged=False`` and that reason. The fourth rigid reason, ``INCONSISTENT``, is not a support
figure: with ``ICPOptions.verify`` the ICP also registers the target onto the model and says when
the two answers disagree (:func:`reglib.registration._icp.disagreement`).

Points are (N, D) rows (x, y[, z]) in the caller's units; trusted input.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._verdict import Reason, rigid_reason
from ._steps import sample_rows

__all__ = ["Support", "chamfer_spacings", "fit_figures", "fit_reach", "measure_support", "median_spacing",
           "overlap_score", "point_scores", "support_reason"]

_NEAR = 3.0  # a model point within this many target spacings of the target overlaps it
_SAMPLE = 2000  # model points the support is measured on, at most


@dataclass(frozen=True, slots=True)
class Support:
    """The support of a rigid answer (module docstring).

    Attributes
    ----------
    overlap : float
        Share of the model within 3 target spacings of the target, in [0, 1].
    residual : float
        Median distance of those model points to the target, in target spacings (inf: none).
    features : float or None
        Share of the feature start's inliers kept; None without a feature start.
    """

    overlap: float
    residual: float
    features: float | None


def measure_support(model: np.ndarray, tree: cKDTree, spacing: float, matrix: np.ndarray,
                    rng: np.random.Generator, *, features: float | None = None) -> Support:
    """The :class:`Support` of ``matrix`` ([R | t], (D, D + 1)) taking ``model`` onto the target of ``tree``.

    ``spacing`` is the target's median nearest-neighbour distance (the overlap uses 3 of them;
    a zero spacing counts exact hits only); ``features`` the kept share of feature inliers.
    """
    dim = model.shape[1]
    x = model[sample_rows(len(model), _SAMPLE, rng)]
    x = x @ matrix[:, :dim].T + matrix[:, dim]
    near = _NEAR * spacing
    d = np.asarray(tree.query(x, distance_upper_bound=near if near > 0 else np.inf)[0])
    hit = np.isfinite(d) & (d <= near)
    overlap = float(hit.mean()) if len(hit) else 0.0
    residual = float(np.median(d[hit]) / spacing) if hit.any() and spacing > 0 else (0.0 if hit.any() else np.inf)
    return Support(overlap=overlap, residual=residual, features=features)


def support_reason(support: Support) -> Reason | None:
    """The rigid reason that ``support`` meets (:func:`reglib._verdict.rigid_reason`), or None when it is enough."""
    return rigid_reason(support.overlap, support.residual, support.features)

def chamfer_spacings(moved: np.ndarray, y: np.ndarray, tree: cKDTree) -> float:
    """The symmetric mean nearest-point distance between ``moved`` and the target ``y`` (``tree`` is its
    k-d tree), in target spacings (its median nearest-neighbour distance); 0 for coinciding sets."""
    forward = float(np.mean(tree.query(moved)[0]))
    backward = float(np.mean(cKDTree(moved).query(y)[0]))
    spacing = _median_spacing(tree, len(y))
    chamfer = (forward + backward) / 2.0
    return chamfer / spacing if spacing > 0 else (0.0 if chamfer == 0 else float("inf"))


_FIT_REACH = 3.0  # a registered model point with a target point within this many target spacings is "fitted"
_SPACING_SAMPLE = 2000  # target points the spacing is measured on, at most (evenly spaced)


def fit_reach(tree: cKDTree) -> float:
    """The reach of :func:`fit_figures`: :data:`_FIT_REACH` target spacings (0 with fewer than two target points)."""
    return _FIT_REACH * _median_spacing(tree, _SPACING_SAMPLE) if tree.n >= 2 else 0.0


def fit_figures(moved: np.ndarray, tree: cKDTree, *, dist: np.ndarray | None = None,
                reach: float | None = None) -> tuple[float, float]:
    """Open3D's two figures of a registration, with a reach the target sets: ``fitness``, the share of the
    registered model points ``moved`` with a target point (of ``tree``) within :data:`_FIT_REACH` target
    spacings (its median nearest-neighbour distance, on an even sample), and ``inlier_rmse``, the RMS of
    those points' distances (0 with none). Comparable across methods: no method's own scale enters.
    ``dist``: the nearest-target distances of ``moved`` from a query the caller bounded at :func:`fit_reach`
    (``reach``, when known) or beyond, inf past the bound; then the tree is not queried again."""
    if not len(moved) or tree.n < 2:
        return 0.0, 0.0
    reach = fit_reach(tree) if reach is None else reach
    if dist is None:
        dist = np.asarray(tree.query(moved, distance_upper_bound=np.nextafter(reach, np.inf))[0])
    near = dist[dist <= reach]
    return float(len(near) / len(moved)), float(np.sqrt(np.mean(near**2))) if len(near) else 0.0


def overlap_score(tree: cKDTree, points: np.ndarray, tau: float) -> float:
    """The coarse stage's score of ``points`` against the tree's set: the mean of max(0, 1 - (d / tau)^2) over
    their nearest distances d (a largest-common-point-set measure; nothing beyond ``tau`` counts)."""
    return float(point_scores(tree, points, tau).mean())


def point_scores(tree: cKDTree, points: np.ndarray, tau: float) -> np.ndarray:
    """Each point's term of :func:`overlap_score`: max(0, 1 - (d / tau)^2), d its nearest distance to the set."""
    d = np.asarray(tree.query(points, distance_upper_bound=tau)[0])
    return np.maximum(0.0, 1.0 - (d / tau) ** 2)


def median_spacing(tree: cKDTree) -> float:
    """The target's median nearest-neighbour distance, on an even sample (:func:`_median_spacing`)."""
    return _median_spacing(tree, _SPACING_SAMPLE)


def _median_spacing(tree: cKDTree, sample: int) -> float:
    """Median distance from a point of the tree's set to its nearest other point, on at most ``sample`` of
    them, evenly spaced (deterministic, unlike :func:`~reglib.registration._steps.point_spacing`'s random
    draw, and with coinciding points counted: a verdict must not depend on a seed)."""
    points = tree.data
    every = np.linspace(0, len(points) - 1, min(len(points), sample)).astype(np.intp)
    return float(np.median(np.asarray(tree.query(points[every], k=2)[0])[:, 1]))
