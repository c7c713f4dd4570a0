"""Whether a probabilistic method's rigid (or similarity) answer is where a robust fit of the data puts it.

A Gaussian mixture with no outlier component (CPD's default ``outlier_weight=0``) gives every target point
a share of the model: target points far from the model (outliers) pull the answer off, and shrink or grow
its scale, while the EM still settles, so the method's own tolerance says nothing. :func:`polish_shift`
runs a robust ICP of the same kind of map (rotation and translation, and a scale when the method fitted
one) from the answer: nearest target points, the closest share of them that VarTrimmed keeps (the part of
the model that overlaps the target), Cauchy weights at their MAD scale (at least a target spacing: noise
below the data's resolution is not a misfit), weighted Umeyama, until the points
move less than a thousandth of a spacing. Far points get no weight, so from a right answer it moves the
model by a fraction of a spacing, and from one pulled off by about its error.
:func:`reglib._verdict.polish_reason` turns the mean displacement, in target spacings, into the verdict.

Points are (N, D) rows in the caller's units; trusted input.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._geometry import umeyama_similarity
from ._losses import DEFAULT_TUNING, mad_scale, robust_weights, trim_fraction
from ._support import median_spacing

__all__ = ["polish_shift"]

_SAMPLE = 5000   # registered model points the fit runs on, at most (evenly spaced)
_ITER = 50       # robust ICP iterations at most
_SETTLED = 1e-3  # ... until the points move less than this share of a target spacing


def polish_shift(moved: np.ndarray, tree: cKDTree, *, scale: bool) -> float:
    """Mean displacement, in target spacings, of the registered model ``moved`` by a robust ICP from it.

    Parameters
    ----------
    moved : (N, D) ndarray
        The model points under the answer.
    tree : scipy.spatial.cKDTree
        Built on the target points.
    scale : bool
        The answer has a scale of its own (the fit then estimates one too).

    Returns
    -------
    float
        0 when the target has no spacing or a set has fewer than D + 1 points.
    """
    dim = moved.shape[1]
    spacing = median_spacing(tree)
    if spacing <= 0 or len(moved) <= dim or tree.n <= dim:
        return 0.0
    x = moved[np.linspace(0, len(moved) - 1, min(len(moved), _SAMPLE)).astype(np.intp)]
    target = np.asarray(tree.data)
    cur = x
    k = DEFAULT_TUNING["cauchy"]
    for _ in range(_ITER):
        d, j = tree.query(cur)
        d = np.asarray(d)
        # the share of the model that overlaps the target (VarTrimmed's xi): the rest, with no counterpart, gets
        # no weight, and the scale is theirs
        near = d <= np.quantile(d, trim_fraction(d))
        sigma = max(mad_scale(d[near], dim), spacing)
        w = np.where(near, robust_weights(d, sigma, "cauchy", k), 0.0)
        if not w.sum() > 0:
            break
        m = umeyama_similarity(x, target[np.asarray(j)], w, scale=scale)
        new = x @ m[:, :dim].T + m[:, dim]
        step = float(np.linalg.norm(new - cur, axis=1).mean())
        cur = new
        if step < _SETTLED * spacing:
            break
    return float(np.linalg.norm(cur - x, axis=1).mean() / spacing)
