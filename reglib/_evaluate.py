"""Landmark evaluation of a registration: target registration error (TRE) and its summaries.

For a transform ``f`` (a -> b) and landmark pairs ``(p_i, q_i)`` placed by hand on the same
structure in a and in b, the TRE of landmark i is ``|f(p_i) - q_i|``. :func:`evaluate` gives the
TREs, their mean / median / max and RMS, rTRE (the TRE over the diagonal of image b, as in the
ANHIR challenge [1]_, when b's size is given), the symmetric Hausdorff distance between the
registered set ``f(p)`` and the target set ``q``, and the share of a's pixels where ``f`` folds
(when a's size is given). Coordinates are (x, y) pixels, x the column.

References
----------
.. [1] J. Borovec et al., "ANHIR: Automatic Non-Rigid Histological Image Registration
       Challenge", IEEE Trans. Medical Imaging 39(10), 2020. :doi:`10.1109/TMI.2020.2986331`
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.distance import cdist

from ._repr import short_repr
from ._transforms import KernelWarp
from ._validation import as_points
from .dense import as_shape, fold_fraction
from .errors import InputError

__all__ = ["Evaluation", "evaluate"]

_FOLD_SAMPLES = 4_000_000  # a's pixels beyond this: the fold share is measured on a lattice of about this many


@dataclass(frozen=True, eq=False)
class Evaluation:
    """What :func:`evaluate` measured. Distances are pixels of b.

    Attributes
    ----------
    tre : (N,) float64 ndarray
        The target registration error of each landmark, ``|f(p_i) - q_i|``.
    mean, median, max, rms : float
        Of ``tre`` (0.0 for no landmarks).
    hausdorff : float
        The symmetric Hausdorff distance between the registered landmarks ``f(p)`` and the target
        landmarks ``q`` (as sets; 0.0 for no landmarks).
    diagonal : float or None
        The diagonal of image b, ``sqrt(H_b^2 + W_b^2)`` (None without ``shape_b``).
    rtre : (N,) float64 ndarray or None
        ``tre / diagonal`` (None without ``shape_b``).
    rtre_mean, rtre_median, rtre_max : float or None
        Of ``rtre`` (None without ``shape_b``; 0.0 for no landmarks).
    fold_fraction : float or None
        Share of a's pixels where the transform folds (Jacobian determinant <= 0;
        :func:`reglib.dense.fold_fraction`), None without ``shape_a``.
    registered : (N, D) float64 ndarray
        ``f(p)``, the landmarks of a mapped into b.
    """

    tre: np.ndarray
    mean: float
    median: float
    max: float
    rms: float
    hausdorff: float
    diagonal: float | None
    rtre: np.ndarray | None
    rtre_mean: float | None
    rtre_median: float | None
    rtre_max: float | None
    fold_fraction: float | None
    registered: np.ndarray

    @property
    def n_landmarks(self) -> int:
        """Number of landmark pairs N."""
        return int(len(self.tre))

    def __repr__(self) -> str:
        return short_repr(self, ("n_landmarks", "mean", "median", "max", "rms", "hausdorff", "rtre_mean",
                                 "fold_fraction"))

    def to_dict(self) -> dict[str, Any]:
        """The evaluation's JSON form (``reglib evaluate --out``): every attribute, arrays as lists."""
        return {
            "n_landmarks": self.n_landmarks,
            "tre": [float(v) for v in self.tre],
            "mean": self.mean,
            "median": self.median,
            "max": self.max,
            "rms": self.rms,
            "hausdorff": self.hausdorff,
            "diagonal": self.diagonal,
            "rtre": None if self.rtre is None else [float(v) for v in self.rtre],
            "rtre_mean": self.rtre_mean,
            "rtre_median": self.rtre_median,
            "rtre_max": self.rtre_max,
            "fold_fraction": self.fold_fraction,
            "registered": self.registered.tolist(),
        }


def evaluate(transform: KernelWarp | dict[str, Any], landmarks_a: Any, landmarks_b: Any, *,
             shape_a: Any = None, shape_b: Any = None) -> Evaluation:
    """Landmark errors of ``transform`` (a -> b): TRE, rTRE, RMS, Hausdorff distance and folds.

    Parameters
    ----------
    transform : KernelWarp or dict
        Maps a's points (x, y) into b (a transform's JSON form is accepted).
    landmarks_a, landmarks_b : (N, D) array_like
        Landmark ``i`` in a and the same structure in b, (x, y[, z]) pixels; D is the
        transform's dimension.
    shape_a : (int, int), optional
        (H, W) of image a: the fold share of the transform over a's pixels is measured (2-D only).
    shape_b : (int, int), optional
        (H, W) of image b (the target): rTRE is the TRE over b's diagonal.

    Returns
    -------
    Evaluation

    Raises
    ------
    InputError
        Landmarks that are not (N, D) finite numbers of the transform's dimension, landmark sets of
        different lengths, a shape that is not two positive integers, or a ``shape_a`` for a 3-D
        transform.

    Examples
    --------
    >>> import numpy as np
    >>> from reglib._transforms import KernelWarp
    >>> p = np.array([[10.0, 20.0], [30.0, 40.0]])
    >>> ev = evaluate(KernelWarp.identity(2), p, p + [3.0, 4.0], shape_b=(300, 400))
    >>> ev.mean, ev.rtre_median, ev.hausdorff
    (5.0, 0.01, 5.0)
    """
    f = _as_warp(transform)
    dims = (f.dim,)
    pa = as_points(landmarks_a, "landmarks_a", dims=dims)
    pb = as_points(landmarks_b, "landmarks_b", dims=dims)
    if len(pa) != len(pb):
        raise InputError(f"`landmarks_a` and `landmarks_b` must hold the same number of landmarks, "
                         f"got {len(pa)} and {len(pb)}")
    folds = None
    if shape_a is not None:
        if f.dim != 2:
            raise InputError("`shape_a` (the fold share over image a) needs a 2-D transform")
        folds = float(fold_fraction(f, as_shape(shape_a, "shape_a"), max_samples=_FOLD_SAMPLES))
    diagonal = None
    if shape_b is not None:
        hb, wb = as_shape(shape_b, "shape_b")
        diagonal = math.hypot(hb, wb)
    registered = f(pa) if len(pa) else np.zeros((0, f.dim))
    tre = np.linalg.norm(registered - pb, axis=1) if len(pa) else np.zeros(0)
    rtre = None if diagonal is None else tre / diagonal
    return Evaluation(tre=tre, mean=_stat(tre, np.mean), median=_stat(tre, np.median), max=_stat(tre, np.max),
                      rms=float(np.sqrt(np.mean(tre**2))) if len(tre) else 0.0,
                      hausdorff=_hausdorff(registered, pb), diagonal=diagonal, rtre=rtre,
                      rtre_mean=None if rtre is None else _stat(rtre, np.mean),
                      rtre_median=None if rtre is None else _stat(rtre, np.median),
                      rtre_max=None if rtre is None else _stat(rtre, np.max),
                      fold_fraction=folds, registered=registered)


def _as_warp(transform: Any) -> KernelWarp:
    """A :class:`KernelWarp` (2-D or 3-D), or its JSON dict form."""
    if isinstance(transform, dict):
        return KernelWarp.from_dict(transform)
    if not isinstance(transform, KernelWarp):
        raise InputError(f"`transform` must be a KernelWarp or its dict form, got {type(transform).__name__}")
    return transform


def _stat(values: np.ndarray, how: Any) -> float:
    return float(how(values)) if len(values) else 0.0


def _hausdorff(x: np.ndarray, y: np.ndarray) -> float:
    """The symmetric Hausdorff distance between point sets ``x`` and ``y`` (0.0 when either is empty)."""
    if not len(x) or not len(y):
        return 0.0
    d = cdist(x, y)
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))
