"""The dense stage: from a rough first estimate to a transform fitted to dense matches, coarse to fine.

Patches of a on a regular grid are matched to b around the current estimate
(:mod:`reglib.dense._correlation`) and the robust estimator with a richer basis is fitted to those
matches (:func:`refine_dense`), as in the dense step of the L2E paper's image pipeline [1]_.

The stage works coarse to fine over an image pyramid (a wide capture range at the coarse levels,
where a patch covers more of the scene and a pixel of search reaches further), runs more rounds on
a level while they still move the estimate, and sizes each round's search window from how far the
previous round moved it (:func:`barely_moved`). Grid points are searched up to a's border (b is
resampled beyond a's frame), so the field is measured where the deformation is often largest rather
than extrapolated there, and the final fit's kernel keeps one width however many centres the dense
support allows. The guard (:mod:`reglib.dense._guarding`) then weighs the dense estimate against
the first one on fresh image evidence; the result and the records handed to the guard are in
:mod:`reglib.dense._result`.

Coordinates are (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0); the
transforms map a into b.

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of
       Transformation for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
"""
from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from .._parallel import run_both
from .._transforms import KernelWarp
from ..robust import fit_matches
from ._confidence import check_support, supported
from ._correlation import _NEAR_RADIUS, SearchSpec, Thresholds, search_grid
from ._detail import detailed
from ._fields import _as_fields, _downscaled
from ._guarding import _check, _confidence, guard
from ._guided import _matched
from ._options import MIN_MATCHES, DenseOptions
from ._result import DenseFit, DenseResult, Evidence, WorkingFrames
from ._texture import _default_min_std, texture_map

__all__ = ["barely_moved", "refine_dense", "working_frames"]

# With ``DenseOptions.detail``, the fits of the pyramid levels from this index on (0: the working level) get the
# narrow-kernel detail (reglib.dense._detail): a strongly bent part of the field is then followed on the coarser
# levels, which brings the finer levels' search within reach of it. Not on the working level, where the narrow fit
# would follow the matches' noise that the smooth fit averages out. Grey images only: matches of descriptor fields
# (across stains and sensors) are not mostly true.
_DETAIL_FROM = 1
_MIN_LEVEL_SIDE = 64  # a pyramid level's shorter side, px, at least
_MAX_LEVELS = 3  # working resolution, 1/2 and 1/4
_STILL = 0.3  # a round moving the estimate by less than this (median over the matches, level px) ends the level
_STILL_COARSE = 0.3  # ... on a coarser level (it only has to bring the estimate within the next level's reach)
_COARSE_STEP = 1.5  # coarser levels' grid spacing, relative to the finest level's (in scene units)
_SEARCH_NCC = 0.5  # a dense match's correlation peak at least


@dataclass(frozen=True, eq=False)
class _Level:
    """One pyramid level: the fields, masks and grid of a's and b's copies at this level."""

    index: int  # 0: the working level; n: 2^-n of it
    a: np.ndarray
    b: np.ndarray
    mask_a: np.ndarray | None
    mask_b: np.ndarray | None
    step: int
    scale_a: float  # level size over original size
    scale_b: float
    min_std: float
    std: np.ndarray | None


@dataclass(frozen=True, eq=False)
class _State:
    """Where the coarse-to-fine rounds stand."""

    estimate: KernelWarp  # the current estimate, original pixels
    radius: int  # the next round's search radius, level px
    rounds: int = 0
    fit: DenseFit | None = None  # the last successful fit (None: none yet)
    evidence: Evidence | None = None  # the working level's last search, when the last fit was made there
    before: KernelWarp | None = None  # the estimate before the last fit (``estimate`` after it)
    done: bool = False  # the level ends: too few matches, or a round that barely moved the estimate


def working_frames(image_a: np.ndarray, image_b: np.ndarray, options: DenseOptions,
                   mask_a: np.ndarray | None = None, mask_b: np.ndarray | None = None) -> WorkingFrames:
    """The images (grey (H, W) or fields (H, W, C), the same C) and masks at the working resolution.

    Raises
    ------
    InputError
        Images that are not (H, W) or (H, W, C), or fields with different C.
    """
    fa, fb = _as_fields(image_a, image_b)
    sa = min(1.0, options.max_side / max(fa.shape[:2]))
    sb = min(1.0, options.max_side / max(fb.shape[:2]))
    ga, ma = _downscaled(fa, mask_a, sa)
    gb, mb = _downscaled(fb, mask_b, sb)
    min_std, std = _texture_stats(ga, options.patch)
    return WorkingFrames(a=ga, b=gb, mask_a=ma, mask_b=mb, scale_a=sa, scale_b=sb,
                         shape_a=(int(fa.shape[0]), int(fa.shape[1])), min_std=min_std, std=std)


def refine_dense(image_a: np.ndarray, image_b: np.ndarray, f0: KernelWarp, options: DenseOptions,
                 rng: np.random.Generator, mask_a: np.ndarray | None = None,
                 mask_b: np.ndarray | None = None) -> DenseResult:
    """From the first estimate ``f0`` to a transform fitted to dense matches.

    Parameters
    ----------
    image_a, image_b : (H, W) or (H, W, C) ndarray
        What is correlated: grey images (any real dtype), or descriptor fields with C channels
        (float32, e.g. a modality-independent structure field) for pairs whose intensities
        cannot be compared. Same C in both.
    f0 : KernelWarp
        First estimate (the sparse stage's), a -> b, original pixels.
    options : DenseOptions
        Grid, search, rounds, working size and the estimator.
    rng : numpy.random.Generator
        Passed to the estimator.
    mask_a, mask_b : (H, W) bool ndarray, optional
        Grid points outside ``mask_a`` and matches outside ``mask_b`` are dropped.

    Returns
    -------
    DenseResult
        ``fitted=False`` (and ``f0`` as the transform) when no level found enough dense matches.

    Raises
    ------
    InputError
        Images that are not (H, W) or (H, W, C), fields with different C, or invalid estimator
        options.

    Notes
    -----
    Images larger than ``options.max_side`` are matched on resized copies (the working resolution);
    matches are mapped back to original pixels exactly before each fit. On top of it, up to two
    coarser levels (1/2, 1/4; shorter side >= 64 px) are matched first with 1.5 times the grid
    spacing in scene units, so patches cover more and the search reaches further there.
    Every grid point whose patch lies inside a is searched, also within the search radius of a's
    border (b is resampled beyond a's frame; a match counts where its patch lies inside b).
    On each level at most ``options.rounds`` rounds run, fewer once a round moves the estimate
    by less than 0.3 level px (median over the matches). The first round of the coarsest
    level searches ``options.radius`` px; every later round searches 2 px beyond twice the
    previous round's 90th-percentile move (between 3 px and ``options.radius``); on the working
    level, grid points where the last round (or the coarser level's last) moved the estimate by at
    most 4 px search within 10 px at most (OpenCV's correlation costs more per call beyond
    radius 10; on coarser levels the same rule lost a strongly deformed pair). The final
    fit's basis follows the dense matches' support (one kernel centre per 4 matches at most,
    centres placed among the matches) at a fixed kernel width (beta 1.8 in the estimator's
    normalized units, whatever the number of centres: a kernel that narrowed with the basis
    would let the field fall back to its affine part across every untextured area). The guard
    (:func:`~reglib.dense._guarding.guard`) then checks both the dense estimate and ``f0``. The guard's check of ``f0``
    runs beside the levels (it depends on ``f0`` alone).
    """
    frames = working_frames(image_a, image_b, options, mask_a, mask_b)
    # The guard's check of f0 depends on f0 alone: it runs beside the levels (run_both; the
    # searches' calls release the GIL), its result unused when no level finds enough matches.
    g0 = f0.rescaled(frames.scale_a, frames.scale_b)
    check0, state = run_both(lambda: _check(frames, g0, 2 * options.step, options),
                             lambda: _coarse_to_fine(frames, f0, options, rng))
    if state.fit is None:
        return _unfitted(frames, f0, options, state.rounds)
    return guard(frames, f0, state.fit, options, rng, rounds=state.rounds, evidence=state.evidence,
                 check_first=check0)


def _coarse_to_fine(frames: WorkingFrames, f0: KernelWarp, options: DenseOptions,
                    rng: np.random.Generator) -> _State:
    """Every level's rounds, the coarsest first, from ``f0``."""
    state = _State(estimate=f0, radius=options.radius)
    n_levels = _n_levels(frames.a.shape[:2], frames.b.shape[:2])
    for index in range(n_levels - 1, -1, -1):
        level = _level(frames, index, options)
        state = dataclasses.replace(state, done=False)
        for _ in range(options.rounds):
            state = _round(level, state, options, rng)
            if state.done:
                break
        # the next level's pixels are half the size: the same uncertainty is twice as many of them
        state = dataclasses.replace(state, radius=int(min(options.radius, max(3, 2 * state.radius - 2))))
    return state


def _level(frames: WorkingFrames, index: int, options: DenseOptions) -> _Level:
    """Pyramid level ``index`` (0: the working level itself; its texture statistics, once per level)."""
    if not index:
        return _Level(index=0, a=frames.a, b=frames.b, mask_a=frames.mask_a, mask_b=frames.mask_b,
                      step=options.step, scale_a=frames.scale_a, scale_b=frames.scale_b,
                      min_std=frames.min_std, std=frames.std)
    k = 2.0 ** -index
    la, lma = _downscaled(frames.a, frames.mask_a, k)
    lb, lmb = _downscaled(frames.b, frames.mask_b, k)
    min_std, std = _texture_stats(la, options.patch)
    return _Level(index=index, a=la, b=lb, mask_a=lma, mask_b=lmb,
                  step=max(4, round(_COARSE_STEP * options.step * k)), scale_a=frames.scale_a * k,
                  scale_b=frames.scale_b * k, min_std=min_std, std=std)


def _round(level: _Level, state: _State, options: DenseOptions, rng: np.random.Generator) -> _State:
    """One round of guided matching around the current estimate, and the fit to its matches."""
    ka, kb = level.scale_a, level.scale_b
    f = state.estimate
    g = f.rescaled(ka, kb)
    near = None
    if state.before is not None and not level.index:
        near = functools.partial(barely_moved, state.before, f, ka, kb)
    spec = SearchSpec(step=level.step, radius=state.radius, half_patch=options.patch,
                      thresholds=Thresholds(min_ncc=_SEARCH_NCC, min_std=level.min_std, min_sharpness=0.0))
    search = search_grid(level.a, level.b, g, spec, mask_a=level.mask_a, std=level.std, near=near)
    src, dst, _ = _matched(search, g, level.mask_b)
    rounds = state.rounds + 1
    if len(src) < MIN_MATCHES:
        return dataclasses.replace(state, rounds=rounds, done=True)
    src = (src + 0.5) / ka - 0.5
    dst = (dst + 0.5) / kb - 0.5
    fit_options = options.estimator_options(len(src), level.index, smooth=level.a.shape[2] > 1)
    res = fit_matches(src, dst, method=options.method, options=fit_options, rng=rng)
    if res.reason is not None or res.n_inliers < MIN_MATCHES:
        return dataclasses.replace(state, rounds=rounds, done=True)
    if options.detail and level.a.shape[2] == 1 and level.index >= _DETAIL_FROM:
        shape = (round(level.a.shape[0] / ka), round(level.a.shape[1] / ka))
        res = dataclasses.replace(res, transform=detailed(res.transform, src, dst, shape, level.step / ka,
                                                          pixel=1.0 / kb, scores=res.scores))
    moves = np.linalg.norm(res.transform(src) - f(src), axis=1) * kb
    moved, spread = float(np.median(moves)), float(np.percentile(moves, 90))
    return _State(estimate=res.transform, radius=int(min(options.radius, max(3, math.ceil(2.0 * spread + 2.0)))),
                  rounds=rounds, fit=DenseFit(transform=res.transform, converged=res.converged, src=src, dst=dst),
                  evidence=Evidence(search, g) if level.index == 0 else None, before=f,
                  done=moved < (_STILL if level.index == 0 else _STILL_COARSE))


def _unfitted(frames: WorkingFrames, f0: KernelWarp, options: DenseOptions, rounds: int) -> DenseResult:
    """The answer when no level found enough dense matches: ``f0``, with its map as
    :func:`~reglib.dense.confidence_map` makes it."""
    g0 = f0.rescaled(frames.scale_a, frames.scale_b)
    # as confidence_map checks: the texture measured at the grid points (no precomputed map)
    check = check_support(frames.a, frames.b, g0, options.step, options.patch, frames.mask_a, frames.min_std)
    conf = _confidence(frames, check, supported(check, g0, g0), g0, options.step)
    return DenseResult(transform=f0, converged=False, n_dense=0, confidence=conf, rounds=rounds, kept_first=False,
                       fitted=False, outcome="no_matches")


def _texture_stats(field: np.ndarray, half_patch: int) -> tuple[float, np.ndarray | None]:
    """A level's texture threshold (a whole-field statistic) and, for a grey field, its texture map (cheaper
    once than at each search's grid points; a multi-channel field's is made at the grid points only, a full
    map costs more there)."""
    return _default_min_std(field), (texture_map(field, half_patch) if field.shape[2] == 1 else None)


def _n_levels(shape_a: tuple[int, int], shape_b: tuple[int, int]) -> int:
    side = min(min(shape_a), min(shape_b))
    n = 1
    while n < _MAX_LEVELS and side / 2 ** n >= _MIN_LEVEL_SIDE:
        n += 1
    return n


def barely_moved(before: KernelWarp, after: KernelWarp, ka: float, kb: float, points: np.ndarray) -> np.ndarray:
    """(G,) bool: the last round moved the estimate at these grid points (a level's px, scales ``ka`` of a and
    ``kb`` of b) by at most (10 - 2) / 2 = 4 of that level's px.

    The round's radius rule (2 px beyond twice the move; the next level, twice that less 2 px,
    in pixels half the size) asks no more than 10 px there (the near search's radius). Trusted
    input: does not validate."""
    q = (points + 0.5) / ka - 0.5
    move = np.linalg.norm(after(q) - before(q), axis=1) * kb
    return move <= (_NEAR_RADIUS - 2) / 2.0
