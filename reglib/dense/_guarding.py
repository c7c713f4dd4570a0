"""The dense stage's guard: the dense estimate weighed against the first one on fresh image evidence.

Both estimates are checked (:mod:`reglib.dense._confidence`). Where the dense estimate is no longer
supported but the first one ``f0`` is, the check matches that support ``f0`` join the dense matches
for one more fit, which pins the final fit to ``f0`` there; if the result is still supported at
clearly fewer places than ``f0``, or at almost none, ``f0`` is kept (:func:`keep_first`). Where the
check supports neither (across stains and sensors fine structure differs, so no patch has a distinct
peak within 1 px), the images' local similarity at the two estimates decides instead
(:func:`~reglib.dense._evidence.evidence_z`): the dense estimate is kept when it makes the images more similar
at clearly more places than ``f0``. :attr:`~reglib.dense.DenseResult.outcome` says which.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._transforms import KernelWarp
from ..robust import fit_matches
from ._confidence import check_support, support_map, supported, upsampled
from ._correlation import GridSearch, on_lattice
from ._evidence import EVIDENCE_Z, evidence_z
from ._guided import _matched
from ._options import MIN_MATCHES, DenseOptions
from ._result import DenseFit, DenseResult, Evidence, WorkingFrames

__all__ = ["guard", "keep_first"]

_LOST_SHARE = 0.03  # the guard re-fits when f0 alone is supported at this share of its check's grid or more


@dataclass(frozen=True, eq=False)
class _Candidate:
    """An estimate the guard weighs: its transform, its check and the grid points supporting it."""

    transform: KernelWarp
    converged: bool
    n_dense: int
    check: GridSearch
    support: np.ndarray
    scaled: KernelWarp  # ``transform`` at the working resolution


def guard(frames: WorkingFrames, f0: KernelWarp, fit: DenseFit, options: DenseOptions, rng: np.random.Generator,
          *, rounds: int = 0, evidence: Evidence | None = None, check_first: GridSearch | None = None) -> DenseResult:
    """The guard: keep ``f0`` where (and if) the dense estimate ``fit`` is supported less than it.

    Both the dense estimate and ``f0`` are checked (:func:`~reglib.dense._confidence.check_support`); check
    matches that support ``f0`` where the dense estimate is unsupported join the dense matches
    for one more fit (kept if, on every other grid point, it is supported at least as often as the
    dense estimate), and ``f0`` is kept if the result is still supported at fewer grid points
    than ``f0``, or at almost none (:func:`keep_first`). In that last case the images' local
    similarity decides instead: the result is kept when it is more similar than ``f0`` at clearly more
    places (:func:`~reglib.dense._evidence.evidence_z` at least ``EVIDENCE_Z``).
    :attr:`~reglib.dense.DenseResult.outcome` says which.

    Parameters
    ----------
    frames : WorkingFrames
        The images at the working resolution (:func:`~reglib.dense._refine.working_frames`).
    f0 : KernelWarp
        The first estimate, a -> b, original pixels.
    fit : DenseFit
        The dense estimate and the matches it was fitted to.
    options : DenseOptions
    rng : numpy.random.Generator
        Passed to the estimator of the re-fit.
    rounds : int
        Recorded in the result (:attr:`~reglib.dense.DenseResult.rounds`).
    evidence : Evidence, optional
        The working level's last search, close to the dense estimate: used as its check when given.
    check_first : GridSearch, optional
        ``f0``'s check on every other grid point (which suffices to compare), when the caller
        has made it.

    Returns
    -------
    DenseResult
    """
    step = options.step
    sa, sb = frames.scale_a, frames.scale_b
    g0, gd = f0.rescaled(sa, sb), fit.transform.rescaled(sa, sb)
    check0 = _check(frames, g0, 2 * step, options) if check_first is None else check_first
    sup0 = supported(check0, g0, g0)
    if evidence is not None:  # the working level's last round searched close to the dense estimate: its evidence
        checkd = evidence.search
        supd = supported(checkd, evidence.around, gd)
    else:
        checkd = _check(frames, gd, step, options)
        supd = supported(checkd, gd, gd)
    dense = _Candidate(fit.transform, fit.converged, len(fit.src), checkd, supd, gd)
    final = _refitted(frames, dense, fit, check0, sup0, g0, options, rng)
    # f0 is kept when it is supported at clearly more grid cells than the final estimate (cells both searched)
    both = _cells_of(check0.grid, final.check.grid, step)
    only0 = int(np.count_nonzero(sup0 & both & ~_cells_of(check0.grid, final.check.grid[final.support], step)))
    only_final = int(np.count_nonzero(final.support & _cells_of(final.check.grid, check0.grid, step)
                                      & ~_cells_of(final.check.grid, check0.grid[sup0], step)))
    n_supported = int(np.count_nonzero(final.support))
    kept_first = keep_first(only0, only_final, n_supported, len(check0.grid), len(final.check.grid))
    outcome = "kept"
    if kept_first and _unsupported(n_supported, len(final.check.grid)):
        # no distinct peak backs the final estimate (across stains and sensors fine structure differs):
        # the images' similarity at the two estimates decides (evidence_z, patches that do not overlap)
        kept_first = evidence_z(frames.a, frames.b, final.scaled, g0, options.step) < EVIDENCE_Z
        outcome = "no_support" if kept_first else "kept"
    elif kept_first:
        outcome = "sparse_better"
    map_step = step
    if kept_first:  # the confidence map then shows the evidence f0 was judged by: its check, every other grid point
        final = _Candidate(f0, fit.converged, 0, check0, sup0, g0)
        map_step = 2 * step
    elif final is not dense:  # the re-fit, checked on the whole grid for its map
        check = _check(frames, final.scaled, step, options)
        final = dataclasses.replace(final, check=check, support=supported(check, final.scaled, final.scaled))
    return DenseResult(transform=final.transform, converged=bool(final.converged), n_dense=int(final.n_dense),
                       confidence=_confidence(frames, final.check, final.support, final.scaled, map_step),
                       rounds=rounds, kept_first=kept_first, outcome=outcome)


def _refitted(frames: WorkingFrames, dense: _Candidate, fit: DenseFit, check0: GridSearch, sup0: np.ndarray,
              g0: KernelWarp, options: DenseOptions, rng: np.random.Generator) -> _Candidate:
    """The dense estimate re-fitted with the check matches that support ``f0`` (scaled ``g0``) where it is not
    supported; ``dense`` itself unless there are enough of those and the re-fit is supported at least as often."""
    step, hp = options.step, options.patch
    sa, sb = frames.scale_a, frames.scale_b
    # grid cells where f0 is supported and the dense estimate is not
    lost = sup0 & ~_cells_of(check0.grid, dense.check.grid[dense.support], step)
    if lost.sum() < max(3, _LOST_SHARE * len(check0.grid)):
        return dense
    p, q, _ = _matched(check0.where(lost), g0, frames.mask_b)
    p = (p + 0.5) / sa - 0.5
    q = (q + 0.5) / sb - 0.5
    src2, dst2 = np.r_[fit.src, p], np.r_[fit.dst, q]
    res = fit_matches(src2, dst2, method=options.method, options=options.estimator_options(len(src2), smooth=True),
                      rng=rng)
    if res.reason is not None or res.n_inliers < MIN_MATCHES:
        return dense
    # the re-fit is checked on f0's lattice (every other grid point) and compared with the
    # dense estimate's support there; which cells only one of them supports (in the guard) only
    # ever involves those points. The whole grid is checked only for a re-fit that is kept
    # to the end (its confidence map).
    g2 = res.transform.rescaled(sa, sb)
    check2 = _check(frames, g2, 2 * step, options)
    sup2 = supported(check2, g2, g2)
    if sup2.sum() < dense.support[on_lattice(dense.check.grid, 2 * step, hp)].sum():
        return dense
    return _Candidate(res.transform, res.converged, len(src2), check2, sup2, g2)


def _check(frames: WorkingFrames, g: KernelWarp, step: int, options: DenseOptions) -> GridSearch:
    """The support check of ``g`` (working pixels) on the grid of ``step``, with the working level's texture."""
    return check_support(frames.a, frames.b, g, step, options.patch, frames.mask_a, frames.min_std, frames.std)


def _confidence(frames: WorkingFrames, check: GridSearch, support: np.ndarray, g: KernelWarp,
                step: int) -> np.ndarray:
    """The confidence map of ``g`` from its check, on a's original pixels."""
    conf = support_map(check, support, g, frames.b.shape[:2], frames.a.shape[:2], step)
    return upsampled(conf, frames.shape_a) if frames.scale_a < 1.0 else conf


def keep_first(only_first: int, only_final: int, n_supported: int, n_check_first: int, n_check: int) -> bool:
    """The guard's decision: keep the sparse estimate f0 rather than the dense stage's final one?

    Yes when f0 is supported at clearly more grid cells than the final estimate (``only_first``
    against ``only_final``: cells where only one of them is, both searched; margin max(3, 3 % of
    f0's check grid of ``n_check_first`` points)), and yes when the final estimate is supported at
    fewer than max(3, 3 % of its ``n_check`` grid points): then nothing the images show
    backs it over f0, which the sparse stage's inliers back (across sensors the check often finds
    no support for either; the dense fit then rests on its own weak matches alone).
    """
    if _unsupported(n_supported, n_check):
        return True
    return only_first > only_final + max(3, _LOST_SHARE * n_check_first)


def _unsupported(n_supported: int, n_check: int) -> bool:
    """Supported at fewer than max(3, 3 % of the ``n_check`` grid points checked): nothing the images show backs it."""
    return n_supported < max(3, _LOST_SHARE * n_check)


def _cells_of(points: np.ndarray, marked: np.ndarray, step: int) -> np.ndarray:
    """(len(points),) bool: the grid cell (floor(x / step), floor(y / step)) of each point holds a marked point."""
    if not len(points) or not len(marked):
        return np.zeros(len(points), bool)

    def key(p: np.ndarray) -> np.ndarray:
        return (p[:, 1] // step).astype(np.int64) * 1_000_003 + (p[:, 0] // step).astype(np.int64)

    return np.isin(key(points), key(marked))
