"""Whether the data pin a rigid 3-D answer down: no pose a small move away is as well supported.

At low overlap a robust ICP can settle where the overlapping part of the surface lets it slide (a wall
and a floor, a shallow cylinder): its minimum moves along a direction the data barely constrain, and
the answer is off by a few percent of the object while its overlap and residual look like a success's.
The reverse registration (``ICPOptions.verify``) does not see it when the backward run slides the same
way. What does: the answer should be the best supported pose of its neighbourhood. :func:`neighbour_support`
moves the answer along each principal direction of the point-to-plane normal equations restricted to the
overlap (the six eigenvectors of sum a a^T with a = [(p - c) x n / L, n] over the overlapping model points
p, their target normals n, centroid c and RMS radius L; a direction the overlap does not constrain has a
small eigenvalue) by ``_STEP`` of the target's extent, both ways, and returns the best support of those
twelve poses over the answer's. The support is the coarse stage's score: the mean of
max(0, 1 - (d / tau)^2) over the model points' distances d to the target, tau two target spacings. At
1 or above, a pose that far away fits the data at least as well: the data do not pin the answer within
that distance, and :func:`reglib._verdict.pinned_reason` says so.

At low overlap the robust ICP's own minimum can be such a slide: its weights, scaled by the residuals of the
whole overlap, still count pairs a few spacings apart, and a pose that slid keeps more of those. The score at
one target spacing does not: there the true pose beats the slide. :func:`tight_polish` therefore takes the
answer through a point-to-plane polish whose pairs are those within a reach that shrinks from 3 to 1 target
spacings (every pair within it weighted alike, none beyond: the ascent of that score), and keeps the polished
pose only when its per-point scores at one spacing beat the answer's by more than 3 standard errors of the
paired difference (:func:`reglib.registration._coarse.overtakes`, the coarse stage's lead test), so a
right answer that the polish only nudges keeps its pose.

Deterministic (an even sample of the model, no random draw), so it moves no other answer. 3-D only.
Points are (N, 3) rows in the caller's units; trusted input.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ._coarse import overtakes
from ._normals import LazyNormals
from ._steps import plane_step, rotation_from_vector
from ._support import median_spacing, overlap_score, point_scores

__all__ = ["neighbour_support", "surface_normals", "tight_polish"]

# a neighbour pose moves the overlap by this share of the target's extent (its bounding-box diagonal):
# chosen on the global case's tuning seeds, where it separated the slides from the successes
_STEP = 0.01
_SAMPLE = 2000      # model points the support is measured on, at most (evenly spaced)
_TAU = 2.0          # the score's reach, in target spacings (as the coarse stage's)
_NEAR = 3.0         # a model point within this many target spacings overlaps the target
_K_NORMALS = 10     # neighbours of the target normals' PCA
_REACHES = (3.0, 2.0, 1.5, 1.0)  # the tight polish's pairs: within these many target spacings, one stage each
_POLISH_ITER = 15   # iterations of a stage at most
_POLISH_SAMPLE = 4000  # model points the polish runs and is judged on, at most (evenly spaced)
_STILL = 0.01       # a stage ends when an iteration moves the sample by under this many spacings (RMS)


def surface_normals(tree: cKDTree) -> LazyNormals:
    """The target's normals as both checks read them (PCA of ``_K_NORMALS`` neighbours, computed on first use):
    one cache for an answer's polish and its neighbours' check."""
    return LazyNormals(np.asarray(tree.data), tree, _K_NORMALS)


def neighbour_support(model: np.ndarray, tree: cKDTree, matrix: np.ndarray,
                      normals: LazyNormals | None = None) -> float:
    """The best support of the twelve neighbour poses of ``matrix`` over its own (module docstring).

    Parameters
    ----------
    model : (N, 3) ndarray
        The model points the answer was fitted on.
    tree : scipy.spatial.cKDTree
        Built on the target points.
    matrix : (3, 4) ndarray
        The answer, [R | t] taking model points onto the target.
    normals : LazyNormals, optional
        :func:`surface_normals` of ``tree``, when the caller holds it (None: made here).

    Returns
    -------
    float
        max over the neighbours of their support / the answer's: 1 or more when a pose ``_STEP`` of the
        target's extent away is as well supported; 0 when nothing overlaps or the target has no spacing.
    """
    target = np.asarray(tree.data)
    spacing = median_spacing(tree)
    extent = float(np.linalg.norm(target.max(0) - target.min(0)))
    if spacing <= 0 or extent <= 0 or len(model) < 6:
        return 0.0
    x = model[np.linspace(0, len(model) - 1, min(len(model), _SAMPLE)).astype(np.intp)]
    moved = x @ matrix[:, :3].T + matrix[:, 3]
    dist, idx = tree.query(moved, distance_upper_bound=_NEAR * spacing)
    hit = np.isfinite(dist)
    if hit.sum() < 6:
        return 0.0
    p = moved[hit]
    n = (surface_normals(tree) if normals is None else normals)[np.asarray(idx)[hit]]
    c = p.mean(0)
    radius = float(np.sqrt(((p - c) ** 2).sum(1).mean()))
    rows = np.c_[np.cross(p - c, n) / max(radius, 1e-300), n]
    _, vecs = np.linalg.eigh(rows.T @ rows)
    tau = _TAU * spacing

    def support(m: np.ndarray) -> float:
        return overlap_score(tree, x @ m[:, :3].T + m[:, 3], tau)

    own = support(matrix)
    if own <= 0:
        return 0.0
    step = _STEP * extent
    best = 0.0
    for v in vecs.T:
        for sign in (1.0, -1.0):
            # turn about the overlap's centroid by the rotational part, then shift by the translational part
            turn = rotation_from_vector(sign * v[:3] * step / max(radius, 1e-300))
            m = np.c_[turn @ matrix[:, :3], turn @ (matrix[:, 3] - c) + c + sign * v[3:] * step]
            best = max(best, support(m) / own)
    return best


def tight_polish(model: np.ndarray, tree: cKDTree, matrix: np.ndarray,
                 normals: LazyNormals | None = None) -> tuple[np.ndarray, bool]:
    """The answer ``matrix`` polished by the score at one target spacing, or itself (module docstring).

    Parameters
    ----------
    model, tree, matrix, normals
        As for :func:`neighbour_support`: the model points the answer was fitted on, the tree on the target
        points, the answer [R | t], and the target's normals when the caller holds them.

    Returns
    -------
    (3, 4) ndarray
        The polished pose when its per-point scores at one spacing beat the answer's by more than 3
        standard errors; otherwise ``matrix`` itself.
    bool
        Whether that polished pose was kept and its last stage settled (an iteration moved the sample by
        under ``_STILL`` spacings): the answer given is then a settled one, whatever the ICP before it did.
    """
    target = np.asarray(tree.data)
    spacing = median_spacing(tree)
    if spacing <= 0 or len(model) < 6:
        return matrix, False
    x = model[np.linspace(0, len(model) - 1, min(len(model), _POLISH_SAMPLE)).astype(np.intp)]
    normals = surface_normals(tree) if normals is None else normals
    m = np.array(matrix, dtype=np.float64)
    still = False
    for reach in _REACHES:
        still = False
        for _ in range(_POLISH_ITER):
            moved = x @ m[:, :3].T + m[:, 3]
            dist, idx = tree.query(moved, distance_upper_bound=reach * spacing)
            hit = np.isfinite(dist)
            if hit.sum() < 6:
                return matrix, False
            j = np.asarray(idx)[hit]
            rot, c, shift = plane_step(moved[hit], target[j], normals[j], np.ones(int(hit.sum())))
            m = np.c_[rot @ m[:, :3], rot @ (m[:, 3] - c) + c + shift]
            step = (moved - c) @ rot.T + c + shift - moved
            if float(np.sqrt((step**2).sum(1).mean())) < _STILL * spacing:
                still = True
                break
    new = point_scores(tree, x @ m[:, :3].T + m[:, 3], spacing)
    old = point_scores(tree, x @ matrix[:, :3].T + matrix[:, 3], spacing)
    return (m, still) if overtakes(new, old) else (matrix, False)
