"""``filter_matches``: keep the putative matches that agree with one smooth transformation."""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Literal

import numpy as np

from .._transforms import KernelWarp
from .._validation import as_choice, as_options, as_point_pair, as_rng, seed_of
from .._verdict import FOLDING, TOO_FEW_MATCHES
from ..errors import InputError
from ._core import Normalization, single_thread_blas
from ._l2e import Fit, l2e_fit, with_layer
from ._options import L2EOptions, VFCOptions
from ._result import FilterResult
from ._verdict import failure_reason, folded
from ._vfc import vfc_fit

__all__ = ["FilterResult", "filter_matches", "fit_matches", "METHODS"]

METHODS: tuple[Literal["l2e", "vfc"], ...] = ("l2e", "vfc")
_OPTIONS: dict[str, type[L2EOptions] | type[VFCOptions]] = {"l2e": L2EOptions, "vfc": VFCOptions}
# each fit takes the options class of its own method (``_OPTIONS``, same key)
_FITS: dict[str, Callable[[np.ndarray, np.ndarray, Any, np.random.Generator], Fit]] = {"l2e": l2e_fit, "vfc": vfc_fit}


def filter_matches(src: Any, dst: Any, *, method: Literal["l2e", "vfc"] = "l2e",
                   options: L2EOptions | VFCOptions | dict[str, Any] | None = None,
                   rng: int | np.random.Generator | None = None) -> FilterResult:
    """Separate true from false putative matches by robustly fitting one smooth transformation.

    Parameters
    ----------
    src, dst : (N, D) array_like
        Putative matches, D in {2, 3}: row i of ``src`` (x, y[, z]) is matched to row i of ``dst``.
        For images, x is the column and y the row, pixel centres at integers.
    method : {"l2e", "vfc"}
        "l2e": the L2E-RKHS estimator (Ma et al. 2013/2015), robust by bounded influence.
        "vfc": Vector Field Consensus (Ma et al. 2014), its EM sibling with a uniform outlier term.
    options : L2EOptions, VFCOptions or dict, optional
        Options of ``method`` (a dict is checked field by field; a misspelled field is an error).
    rng : int or numpy.random.Generator, optional
        Seed of the random choices: VFC's first centre, and L2E's working subset when N exceeds
        ``options.max_work_points``. Below that, L2E makes every choice from the data alone
        (a deterministic start, fixed internal subsets), so its answer does not depend on ``rng``.

    Returns
    -------
    FilterResult
        Fewer than ``options.min_matches`` matches (zero included) give all-False inliers, zero
        scores, the identity transform, ``converged=False`` and the reason ``too_few_matches``.
        An estimate that does not explain the scene (too few inliers, one small cluster, a
        transform that folds; see :class:`FilterResult`) keeps its inliers and transform but has
        ``converged=False`` and the ``reason``.

    Raises
    ------
    InputError
        When ``src`` or ``dst`` is not (N, 2) or (N, 3), their shapes differ, they hold NaN or inf,
        or ``method`` / ``options`` are not recognized.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(0, 500, (200, 2))
    >>> dst = src + [20.0, -5.0] + 5 * np.sin(src[:, ::-1] / 100) + rng.normal(0, 0.5, (200, 2))
    >>> dst[:60] = rng.uniform(0, 500, (60, 2))          # 30 % wrong matches
    >>> res = filter_matches(src, dst, rng=0)
    >>> int(res.inliers[60:].sum()), int(res.inliers[:60].sum())
    (140, 0)
    """
    method = as_choice(method, "method", METHODS)
    opts = as_options(options, _OPTIONS[method])
    src_a, dst_a = as_point_pair(src, dst)
    if src_a.shape[1] == 3 and opts.linear == "homography":
        raise InputError("`options.linear` 'homography' needs 2-D points; `src` is 3-D "
                         "(use 'affine', 'similarity', 'rigid' or 'none')")
    return fit_matches(src_a, dst_a, method=method, options=opts, rng=as_rng(rng), seed=seed_of(rng))


def fit_matches(src: np.ndarray, dst: np.ndarray, *, method: Literal["l2e", "vfc"],
                options: L2EOptions | VFCOptions, rng: np.random.Generator, seed: int | None = None) -> FilterResult:
    """:func:`filter_matches` on trusted input, for the library's own loops; it validates nothing.

    Parameters
    ----------
    src, dst : (N, D) float64 ndarray
        Finite putative matches, D in {2, 3} (a 2-D ``linear="homography"`` only).
    method : {"l2e", "vfc"}
    options : L2EOptions or VFCOptions
        An instance of ``method``'s own options class.
    rng : numpy.random.Generator
    seed : int or None
        Recorded in the result (``FilterResult.seed``).

    Returns
    -------
    FilterResult
        As :func:`filter_matches` returns it.
    """
    opts = options
    src_a, dst_a = src, dst
    generator = rng
    n, d = src_a.shape
    if n < max(opts.min_matches, 1):
        return _too_few(n, d, method, seed)
    # a rigid linear part needs one scale for both sets (each its own would make it a similarity)
    norm = Normalization.common(src_a, dst_a) if opts.linear == "rigid" else Normalization.of(src_a, dst_a)
    u, y = norm.apply(src_a, dst_a)
    with single_thread_blas():
        fit: Fit = _FITS[method](u, y, opts, generator)
        transform = fit.model.to_warp(norm)
        reason = failure_reason(u, y, fit.inliers, fit.sigma, fit.model, opts.min_matches, fit.volume)
        if reason == FOLDING:
            # A true match cannot lie where the map folds (it is not one-to-one there): the
            # agreement is with a field bent to follow false matches. Drop those, judge again.
            fold = folded(u, fit.inliers, fit.model)
            scores = np.where(fold, 0.0, fit.scores)
            fit = dataclasses.replace(fit, inliers=fit.inliers & ~fold, scores=scores)
            reason = failure_reason(u, y, fit.inliers, fit.sigma, fit.model, opts.min_matches, fit.volume)
        if isinstance(opts, L2EOptions) and opts.max_layers > 1:
            fit = with_layer(fit, u, y, norm.src_scale / norm.dst_scale, opts, generator)
    return FilterResult(inliers=fit.inliers, scores=np.clip(fit.scores, 0.0, 1.0), transform=transform,
                        sigma=fit.sigma * norm.dst_scale, n_iter=fit.n_iter,
                        converged=reason is None, reason=reason, method=method, seed=seed,
                        stopped="tolerance" if fit.converged else "iteration_cap")


def _too_few(n: int, d: int, method: str, seed: int | None) -> FilterResult:
    return FilterResult(inliers=np.zeros(n, dtype=bool), scores=np.zeros(n), transform=KernelWarp.identity(d),
                        sigma=0.0, n_iter=0, converged=False, reason=TOO_FEW_MATCHES, method=method, seed=seed)
