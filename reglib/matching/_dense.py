"""The dense stage of :func:`reglib.match_images`: guided dense matching around the sparse fit, and a
final transform with a richer basis from those matches (:mod:`reglib.dense`), when the fit allows it."""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._parallel import run_both
from .._transforms import KernelWarp
from .._verdict import TOO_FEW_INLIERS
from ..dense import DenseOptions, refine_dense, residual_start
from ..features import structure_image
from ._inputs import Images, Run, ms
from ._options import MatchOptions
from ._sparse import Sparse

DENSE_STARTS = (None, TOO_FEW_INLIERS)  # the dense stage starts from a sparse fit with one of these reasons ...
_DENSE_MIN_INLIERS = 6  # ... and at least this many inliers, unless the fit has a reason
_STRUCTURE_SIGMA = 2.0  # smoothing of the multimodal dense stage's structure fields, px


@dataclass(frozen=True, eq=False)
class Dense:
    """The dense stage's answer: the fields it correlated (grey images, or structure fields for the multimodal
    path), the transform and its convergence (the sparse fit's when no dense fit was made), the dense matches
    used, the confidence map (None when the stage did not run) and its outcome (:data:`reglib.dense.DENSE_OUTCOMES`);
    ``options``: what the stage runs with (the images' evidence is measured with them too)."""

    options: DenseOptions
    field_a: np.ndarray
    field_b: np.ndarray
    transform: KernelWarp
    converged: bool
    n_dense: int
    confidence: np.ndarray | None
    outcome: str


def dense_options(opts: MatchOptions, method: Literal["l2e", "vfc"]) -> DenseOptions:
    """The dense stage's options (:class:`~reglib.dense.DenseOptions`) from ``match_images``' options."""
    return DenseOptions(method=method, step=opts.dense_step, radius=opts.dense_radius, rounds=opts.dense_rounds,
                        patch=opts.dense_patch, max_side=opts.max_side, filter=opts.dense_filter,
                        sparse_filter=opts.filter, detail=opts.dense_detail)


def dense_stage(sparse: Sparse, images: Images, run: Run, start: KernelWarp | None = None) -> Dense:
    """The dense stage over ``sparse``'s fit, when ``dense`` is on and the fit is one it starts from.

    It also starts from a fit its few inliers do not back (e.g. the multimodal rigid map): its guard
    and the images' evidence then judge the result. ``start``: where its search starts instead of the
    sparse fit (:func:`residual_retry`); the guard then weighs the dense estimate against it."""
    fit = sparse.fit
    field_a, field_b = _fields(sparse, images, run)
    answer = Dense(options=dense_options(run.options, run.method), field_a=field_a, field_b=field_b,
                   transform=fit.transform, converged=fit.converged, n_dense=0, confidence=None, outcome="not_run")
    if not (run.options.dense and fit.reason in DENSE_STARTS
            and (fit.n_inliers >= _DENSE_MIN_INLIERS or fit.reason is not None)):
        return answer
    t = time.perf_counter()
    refined = refine_dense(field_a, field_b, fit.transform if start is None else start, answer.options, run.rng,
                           images.mask_a, images.mask_b)
    if refined.fitted:
        answer = dataclasses.replace(answer, transform=refined.transform, converged=refined.converged,
                                     n_dense=refined.n_dense)
    run.timings["dense"] = ms(t)
    # (f0's own confidence map when no dense fit was made)
    return dataclasses.replace(answer, confidence=refined.confidence, outcome=refined.outcome)


def residual_retry(sparse: Sparse, dense: Dense, images: Images, run: Run) -> Dense | None:
    """The dense stage again, from the sparse fit composed with the motion it left
    (:func:`reglib.dense.residual_start`), for an answer of grey images of one modality
    (``features="sift"``); None where that start cannot be made.

    For the answers the images do not back only: another start moves the dense stage's answer on most pairs, for
    better or worse (benchmarks/README.md, issue 50), so it is tried only where the first answer is not usable.
    Its estimator draws from a child of ``run.rng`` (spawned, not drawn), so the dense fits' draws are as in
    the first try."""
    fit = sparse.fit
    if sparse.features != "sift" or dense.field_a.shape[2:] not in ((), (1,)) or dense.confidence is None:
        return None
    t = time.perf_counter()
    start = residual_start(dense.field_a, dense.field_b, fit.transform, dense.options, run.rng.spawn(1)[0],
                           images.mask_a, images.mask_b)
    run.timings["residual_start"] = ms(t)
    return None if start is None else dense_stage(sparse, images, run, start)


def _fields(sparse: Sparse, images: Images, run: Run) -> tuple[np.ndarray, np.ndarray]:
    """What the dense stage correlates: the grey images, or for the multimodal path structure fields."""
    if sparse.features != "multimodal":
        return images.gray_a, images.gray_b
    t = time.perf_counter()
    norm_a, norm_b = images.normalized
    fields = run_both(lambda: structure_image(norm_a, sigma=_STRUCTURE_SIGMA),
                      lambda: structure_image(norm_b, sigma=_STRUCTURE_SIGMA))
    run.timings["structure"] = ms(t)
    return fields
