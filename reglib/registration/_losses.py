"""Robust functions of rigid ICP: the IRLS weights of Babin et al. [1] and the residual scale.

In terms of the scaled residual e = |r| / sigma and the tuning constant k (its default per loss
is in ``DEFAULT_TUNING``), as in Table I of [1]:

=================  ==========================================  ===========
loss               weight w(e)                                 default k
=================  ==========================================  ===========
``l2``             1                                           --
``l1``             1 / e                                       --
``huber``          1 if e <= k else k / e                      1.345
``cauchy``         1 / (1 + (e / k)^2)                         2.3849
``geman_mcclure``  1 / (1 + (e / k)^2)^2                       2.0
``welsch``         exp(-(e / k)^2)                             2.9846
``tukey``          (1 - (e / k)^2)^2 if e < k else 0           4.6851
``student``        (k + 1) / (k + e^2)   (k degrees of freedom)  3.0
``switchable``     1 if e <= k else 4 / (1 + (e / k)^2)^2      2.0
``trimmed``        1 for the ``trim_ratio`` smallest |r|, else 0  --
``max_distance``   1 if e <= k else 0 (or |r| <= max_distance)  3.0
=================  ==========================================  ===========

(Babin et al. write Geman-McClure and switchable constraint with k on the squared residual; ours
is theirs with k_theirs = k^2. ``trim_ratio=None`` is their "VarTrimmed": the kept fraction xi
minimizes the trimmed RMS over xi^3, as in Chetverikov et al.'s fractional RMSD [2].)

The scale is a median absolute deviation about zero, sigma = median |r| / m, with m the median
of |r| for standard Gaussian noise (0.6745 for a signed scalar residual, 1.1774 for a 2-D and
1.5382 for a 3-D distance), so that sigma estimates the per-coordinate noise when most pairs are
right; :func:`mad_scale` also takes another quantile than the median.

Every function here trusts its input (validated by the options and the public entry points).

References
----------
.. [1] P. Babin, P. Giguere, F. Pomerleau, "Analysis of Robust Functions for Registration
       Algorithms", ICRA 2019. :doi:`10.1109/ICRA.2019.8793791`
.. [2] D. Chetverikov, D. Stepanov, P. Krsek, "Robust Euclidean alignment of 3D point sets: the
       trimmed iterative closest point algorithm", Image and Vision Computing 23(3), 2005.
       :doi:`10.1016/j.imavis.2004.05.007`
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
from scipy import stats

__all__ = ["DEFAULT_TUNING", "LOSSES", "Loss", "mad_scale", "robust_weights", "trim_fraction"]

Loss = Literal["l2", "l1", "huber", "cauchy", "geman_mcclure", "welsch", "tukey", "student",
               "switchable", "trimmed", "max_distance"]
LOSSES: tuple[Loss, ...] = ("l2", "l1", "huber", "cauchy", "geman_mcclure", "welsch", "tukey", "student",
                            "switchable", "trimmed", "max_distance")

DEFAULT_TUNING: dict[str, float] = {"l2": 1.0, "l1": 1.0, "huber": 1.345, "cauchy": 2.3849,
                                    "geman_mcclure": 2.0, "welsch": 2.9846, "tukey": 4.6851,
                                    "student": 3.0, "switchable": 2.0, "trimmed": 1.0,
                                    "max_distance": 3.0}

# median of |r| for standard Gaussian noise: signed scalar residual, 2-D and 3-D distances
_MEDIAN_ABS = {1: 0.6744897501960817, 2: 1.1774100225154747, 3: 1.5381722544550522}

# w(e, k) of the losses that are functions of the scaled residual e alone (module table)
_WEIGHT_OF_SCALED: dict[str, Callable[[np.ndarray, float], np.ndarray]] = {
    "l1": lambda e, k: 1.0 / np.maximum(e, 1e-6),
    "huber": lambda e, k: np.where(e <= k, 1.0, k / np.maximum(e, 1e-300)),
    "cauchy": lambda e, k: 1.0 / (1.0 + (e / k) ** 2),
    "geman_mcclure": lambda e, k: 1.0 / (1.0 + (e / k) ** 2) ** 2,
    "welsch": lambda e, k: np.exp(-((e / k) ** 2)),
    "tukey": lambda e, k: np.where((e / k) ** 2 < 1.0, (1.0 - (e / k) ** 2) ** 2, 0.0),
    "student": lambda e, k: (k + 1.0) / (k + e * e),
    "switchable": lambda e, k: np.where((e / k) ** 2 <= 1.0, 1.0, 4.0 / (1.0 + (e / k) ** 2) ** 2),
    "max_distance": lambda e, k: (e <= k).astype(np.float64),
}


def trim_fraction(r_abs: np.ndarray) -> float:
    """Chetverikov's xi in [0.2, 1] minimizing sqrt(mean of the xi smallest r^2) / xi^3 [2].

    Parameters
    ----------
    r_abs : (K,) ndarray
        Residual magnitudes, K >= 1 (trusted input).

    Returns
    -------
    float
        The kept fraction xi (VarTrimmed's), on a grid of 33 values.
    """
    r2 = np.sort(r_abs * r_abs)
    n = len(r2)
    xi = np.linspace(0.2, 1.0, 33)
    counts = np.maximum((xi * n).astype(int), 1)
    rms = np.sqrt(np.cumsum(r2)[counts - 1] / counts)
    return float(xi[int(np.argmin(rms / xi**3))])


def robust_weights(r_abs: np.ndarray, sigma: float, loss: Loss | str, k: float, *,
                   trim_ratio: float | None = None, max_distance: float | None = None) -> np.ndarray:
    """IRLS weights w(|r| / sigma) of ``loss`` with tuning constant ``k`` (module table).

    Trusted input: ``loss`` is one of ``LOSSES``; does not validate.

    Parameters
    ----------
    r_abs : (K,) ndarray
        Residual magnitudes |r_i| (caller's units).
    sigma : float
        Residual scale (> 0).
    loss : str
        One of ``LOSSES``.
    k : float
        Tuning constant, in units of ``sigma``.
    trim_ratio : float, optional
        ``"trimmed"``: the fraction kept; None chooses it (:func:`trim_fraction`).
    max_distance : float, optional
        ``"max_distance"``: the threshold on |r| (caller's units) instead of k sigma.

    Returns
    -------
    (K,) ndarray
        Weights in [0, inf) (l1) or [0, 1] (every other loss).

    Examples
    --------
    >>> import numpy as np
    >>> robust_weights(np.array([0.0, 1.0, 3.0]), 1.0, "cauchy", 1.0).tolist()
    [1.0, 0.5, 0.1]
    """
    if loss == "l2":
        return np.ones_like(r_abs)
    if loss == "trimmed":
        if len(r_abs) == 0:
            return np.ones_like(r_abs)
        ratio = trim_fraction(r_abs) if trim_ratio is None else trim_ratio
        keep = max(int(np.ceil(ratio * len(r_abs))), 1)
        thr = np.partition(r_abs, keep - 1)[keep - 1]
        return (r_abs <= thr).astype(np.float64)
    if loss == "max_distance" and max_distance is not None:
        return (r_abs <= max_distance).astype(np.float64)
    return _WEIGHT_OF_SCALED[loss](r_abs / sigma, k)


def mad_scale(r_abs: np.ndarray, dof: int, quantile: float = 0.5) -> float:
    """sigma = the ``quantile`` of |r| over the same quantile for unit Gaussian noise.

    Parameters
    ----------
    r_abs : (K,) ndarray
        Residual magnitudes.
    dof : {1, 2, 3}
        Degrees of freedom of a residual: 1 for a signed scalar (point-to-plane), D for a
        D-dimensional distance (point-to-point).
    quantile : float
        0.5 is the MAD (module docstring).

    Returns
    -------
    float
        The scale; 0 for no residuals.

    Examples
    --------
    >>> import numpy as np
    >>> round(mad_scale(np.abs(np.random.default_rng(0).normal(size=100_000)), 1), 2)
    1.0
    """
    if len(r_abs) == 0:
        return 0.0
    if quantile == 0.5:
        return float(np.median(r_abs)) / _MEDIAN_ABS[dof]
    return float(np.quantile(r_abs, quantile)) / float(stats.chi.ppf(quantile, dof))
