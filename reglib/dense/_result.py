"""What the dense stage hands on: its result, and the records its rounds hand to its guard.

:class:`DenseResult` is what :func:`~reglib.dense.refine_dense` and :func:`~reglib.dense._guarding.guard`
return, its ``outcome`` one of :data:`DENSE_OUTCOMES`; :class:`WorkingFrames` are the two images at
the working resolution that the pyramid levels and the guard share; :class:`DenseFit` (a fit and the
matches it was fitted to) and :class:`Evidence` (the working level's last search) are what the
coarse-to-fine rounds give the guard to weigh.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._repr import short_repr
from .._transforms import KernelWarp
from ._correlation import GridSearch

__all__ = ["DENSE_OUTCOMES", "DenseFit", "DenseResult", "Evidence", "WorkingFrames"]

# what became of the dense stage (the match JSON's ``confidence.dense``): its result was kept; f0 was kept
# because the images support it at clearly more places; f0 was kept because the check supports neither and
# the images' similarity does not clearly favour the dense result; no pyramid level found enough dense
# matches; the stage did not run (set by match_images)
DENSE_OUTCOMES = ("kept", "sparse_better", "no_support", "no_matches", "not_run")


@dataclass(frozen=True, eq=False)
class DenseResult:
    """What :func:`~reglib.dense.refine_dense` found.

    Attributes
    ----------
    transform : KernelWarp
        The final estimate, a -> b, original pixels (the first estimate ``f0`` itself when the
        guard kept it or no level found enough dense matches).
    converged : bool
        Whether the dense fit's estimator converged (False when there was no fit).
    n_dense : int
        Dense matches it was fitted to (0 when the guard kept the first estimate, or no fit).
    confidence : (H_a, W_a) float32 ndarray
        The support of ``transform`` as :func:`~reglib.dense.confidence_map` measures it, in
        [0, 1]; when the guard kept ``f0``, from its check of ``f0`` (every other grid point).
    rounds : int
        Rounds of guided matching run, over all pyramid levels.
    kept_first : bool
        True when the guard kept the first estimate ``f0`` (the dense one was supported less, or
        hardly at all: :func:`~reglib.dense._guarding.keep_first`).
    fitted : bool
        False when no pyramid level found enough dense matches for a fit: ``transform`` is then
        ``f0``, ``n_dense`` 0, ``converged`` False and ``confidence`` :func:`~reglib.dense.confidence_map`'s of ``f0``.
    outcome : str
        One of :data:`DENSE_OUTCOMES`: "kept" (the dense estimate, or its re-fit, is the answer),
        "sparse_better" (``f0`` kept: supported at clearly more places), "no_support" (``f0`` kept:
        the check supports neither and the similarity evidence does not favour the dense estimate),
        "no_matches" (``fitted`` False).
    """

    transform: KernelWarp
    converged: bool
    n_dense: int
    confidence: np.ndarray
    rounds: int
    kept_first: bool
    fitted: bool = True
    outcome: str = "kept"

    def __repr__(self) -> str:
        return short_repr(self, ("outcome", "n_dense", "converged", "rounds", "confidence", "transform"))


@dataclass(frozen=True, eq=False)
class WorkingFrames:
    """The two images at the working resolution, shared by the pyramid levels and the guard.

    Attributes
    ----------
    a, b : (h, w, C) float32 ndarray
        The fields correlated, resized by ``scale_a`` / ``scale_b`` (1 when within ``max_side``).
    mask_a, mask_b : (h, w) bool ndarray or None
        The masks, resized likewise.
    scale_a, scale_b : float
        Working size over original size (OpenCV's half-pixel centres: x' = s (x + 0.5) - 0.5).
    shape_a : (int, int)
        (H, W) of the original a (the confidence map's shape).
    min_std : float
        The working level's texture threshold (a whole-field statistic of ``a``).
    std : (h, w) float32 ndarray or None
        The texture map of a grey ``a`` (cheaper once than at each search's grid points; a
        multi-channel field's is measured at the grid points only, a full map costs more there).
    """

    a: np.ndarray
    b: np.ndarray
    mask_a: np.ndarray | None
    mask_b: np.ndarray | None
    scale_a: float
    scale_b: float
    shape_a: tuple[int, int]
    min_std: float
    std: np.ndarray | None


@dataclass(frozen=True, eq=False)
class DenseFit:
    """A dense fit: its transform (a -> b, original pixels), whether it converged, the matches it was fitted to."""

    transform: KernelWarp
    converged: bool
    src: np.ndarray  # (N, 2) float64, original pixels of a
    dst: np.ndarray  # (N, 2) float64, original pixels of b


@dataclass(frozen=True, eq=False)
class Evidence:
    """The working level's last search, and the estimate (working pixels) it searched around."""

    search: GridSearch
    around: KernelWarp
