"""``FilterResult``: what :func:`reglib.filter_matches` found, and its one JSON form."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .._json import as_bool, as_float, as_int, as_matches, as_reason, as_seed, require_fields
from .._repr import short_repr
from .._transforms import KernelWarp
from .._verdict import Reason
from ..errors import InputError

__all__ = ["STOPPED", "FilterResult", "Stopped"]

Stopped = Literal["tolerance", "iteration_cap"]
STOPPED: tuple[Stopped, ...] = ("tolerance", "iteration_cap")

_WHAT = "filter result"
_KEYS = ("n_matches", "n_inliers", "inliers", "scores", "transform", "converged", "reason", "sigma", "n_iter",
         "method", "seed")


@dataclass(frozen=True, eq=False)
class FilterResult:
    """What :func:`filter_matches` found.

    Attributes
    ----------
    inliers : (N,) bool ndarray
        True for the matches consistent with ``transform`` (with L2E's default ``max_layers=2``,
        also those of a second, independently moving layer; see :class:`L2EOptions`).
    scores : (N,) float ndarray
        Agreement of each match with ``transform`` (or with its layer's affine map) in [0, 1];
        inliers score above the threshold.
    transform : KernelWarp
        Maps src space into dst space; callable on any (K, D) points.
    sigma : float
        Estimated residual scale of the true matches, in dst units (pixels for images).
    n_iter : int
        Re-weighting (L2E) or EM (VFC) iterations run, over all stages.
    converged : bool
        True when the answer is supported by the data and may be used; False exactly when ``reason``
        is set. An iteration cap is not by itself a failure: ``stopped`` records it.
    reason : str or None
        None, or why the result does not explain the scene (then ``converged`` is False; the
        inliers, scores and transform are still the estimator's best):

        - ``too_few_matches``: fewer putative matches than ``options.min_matches``; nothing was
          estimated (all-False inliers, the identity transform).
        - ``too_few_inliers``: fewer inliers than ``min_matches``, than 2 D (D + 1) (twice the
          affine part's unknowns), than two per kernel centre of ``transform``, or hardly more
          than false matches would put within 3 sigma of a fixed transformation by chance.
        - ``small_cluster``: the inliers are one small cluster in both images (median distance to
          their median under a tenth of all matches' in src and in dst): a few false matches
          that agree locally.
        - ``folding``: the transform changes orientation (sign of det df/dx) at more than 5 % of
          the inliers, even after the inliers where it does were dropped: no one-to-one motion
          does that.
    stopped : {"tolerance", "iteration_cap"} or None
        Why the iterations ended: the last annealing step (L2E) or the EM (VFC) settled within its
        tolerance, or ran to its iteration cap; None when nothing was estimated.
    method : str
        The estimator that ran ("l2e" or "vfc").
    seed : int or None
        The integer seed given as ``rng``, recorded for reproduction (None for a Generator or no seed).
    """

    inliers: np.ndarray
    scores: np.ndarray
    transform: KernelWarp
    sigma: float
    n_iter: int
    converged: bool
    reason: Reason | None = None
    method: str = "l2e"
    seed: int | None = None
    stopped: Stopped | None = None

    @property
    def n_matches(self) -> int:
        """Number of putative matches N."""
        return int(len(self.inliers))

    @property
    def n_inliers(self) -> int:
        """Number of inliers."""
        return int(np.count_nonzero(self.inliers))

    def __repr__(self) -> str:
        return short_repr(self, ("method", "n_matches", "n_inliers", "converged", "reason", "stopped", "sigma",
                                 "n_iter", "seed", "transform"))

    def to_dict(self) -> dict[str, Any]:
        """The filter-result JSON of CONTRACTS.md (inliers as ascending indices; plain floats and lists).

        Examples
        --------
        >>> import numpy as np
        >>> from reglib import filter_matches
        >>> src = np.random.default_rng(0).uniform(0, 100, (40, 2))
        >>> res = filter_matches(src, src + 3.0, rng=0)
        >>> d = res.to_dict()
        >>> d["n_inliers"], d["method"], d["seed"]
        (40, 'l2e', 0)
        >>> FilterResult.from_dict(d).n_inliers
        40
        """
        out = {"n_matches": self.n_matches, "n_inliers": self.n_inliers,
               "inliers": np.flatnonzero(self.inliers).tolist(),
               "scores": [float(s) for s in self.scores], "transform": self.transform.to_dict(),
               "converged": bool(self.converged), "reason": self.reason, "sigma": float(self.sigma),
               "n_iter": int(self.n_iter), "method": self.method, "seed": self.seed}
        if self.stopped is not None:  # (an optional key of the form: absent when nothing was estimated)
            out["stopped"] = self.stopped
        return out

    @classmethod
    def from_dict(cls, data: Any) -> FilterResult:
        """Rebuild a result from :meth:`to_dict`'s form (extra keys such as ``timings_ms`` are ignored;
        ``stopped`` is optional).

        Raises
        ------
        InputError
            A missing or malformed field, named.
        """
        d = require_fields(data, _KEYS, _WHAT)
        _, inliers, scores = as_matches(d, _WHAT)
        if not isinstance(d["method"], str):
            raise InputError(f"{_WHAT} `method` must be a string, got {d['method']!r}")
        stopped = d.get("stopped")
        if stopped is not None and stopped not in STOPPED:
            raise InputError(f"{_WHAT} `stopped` must be null or one of {list(STOPPED)}, got {stopped!r}")
        return cls(inliers=inliers, scores=scores, transform=KernelWarp.from_dict(d["transform"]),
                   sigma=as_float(d["sigma"], "sigma", _WHAT), n_iter=as_int(d["n_iter"], "n_iter", _WHAT),
                   converged=as_bool(d["converged"], "converged", _WHAT),
                   reason=as_reason(d["reason"], "reason", _WHAT), method=d["method"],
                   seed=as_seed(d["seed"], "seed", _WHAT), stopped=stopped)
