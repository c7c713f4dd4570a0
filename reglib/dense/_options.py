"""``DenseOptions``: what the dense stage (:func:`~reglib.dense.refine_dense`) is run with.

Each field is declared once with :func:`reglib.options.option` (kind, bounds, meaning);
:func:`reglib.match_images` makes them from its :class:`~reglib.MatchOptions` (``dense_step``,
``dense_radius``, ...). :meth:`DenseOptions.estimator_options` gives each dense fit's estimator
options: a richer basis than the sparse stage's.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from .._validation import as_options
from ..options import check_declared, declared, option
from ..robust import L2EOptions, VFCOptions

__all__ = ["DENSE_L2E", "DENSE_VFC", "DenseOptions"]

# Options of the dense stage's estimator that differ from the sparse stage's (a richer basis).
# One layer: the dense stage's transform is the primary layer's in any case. Annealing from the
# identity (normalized units), not the locality-prior consensus start: that start is there to find
# a minority of true matches among random false ones, and the dense matches, searched around the
# current estimate, are mostly true; its neighbourhood statistics and candidate solves are a
# sizeable part of each dense fit's cost.
DENSE_L2E: dict[str, Any] = {"max_centers": 150, "max_fit_points": 4000, "max_layers": 1, "start": "identity"}
DENSE_VFC: dict[str, Any] = {"n_centers": 60, "beta": 1.0, "linear": "affine"}

MIN_MATCHES = 20  # fewer dense matches or inliers than this: a round, a level or the guard's re-fit gives no fit
MATCHES_PER_CENTER = 4.0  # dense matches per kernel centre at most, final level (the basis follows the support)
COARSE_MATCHES_PER_CENTER = 6.0  # ... on a coarser level (a smaller basis: cheaper, and it need not resolve detail)
COARSE_CENTERS = 0.5  # coarser levels' basis at most this share of the finest level's, per halving
FINAL_BETA = 1.8  # the final fit's kernel exp(-beta |u - c|^2) in normalized units (RMS radius 1): sigma ~0.5
# The working level's RKHS regularization (the estimator's default with a linear part: 1.0). Its dense matches are
# searched around the coarser levels' estimate and mostly true, while a strongly bent field needs the freedom: at the
# default the fit rejects perfect grid matches of its steepest parts as outliers. Weaker still, the fit follows the
# matches' noise on some pairs; coarser levels keep the default (a weaker one on every level lost pairs).
FINAL_LAM = 0.1


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class DenseOptions:
    """Options of the dense stage, :func:`~reglib.dense.refine_dense`.

    Parameters
    ----------
    method : {"l2e", "vfc"}
        The estimator of each dense fit.
    step : int
        Grid spacing of the working level, pixels (of the possibly resized copy).
    radius : int
        Search radius around the first estimate, pixels; later rounds search less (at least 3 px).
    rounds : int
        Rounds of guided matching per pyramid level at most.
    patch : int
        Half-size h of the (2 h + 1)^2 patches correlated, pixels.
    max_side : int
        Images with a longer side are matched on resized copies (the working resolution).
    filter : dict or None
        Estimator options of every dense fit, replacing the defaults below.
    sparse_filter : dict or None
        The sparse stage's estimator options: with ``filter`` None, laid over ``DENSE_L2E`` /
        ``DENSE_VFC`` (L2E: one centre per 4 dense matches at the working size and one per 6 on
        coarser levels, up to 150, at a fixed kernel width and an RKHS weight ``lam`` 0.1 on the working
        level; VFC: 60 centres, beta 1, an affine part).
    detail : bool
        Grey images: each coarser level's fit is replaced by :func:`reglib.dense.detailed` (its
        linear part kept, a narrow-kernel field on a lattice fitted to the matches), so a strongly
        bent field is followed before the finer levels search around it. Off by default (slower).
    """

    method: Literal["l2e", "vfc"] = option("l2e", kind="choice", choices=("l2e", "vfc"),
                                           doc="estimator of each dense fit")
    step: int = option(16, kind="int", low=1, high=1024, doc="grid spacing of the working level (px)")
    radius: int = option(14, kind="int", low=1, high=256, doc="search radius around the first estimate (px)")
    rounds: int = option(2, kind="int", low=1, high=10, doc="rounds of guided matching per pyramid level, at most")
    patch: int = option(5, kind="int", low=2, high=64, doc="half-size of the patches correlated (px)")
    max_side: int = option(1600, kind="int", low=16, high=100_000,
                           doc="images with a longer side are matched on a resized copy (px)")
    filter: dict[str, Any] | None = option(None, kind="json",
                                           doc="estimator options of the dense fits, replacing the defaults")
    sparse_filter: dict[str, Any] | None = option(None, kind="json",
                                                  doc="the sparse stage's estimator options, over the dense defaults")
    detail: bool = option(False, kind="bool",
                          doc="grey images: the coarser levels' fits get a narrow-kernel detail (reglib.dense._detail)")

    def __post_init__(self) -> None:
        check_declared(self)

    def estimator_options(self, n: int, level: int = 0, *, smooth: bool = False) -> L2EOptions | VFCOptions:
        """The estimator options of a dense fit to ``n`` matches on pyramid level ``level`` (0: the working one).

        ``smooth``: keep the estimator's default smoothness rather than ``FINAL_LAM`` on the working level: for
        the guard's re-fit, whose matches (the dense ones and the first estimate's check matches) disagree by
        design, and for matches of descriptor fields (across stains the working level's matches are not
        mostly true: FINAL_LAM lost accuracy on the stain-like pairs).

        Raises
        ------
        InputError
            A misspelled or invalid field of ``filter`` / ``sparse_filter``, named.
        """
        cls: type[L2EOptions | VFCOptions] = L2EOptions if self.method == "l2e" else VFCOptions
        if self.filter is not None:
            return as_options(dict(self.filter), cls)
        base = {**(DENSE_L2E if self.method == "l2e" else DENSE_VFC), **dict(self.sparse_filter or {})}
        if self.method == "l2e" and "max_centers" not in (self.sparse_filter or {}):
            # the basis follows the support: about one centre per MATCHES_PER_CENTER dense matches, and a
            # coarser level (which cannot resolve the finest detail) a smaller one
            cap = base["max_centers"] * COARSE_CENTERS ** level
            per_center = MATCHES_PER_CENTER if level == 0 else COARSE_MATCHES_PER_CENTER
            base["max_centers"] = int(max(15, min(cap, n / per_center)))
            if level == 0 and "beta" not in (self.sparse_filter or {}):
                # the final fit's kernel width is fixed in the estimator's normalized units (it scales
                # beta by M / n_centers over its levels), however many centres the support allows:
                # a basis that narrows with the number of matches decays to the affine part within a
                # few of its widths from the matches, i.e. across any untextured area
                n_centers = int(base.get("n_centers", L2EOptions().n_centers))
                m_final = base["max_centers"] if base["max_centers"] >= 1.5 * n_centers else n_centers
                base["beta"] = FINAL_BETA * n_centers / m_final
            if level == 0 and not smooth and "lam" not in (self.sparse_filter or {}):
                # a weaker smoothness weight on the working level, whose matches are mostly true: a strongly
                # bent field is followed instead of its steepest matches being rejected (FINAL_LAM)
                base["lam"] = FINAL_LAM
        return as_options(base, cls)
