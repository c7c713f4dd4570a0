"""The dense stage: from a rough first estimate to a transform fitted to dense matches.

Patches of a on a regular grid are matched to b around the current estimate
(:mod:`reglib.dense.correlation`) and the robust estimator with a richer basis is fitted to those
matches (:func:`refine_dense`), as in the dense step of the L2E paper's image pipeline [1]_.

The stage works coarse to fine over an image pyramid (a wide capture range at the coarse levels,
where a patch covers more of the scene and a pixel of search reaches further), runs more rounds on
a level while they still move the estimate, and sizes each round's search window from how far the
previous round moved it. Grid points are searched up to a's border (b is resampled beyond a's
frame), so the field is measured where the deformation is often largest rather than extrapolated
there, and the final fit's kernel keeps one width however many centres the dense support allows.
A guard (:func:`guard`) then compares the dense estimate with the first one on fresh image
evidence (:mod:`reglib.dense.confidence`): where the dense estimate is no longer supported but
the first one is, that evidence pins the final fit to the first estimate; if the result is still
supported less overall, the first estimate is kept. Where the check supports neither (across stains
and sensors fine structure differs, so no patch has a distinct peak within 1 px), the images' local
similarity at the two estimates decides instead (:func:`evidence_z`): the dense estimate is kept when it
makes the images more similar at clearly more places than the first one.

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
from ..robust import fit_matches
from ..transforms import KernelWarp
from .confidence import check_support, local_similarity, support_map, supported, upsampled
from .correlation import (
    _NEAR_RADIUS,
    GridSearch,
    SearchSpec,
    Thresholds,
    _as_fields,
    _default_min_std,
    _downscaled,
    _matched,
    on_lattice,
    search_grid,
    texture_map,
)
from .detail import detailed
from .options import DenseOptions

__all__ = ["DENSE_OUTCOMES", "EVIDENCE_Z", "DenseFit", "DenseResult", "Evidence", "WorkingFrames", "barely_moved",
           "guard", "evidence_over_no_motion", "evidence_z", "keep_first", "refine_dense", "working_frames"]

# what became of the dense stage (the match JSON's ``confidence.dense``): its result was kept; f0 was kept
# because the images support it at clearly more places; f0 was kept because the check supports neither and
# the images' similarity does not clearly favour the dense result; no pyramid level found enough dense
# matches; the stage did not run (set by match_images)
DENSE_OUTCOMES = ("kept", "sparse_better", "no_support", "no_matches", "not_run")

# With ``DenseOptions.detail``, the coarser levels' fits get the narrow-kernel detail (reglib.dense.detail): a strongly
# bent part of the field is then followed there, and brings the finer levels' search within reach of it (issue 27's
# wider generator, training seeds: mean EPE 1.68 -> 1.50 px; on the working level as well, lattice spacing 1: 1.54 px
# but every well-registered pair 0.1-0.2 px worse, as the narrow fit follows the matches' noise that the smooth fit
# averages out). Grey images only: matches of descriptor fields (across stains and sensors) are not mostly true.
_DETAIL_FROM = 1
_MIN_MATCHES = 20  # fewer dense matches than this: the round (or level) gives no estimate
_MIN_LEVEL_SIDE = 64  # a pyramid level's shorter side, px, at least
_MAX_LEVELS = 3  # working resolution, 1/2 and 1/4
_STILL = 0.3  # a round moving the estimate by less than this (median over the matches, level px) ends the level
_STILL_COARSE = 0.3  # ... on a coarser level (it only has to bring the estimate within the next level's reach)
_COARSE_STEP = 1.5  # coarser levels' grid spacing, relative to the finest level's (in scene units)
_LOST_SHARE = 0.03  # the guard re-fits when f0 alone is supported at this share of its check's grid or more
_SEARCH_NCC = 0.5  # a dense match's correlation peak at least
EVIDENCE_PATCH = 12  # half-size of the patches of the similarity evidence (working px)
EVIDENCE_Z = 4.0  # a sign test's z at least (patches that do not overlap): one estimate is more similar at clearly
# more places than another (one-sided p about 3e-5; chosen on the stain-like training pairs, z 4.5-12 for a right
# dense estimate there, and on the shared SPECT / CT pairs, 3.0-3.7 for a wrong one)


@dataclass(frozen=True, eq=False)
class DenseResult:
    """What :func:`refine_dense` found.

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
        hardly at all: :func:`keep_first`).
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
    (:func:`guard`) then checks both the dense estimate and ``f0``. The guard's check of ``f0``
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
    if len(src) < _MIN_MATCHES:
        return dataclasses.replace(state, rounds=rounds, done=True)
    src = (src + 0.5) / ka - 0.5
    dst = (dst + 0.5) / kb - 0.5
    fit_options = options.estimator_options(len(src), level.index, smooth=level.a.shape[2] > 1)
    res = fit_matches(src, dst, method=options.method, options=fit_options, rng=rng)
    if res.reason is not None or res.n_inliers < _MIN_MATCHES:
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

    Both the dense estimate and ``f0`` are checked (:func:`~reglib.dense.check_support`); check
    matches that support ``f0`` where the dense estimate is unsupported join the dense matches
    for one more fit (kept if, on every other grid point, it is supported at least as often as the
    dense estimate), and ``f0`` is kept if the result is still supported at fewer grid points
    than ``f0``, or at almost none (:func:`keep_first`). In that last case the images' local
    similarity decides instead: the result is kept when it is more similar than ``f0`` at clearly more
    places (:func:`evidence_z` at least ``EVIDENCE_Z``). :attr:`DenseResult.outcome` says which.

    Parameters
    ----------
    frames : WorkingFrames
        The images at the working resolution (:func:`working_frames`).
    f0 : KernelWarp
        The first estimate, a -> b, original pixels.
    fit : DenseFit
        The dense estimate and the matches it was fitted to.
    options : DenseOptions
    rng : numpy.random.Generator
        Passed to the estimator of the re-fit.
    rounds : int
        Recorded in the result (:attr:`DenseResult.rounds`).
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
    if res.reason is not None or res.n_inliers < _MIN_MATCHES:
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


def _unfitted(frames: WorkingFrames, f0: KernelWarp, options: DenseOptions, rounds: int) -> DenseResult:
    """The answer when no level found enough dense matches: ``f0``, with its map as
    :func:`~reglib.dense.confidence_map` makes it."""
    g0 = f0.rescaled(frames.scale_a, frames.scale_b)
    # as confidence_map checks: the texture measured at the grid points (no precomputed map)
    check = check_support(frames.a, frames.b, g0, options.step, options.patch, frames.mask_a, frames.min_std)
    conf = _confidence(frames, check, supported(check, g0, g0), g0, options.step)
    return DenseResult(transform=f0, converged=False, n_dense=0, confidence=conf, rounds=rounds, kept_first=False,
                       fitted=False, outcome="no_matches")


def _check(frames: WorkingFrames, g: KernelWarp, step: int, options: DenseOptions) -> GridSearch:
    """The support check of ``g`` (working pixels) on the grid of ``step``, with the working level's texture."""
    return check_support(frames.a, frames.b, g, step, options.patch, frames.mask_a, frames.min_std, frames.std)


def _confidence(frames: WorkingFrames, check: GridSearch, support: np.ndarray, g: KernelWarp,
                step: int) -> np.ndarray:
    """The confidence map of ``g`` from its check, on a's original pixels."""
    conf = support_map(check, support, g, frames.b.shape[:2], frames.a.shape[:2], step)
    return upsampled(conf, frames.shape_a) if frames.scale_a < 1.0 else conf


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


def evidence_z(field_a: np.ndarray, field_b: np.ndarray, better: KernelWarp, worse: KernelWarp, step: int) -> float:
    """The sign test's z that ``better`` makes the fields more similar than ``worse`` does (both in their pixels).

    On a grid of a whose patches do not overlap (spacing the larger of ``step`` and the patch, 2 * 12 + 1 px,
    offset by half of it, so that the points are about independent samples), the local similarity
    (:func:`~reglib.dense.confidence.local_similarity`) at both transforms; z = (wins - n / 2) / sqrt(n / 4)
    over the n points where both are measured and differ (0.0 for none). Positive: ``better`` is more similar
    at more points. Trusted input: (H, W, C) float32 fields with the same C; does not validate.
    """
    h, w = field_a.shape[:2]
    spacing = max(int(step), 2 * EVIDENCE_PATCH + 1)
    ys, xs = np.mgrid[spacing // 2:h:spacing, spacing // 2:w:spacing]
    points = np.c_[xs.ravel(), ys.ravel()].astype(np.float64)
    s1 = local_similarity(field_a, field_b, better, points, EVIDENCE_PATCH)
    s2 = local_similarity(field_a, field_b, worse, points, EVIDENCE_PATCH)
    both = np.isfinite(s1) & np.isfinite(s2) & (s1 != s2)
    n = int(np.count_nonzero(both))
    if not n:
        return 0.0
    wins = int(np.count_nonzero(s1[both] > s2[both]))
    return float((wins - n / 2.0) / math.sqrt(n / 4.0))


def evidence_over_no_motion(image_a: np.ndarray, image_b: np.ndarray, transform: KernelWarp,
                            options: DenseOptions) -> float:
    """How clearly the images themselves rate ``transform`` (a -> b, original pixels) over no motion at all.

    :func:`evidence_z` of ``transform`` over the identity on the working copies of ``options.max_side``:
    at most -4 (``-EVIDENCE_Z``), the identity makes the images more similar at clearly more places
    (the answer is worse than no motion); at least 4, ``transform`` clearly better. ``image_a``,
    ``image_b``: what the dense stage correlates ((H, W) grey or (H, W, C) fields, the same C); trusted input
    otherwise.
    """
    fa, fb = _as_fields(image_a, image_b)
    sa = min(1.0, options.max_side / max(fa.shape[:2]))
    sb = min(1.0, options.max_side / max(fb.shape[:2]))
    ga, _ = _downscaled(fa, None, sa)
    gb, _ = _downscaled(fb, None, sb)
    none = KernelWarp.identity(2)
    return evidence_z(ga, gb, transform.rescaled(sa, sb), none.rescaled(sa, sb), options.step)


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
