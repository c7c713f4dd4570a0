"""``ImageMatch``: what :func:`reglib.match_images` found, and its one JSON form (the match JSON)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._json import as_array, as_bool, as_float, as_int, as_matches, as_reason, as_seed, require_fields
from .._repr import short_repr
from .._transforms import KernelWarp
from .._verdict import Reason
from ..dense import DENSE_OUTCOMES, confidence_summary
from ..errors import InputError

__all__ = ["ImageMatch"]

_WHAT = "match result"
_KEYS = ("n_matches", "n_inliers", "src", "dst", "inliers", "scores", "transform", "converged", "reason", "seed",
         "shape_a", "shape_b")


@dataclass(frozen=True, eq=False)
class ImageMatch:
    """What :func:`match_images` found. Coordinates are (x, y) pixels of the original images.

    Attributes
    ----------
    keypoints_a, keypoints_b : (Ka, 2), (Kb, 2) float64 ndarray
        Detected keypoints.
    src, dst : (N, 2) float64 ndarray
        Putative matches: ``src[i]`` in a matched to ``dst[i]`` in b.
    inliers : (N,) bool ndarray
        Matches consistent with the estimated transformation (the sparse L2E/VFC stage).
    scores : (N,) float64 ndarray
        Their agreement in [0, 1].
    transform : KernelWarp
        Maps a's pixels into b (the dense stage's estimate when dense refinement ran).
    converged : bool
        False when the estimator hit an iteration cap or there was too little to work with.
    reason : str or None
        ``too_few_matches`` when nothing could be estimated (no keypoints included), ``unsupported`` when
        the images themselves rate the answer worse than no motion (``converged`` is then False), the
        sparse estimator's reason, else None (one of :data:`reglib.REASONS`).
    seed : int or None
        The integer seed given as ``rng``, recorded for reproduction.
    features, method : str
        The feature kind and the estimator that ran.
    timings_ms : dict of str to float
        Per-stage wall time: "read", "features", "matching", "filter", "dense", "total"; "haematoxylin" where
        ``features="auto"`` tried SIFT on colour images' haematoxylin channel before the multimodal features (that
        attempt's whole time); "second_try" where it tried the channel again after an unsupported answer, and
        "residual_try" (with "residual_start") where ``features="sift"`` tried the dense stage again from the motion
        the sparse fit left (the other stages then time the try whose answer was kept).
    shape_a, shape_b : (int, int)
        (H, W) of the images.
    fold_fraction : float
        Share of a's pixels where the transform folds (Jacobian determinant <= 0).
    n_dense : int
        Dense matches the final transform was fitted to (0 without dense refinement).
    confidence : (H_a, W_a) float32 ndarray or None
        How well the flow is supported by the images at each pixel of a, in [0, 1]
        (:func:`reglib.dense.confidence_map`): near 1 where patches of a are found in b where the
        transform puts them, near 0 where the flow is only extrapolated (no texture, outside b)
        or disagrees with the images. None when no dense stage ran (``dense`` off, shape-context
        features, or a sparse fit the stage does not start from: as CONTRACTS.md says, the summary is
        then null too), and when read back from JSON, which carries only its summary
        (:attr:`confidence_summary`). :func:`reglib.dense.confidence_map` measures any transform's.
    confidence_stats : dict or None
        The summary read back by :meth:`from_dict` (used when ``confidence`` is None).
    dense : str
        What became of the dense stage, one of :data:`reglib.dense.DENSE_OUTCOMES`: "kept" (its result is
        the answer), "sparse_better" or "no_support" (the guard kept the sparse estimate: the images support
        it at clearly more places, or support neither and their similarity does not favour the dense
        estimate), "no_matches" (too few dense matches for a fit), "not_run" (dense off, or the sparse
        stage gave it nothing to start from). In the JSON, the ``confidence`` summary's ``"dense"`` key.

    ``to_dict()`` is the match JSON of CONTRACTS.md; ``from_dict()`` reads it back (the keypoints
    are not part of it and come back empty).
    """

    keypoints_a: np.ndarray
    keypoints_b: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    inliers: np.ndarray
    scores: np.ndarray
    transform: KernelWarp
    converged: bool
    reason: Reason | None
    seed: int | None
    timings_ms: dict[str, float] = field(default_factory=dict)
    shape_a: tuple[int, int] = (0, 0)
    shape_b: tuple[int, int] = (0, 0)
    fold_fraction: float = 0.0
    n_dense: int = 0
    features: str = "sift"
    method: str = "l2e"
    confidence: np.ndarray | None = None
    confidence_stats: dict[str, float] | None = None
    dense: str = "not_run"

    @property
    def n_matches(self) -> int:
        """Number of putative matches N."""
        return int(len(self.src))

    @property
    def n_inliers(self) -> int:
        """Number of inliers."""
        return int(np.count_nonzero(self.inliers))

    @property
    def confidence_summary(self) -> dict[str, float | str] | None:
        """``{"mean", "supported_share", "overlap", "dense"}``: the confidence map's mean and share of pixels >= 0.5
        over the pixels of a that the transform maps inside b, that share of a
        (:func:`reglib.dense.confidence_summary`), and what became of the dense stage (:attr:`dense`)."""
        if self.confidence is None:
            stats = None if self.confidence_stats is None else dict(self.confidence_stats)
        else:
            stats = confidence_summary(self.confidence, self.transform, self.shape_b)
        if stats is None:
            return None
        return {**stats, "dense": self.dense}

    def __repr__(self) -> str:
        return short_repr(self, ("features", "method", "n_matches", "n_inliers", "converged", "reason", "shape_a",
                                 "shape_b", "n_dense", "dense", "fold_fraction", "confidence", "seed", "transform"))

    def to_dict(self) -> dict[str, Any]:
        """The match-result JSON of CONTRACTS.md (inliers as ascending indices), plus shapes, folds and stages."""
        return {
            "n_matches": self.n_matches,
            "n_inliers": self.n_inliers,
            "src": self.src.tolist(),
            "dst": self.dst.tolist(),
            "inliers": np.flatnonzero(self.inliers).tolist(),
            "scores": [float(s) for s in self.scores],
            "transform": self.transform.to_dict(),
            "converged": bool(self.converged),
            "reason": self.reason,
            "seed": self.seed,
            "features": self.features,
            "method": self.method,
            "timings_ms": {k: float(v) for k, v in self.timings_ms.items()},
            "shape_a": [int(v) for v in self.shape_a],
            "shape_b": [int(v) for v in self.shape_b],
            "fold_fraction": float(self.fold_fraction),
            "n_dense": int(self.n_dense),
            "confidence": self.confidence_summary,
        }

    @classmethod
    def from_dict(cls, data: Any) -> ImageMatch:
        """Rebuild a match from :meth:`to_dict`'s form (e.g. a ``match.json``); keypoints come back empty.

        Raises
        ------
        InputError
            A missing or malformed field, named.
        """
        d = require_fields(data, _KEYS, _WHAT)
        n, inliers, scores = as_matches(d, _WHAT)
        shapes = [tuple(int(v) for v in as_array(d[k], k, _WHAT, shape=(2,), dtype=np.int64))
                  for k in ("shape_a", "shape_b")]
        timings = d.get("timings_ms") or {}
        if not isinstance(timings, dict):
            raise InputError(f"{_WHAT} `timings_ms` must be an object of numbers")
        for key in ("features", "method"):
            if not isinstance(d.get(key, ""), str):
                raise InputError(f"{_WHAT} `{key}` must be a string, got {d[key]!r}")
        empty = np.zeros((0, 2))
        return cls(keypoints_a=empty, keypoints_b=empty.copy(), src=as_array(d["src"], "src", _WHAT, shape=(n, 2)),
                   dst=as_array(d["dst"], "dst", _WHAT, shape=(n, 2)), inliers=inliers,
                   scores=scores,
                   transform=KernelWarp.from_dict(d["transform"]),
                   converged=as_bool(d["converged"], "converged", _WHAT),
                   reason=as_reason(d["reason"], "reason", _WHAT),
                   seed=as_seed(d["seed"], "seed", _WHAT),
                   timings_ms={str(k): as_float(v, f"timings_ms.{k}", _WHAT) for k, v in timings.items()},
                   shape_a=shapes[0], shape_b=shapes[1],  # type: ignore[arg-type]  # two ints each (shape=(2,))
                   fold_fraction=as_float(d.get("fold_fraction", 0.0), "fold_fraction", _WHAT),
                   n_dense=as_int(d.get("n_dense", 0), "n_dense", _WHAT),
                   features=d.get("features", "sift"), method=d.get("method", "l2e"),
                   confidence_stats=_confidence_stats(d.get("confidence")), dense=_dense_outcome(d.get("confidence")))


def _dense_outcome(value: Any) -> str:
    """The ``confidence`` summary's ``dense`` key ("not_run" without a summary; a summary written before the key
    existed came from a dense stage whose result was used: "kept")."""
    if not isinstance(value, dict):
        return "not_run"
    out = value.get("dense", "kept")
    if out not in DENSE_OUTCOMES:
        raise InputError(f"{_WHAT} `confidence.dense` must be one of {', '.join(DENSE_OUTCOMES)}, got {out!r}")
    return str(out)


def _confidence_stats(value: Any) -> dict[str, float] | None:
    """The match JSON's ``confidence`` summary: null, or ``mean``, ``supported_share`` (and ``overlap``) in [0, 1],
    and ``dense`` (read by :func:`_dense_outcome`)."""
    if value is None:
        return None
    if not isinstance(value, dict) or not {"mean", "supported_share"} <= set(value) <= {"mean", "supported_share",
                                                                                          "overlap", "dense"}:
        raise InputError(f"{_WHAT} `confidence` must be null or an object of `mean`, `supported_share`, `overlap` "
                         f"and `dense`")
    out = {k: as_float(v, f"confidence.{k}", _WHAT) for k, v in value.items() if k != "dense"}
    for k, v in out.items():
        if not 0.0 <= v <= 1.0:
            raise InputError(f"{_WHAT} `confidence.{k}` must be in [0, 1], got {v!r}")
    return out
