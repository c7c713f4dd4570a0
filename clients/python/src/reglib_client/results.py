"""Frozen, typed results mirroring the service's response schemas (CONTRACTS.md).

Arrays are read-only numpy arrays; points are (N, D) float64 of (x, y[, z]) with x the column.
"""
from __future__ import annotations

from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Generic, TypeVar

import numpy as np

from .transform import Transform, homogeneous_matrix

__all__ = ["MatchResult", "FilterResult", "RegisterResult", "WarpResult", "FlowResult", "ConfidenceResult", "Health",
           "PairOutcome"]

T = TypeVar("T")


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


def points_array(value: Any, key: str, dim: int | None = None) -> np.ndarray:
    """(N, D) float64 from nested lists; an empty list gives (0, dim or 2)."""
    arr = np.array(value, dtype=np.float64)
    if arr.size == 0:
        arr = arr.reshape(0, dim or 2)
    if arr.ndim != 2 or (dim is not None and arr.shape[1] != dim) or arr.shape[1] not in (2, 3):
        raise ValueError(f"`{key}` must have shape (N, {dim or 'D'}), got {arr.shape}")
    return _frozen(arr)


def index_array(value: Any, key: str) -> np.ndarray:
    arr = np.array(value)
    if arr.size == 0:
        arr = arr.reshape(0)
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"`{key}` must be a list of integers")
    return _frozen(arr.astype(np.int64))


def _check_fields(data: Any, required: tuple[str, ...], what: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ValueError(f"{what} must be a JSON object, got {type(data).__name__}")
    missing = [key for key in required if key not in data]
    if missing:
        raise ValueError(f"{what} is missing field(s) {missing}")
    return data


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class MatchResult:
    """Matches between image a and image b (``match``) or putative matches filtered (``filter``).

    Attributes
    ----------
    n_matches, n_inliers : int
        Putative matches N and those kept as true K.
    src, dst : (N, D) float64
        Row i of ``src`` (in image a) is matched to row i of ``dst`` (in image b).
    inliers : (K,) int64
        Ascending indices into ``src`` / ``dst`` of the true matches; see :attr:`inlier_mask`.
    scores : (N,) float64
        Confidence of every match, in [0, 1].
    transform : Transform
        The estimated map from image a to image b, evaluable locally; ``transform.to_dict()``.
    converged : bool
        False when the estimator stopped early or had too little to work with (see ``reason``).
    reason : str or None
        Why ``converged`` is False: one of the service's reason codes (its OpenAPI schema lists them with
        their meaning, under ``reason``'s ``x-reasons``), else None.
    seed : int or None
        The seed the service used; the same request with it gives the same answer.
    features : str or None
        The feature path that ran (``"sift"``, ``"shape_context"``, ``"multimodal"``): with
        ``features="auto"`` this says which one it resolved to. None for ``filter`` results.
    method : str or None
        The estimator that ran (``"l2e"`` or ``"vfc"``).
    shape_a, shape_b : (int, int) or None
        ``(H, W)`` of image a and image b as the service decoded them.
    fold_fraction : float or None
        Share of image a's pixels where the transform folds (det of its Jacobian <= 0), in [0, 1].
    n_dense : int or None
        Matches added by the dense stage (0 with ``dense`` off).
    confidence : Mapping[str, float | str] or None
        The summary of the match's confidence map: ``mean``, ``supported_share`` and ``overlap``, and
        ``dense`` (a string: "kept", "sparse_better", "no_support", "no_matches" or "not_run", what became
        of the dense stage) when the server sends it; None when no map was made (the map itself:
        ``Client.confidence``).
    timings_ms : Mapping[str, float]
        Server-side time per stage.

    ``repr()`` shows counts and key numbers, never the arrays.
    """

    n_matches: int
    n_inliers: int
    src: np.ndarray
    dst: np.ndarray
    inliers: np.ndarray
    scores: np.ndarray
    transform: Transform
    converged: bool
    reason: str | None = None
    seed: int | None = None
    features: str | None = None
    method: str | None = None
    shape_a: tuple[int, int] | None = None
    shape_b: tuple[int, int] | None = None
    fold_fraction: float | None = None
    n_dense: int | None = None
    confidence: Mapping[str, float | str] | None = None
    timings_ms: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def inlier_mask(self) -> np.ndarray:
        """(N,) bool, True at the true matches."""
        mask = np.zeros(self.n_matches, dtype=bool)
        mask[self.inliers] = True
        return mask

    def __repr__(self) -> str:
        return _short_repr(self, ("n_matches", "n_inliers", "converged", "reason", "features", "method", "shape_a",
                                  "shape_b", "fold_fraction", "n_dense", "confidence", "seed", "transform"))

    @classmethod
    def from_json(cls, data: Any, *, src: Any = None, dst: Any = None) -> MatchResult:
        """Read a match result; ``src`` / ``dst`` fill in when the response leaves them out (``filter``)."""
        data = _check_fields(data, ("n_matches", "n_inliers", "inliers", "scores", "transform", "converged"),
                             "match result")
        src_pts = points_array(data["src"] if "src" in data else src, "src")
        dst_pts = points_array(data["dst"] if "dst" in data else dst, "dst", src_pts.shape[1])
        scores = _frozen(np.array(data["scores"], dtype=np.float64).reshape(-1))
        inliers = index_array(data["inliers"], "inliers")
        n = int(data["n_matches"])
        if len(src_pts) != n or len(dst_pts) != n or len(scores) != n:
            raise ValueError(f"match result has n_matches={n} but {len(src_pts)} src, {len(dst_pts)} dst and "
                             f"{len(scores)} scores")
        if len(inliers) != int(data["n_inliers"]) or (len(inliers) and (inliers.min() < 0 or inliers.max() >= n)):
            raise ValueError("match result `inliers` disagree with `n_inliers` or `n_matches`")
        timings = data.get("timings_ms") or {}
        seed = data.get("seed")
        return cls(n_matches=n, n_inliers=len(inliers), src=src_pts, dst=dst_pts, inliers=inliers, scores=scores,
                   transform=Transform.from_dict(data["transform"]), converged=bool(data["converged"]),
                   reason=data.get("reason"), seed=None if seed is None else int(seed),
                   features=_text(data, "features"), method=_text(data, "method"),
                   shape_a=_shape(data, "shape_a"), shape_b=_shape(data, "shape_b"),
                   fold_fraction=_number(data, "fold_fraction"), n_dense=_count(data, "n_dense"),
                   confidence=_match_summary(data.get("confidence")),
                   timings_ms=MappingProxyType({str(k): float(v) for k, v in dict(timings).items()}))


def _text(data: dict[str, Any], key: str) -> str | None:
    value = data.get(key)
    if value is not None and not isinstance(value, str):
        raise ValueError(f"`{key}` must be a string, got {type(value).__name__}")
    return value


def _number(data: dict[str, Any], key: str) -> float | None:
    value = data.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"`{key}` must be a number, got {value!r}")
    return float(value)


def _count(data: dict[str, Any], key: str) -> int | None:
    value = data.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"`{key}` must be an integer >= 0, got {value!r}")
    return value


def _shape(data: dict[str, Any], key: str) -> tuple[int, int] | None:
    value = data.get(key)
    if value is None:
        return None
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value)):
        raise ValueError(f"`{key}` must be [height, width], got {value!r}")
    return (value[0], value[1])


def _summary(value: Any) -> Mapping[str, float] | None:
    if not isinstance(value, dict):
        return None
    return MappingProxyType({str(k): float(v) for k, v in value.items() if isinstance(v, (int, float))})


def _match_summary(value: Any) -> Mapping[str, float | str] | None:
    """A match's ``confidence`` summary: its numbers, and its ``dense`` outcome as a string."""
    numbers = _summary(value)
    if numbers is None:
        return None
    dense = value.get("dense")
    if dense is None:
        return numbers
    if not isinstance(dense, str):
        raise ValueError(f"`confidence.dense` must be a string, got {type(dense).__name__}")
    return MappingProxyType({**numbers, "dense": dense})


def _value_repr(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k!r}: {_value_repr(v)}" for k, v in value.items()) + "}"
    if isinstance(value, np.ndarray):
        return f"<array {'x'.join(map(str, value.shape)) or 'scalar'} {value.dtype}>"
    if isinstance(value, bytes):
        return f"<{len(value)} bytes>"
    return repr(value)


def _short_repr(obj: Any, names: tuple[str, ...]) -> str:
    """``Type(name=value, ...)`` of the named attributes, None ones left out; arrays and bytes as their sizes."""
    parts = [f"{name}={_value_repr(getattr(obj, name))}" for name in names if getattr(obj, name) is not None]
    return f"{type(obj).__name__}({', '.join(parts)})"


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class FilterResult:
    """Putative matches separated into true and false ones (``filter``).

    Attributes
    ----------
    n_matches, n_inliers : int
        Putative matches N and those kept as true K.
    src, dst : (N, D) float64
        The putative matches as sent.
    inliers : (K,) int64
        Ascending indices into ``src`` / ``dst`` of the true matches; see :attr:`inlier_mask`.
    scores : (N,) float64
        Confidence of every match, in [0, 1].
    transform : Transform
        The estimated map from ``src`` space to ``dst`` space, evaluable locally.
    converged : bool
    reason : str or None
        Why ``converged`` is False: one of the service's reason codes (its OpenAPI schema lists them with
        their meaning, under ``reason``'s ``x-reasons``), else None.
    sigma : float or None
        Residual scale of the true matches, in ``dst`` units.
    n_iter : int or None
        Re-weighting iterations the estimator ran.
    method : str or None
        The estimator that ran.
    seed : int or None
    timings_ms : Mapping[str, float]
    """

    n_matches: int
    n_inliers: int
    src: np.ndarray
    dst: np.ndarray
    inliers: np.ndarray
    scores: np.ndarray
    transform: Transform
    converged: bool
    reason: str | None = None
    sigma: float | None = None
    n_iter: int | None = None
    method: str | None = None
    seed: int | None = None
    timings_ms: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def inlier_mask(self) -> np.ndarray:
        """(N,) bool, True at the true matches."""
        mask = np.zeros(self.n_matches, dtype=bool)
        mask[self.inliers] = True
        return mask

    def __repr__(self) -> str:
        return _short_repr(self, ("n_matches", "n_inliers", "converged", "reason", "method", "sigma", "n_iter", "seed",
                                  "transform"))

    @classmethod
    def from_json(cls, data: Any, *, src: Any, dst: Any) -> FilterResult:
        """Read a filter result; ``src`` / ``dst`` are the points that were sent."""
        base = MatchResult.from_json(data, src=src, dst=dst)
        sigma = data.get("sigma")
        n_iter = data.get("n_iter")
        return cls(n_matches=base.n_matches, n_inliers=base.n_inliers, src=base.src, dst=base.dst,
                   inliers=base.inliers, scores=base.scores, transform=base.transform, converged=base.converged,
                   reason=base.reason, sigma=None if sigma is None else float(sigma),
                   n_iter=None if n_iter is None else int(n_iter), method=data.get("method"), seed=base.seed,
                   timings_ms=base.timings_ms)


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class RegisterResult:
    """A point-set registration (``register``): the model moved onto the target.

    Attributes
    ----------
    registered : (N, D) float64
        The model points after the transform (NaN rows where an organized scan has no point).
    correspondence : (N,) int64
        For each model point, the index of the target point it was matched to, -1 for none.
    transform : Transform
        The map from model space to target space, evaluable locally.
    converged : bool
    n_iter : int
    method : str or None
        The registration method that ran.
    seed : int or None
    reason : str or None
        Why ``converged`` is False although the method ran to its tolerance (too little support,
        a code of the service's list, see ``reason``'s ``x-reasons`` in its OpenAPI schema); None otherwise or
        when the service did not say.
    fitness : float or None
        Share of the model's points with a target point within reach of their registered position, in [0, 1]
        (None when the service did not say).
    inlier_rmse : float or None
        RMS distance of those points to their nearest target point.
    matrix : (D+1, D+1) float64 or None
        Rigid, similarity and affine methods: the map as a homogeneous matrix ``[[A, t], [0, 1]]`` in your
        units (``registered = model @ A.T + t``; a 4 x 4 pose in 3-D); None for the non-rigid ones.
    """

    registered: np.ndarray
    correspondence: np.ndarray
    transform: Transform
    converged: bool
    n_iter: int
    method: str | None = None
    seed: int | None = None
    reason: str | None = None
    fitness: float | None = None
    inlier_rmse: float | None = None
    matrix: np.ndarray | None = None

    def __repr__(self) -> str:
        return _short_repr(self, ("registered", "converged", "reason", "fitness", "n_iter", "method", "seed",
                                  "transform"))

    @classmethod
    def from_json(cls, data: Any) -> RegisterResult:
        data = _check_fields(data, ("registered", "correspondence", "transform", "converged", "n_iter"),
                             "registration result")
        transform = Transform.from_dict(data["transform"])
        rows = data["registered"]
        if isinstance(rows, list) and any(r is None for r in rows):  # an organized scan's missing pixels
            rows = [[float("nan")] * transform.dim if r is None else r for r in rows]
        registered = points_array(rows, "registered", transform.dim)
        correspondence = index_array(data["correspondence"], "correspondence")
        if len(correspondence) != len(registered):
            raise ValueError(f"registration result has {len(registered)} points but "
                             f"{len(correspondence)} correspondences")
        return cls(registered=registered, correspondence=correspondence, transform=transform,
                   converged=bool(data["converged"]), n_iter=int(data["n_iter"]), method=data.get("method"),
                   seed=None if data.get("seed") is None else int(data["seed"]),
                   reason=None if data.get("reason") is None else str(data["reason"]),
                   fitness=None if data.get("fitness") is None else float(data["fitness"]),
                   inlier_rmse=None if data.get("inlier_rmse") is None else float(data["inlier_rmse"]),
                   matrix=None if data.get("matrix") is None else homogeneous_matrix(data["matrix"], transform.dim))


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class WarpResult:
    """Image b resampled onto image a's grid (``warp``), so it overlays image a.

    Attributes
    ----------
    image : (H_a, W_a) or (H_a, W_a, C) array
        The warped image, indexed ``[row, col]``; colour channels RGB(A) when decoded from PNG.
    media_type : str
        The media type the service answered with (e.g. ``"image/png"``).
    content : bytes
        The encoded bytes as received, e.g. to save to disk unchanged.
    """

    image: np.ndarray
    media_type: str
    content: bytes

    def __repr__(self) -> str:
        return _short_repr(self, ("image", "media_type", "content"))


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class ConfidenceResult:
    """How well the match's flow is supported at each pixel of image a (``confidence``).

    Attributes
    ----------
    confidence : (H_a, W_a) float32
        In [0, 1]: about 1 where the flow follows the images, 0 where it is only extrapolated.
    media_type : str
        The media type the service answered with.
    content : bytes
        The encoded bytes as received (``.npy`` or the grey PNG).
    """

    confidence: np.ndarray
    media_type: str
    content: bytes

    def __repr__(self) -> str:
        return _short_repr(self, ("confidence", "media_type", "content"))


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class FlowResult:
    """Dense forward flow from image a to image b (``flow``).

    Attributes
    ----------
    flow : (H_a, W_a, 2) float32
        ``flow[r, c] = f((c, r)) - (c, r)``, components (dx, dy).
    media_type : str
        The media type the service answered with.
    content : bytes
        The encoded bytes as received (``.npy`` or ``.flo``), e.g. to save unchanged.
    """

    flow: np.ndarray
    media_type: str
    content: bytes

    def __repr__(self) -> str:
        return _short_repr(self, ("flow", "media_type", "content"))


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Health:
    """Liveness and readiness of the service (``/livez``, ``/readyz``).

    Attributes
    ----------
    live : bool
        The process answers.
    ready : bool
        It accepts work now (False while the pool starts or stops).
    detail : Mapping[str, Any]
        The readiness document as the service sent it (empty when it was not JSON).
    """

    live: bool
    ready: bool
    detail: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class PairOutcome(Generic[T]):
    """One finished pair of ``match_many``: either ``result`` or ``error`` is set.

    Attributes
    ----------
    key : Hashable
        The pair's key in the mapping passed to ``match_many``, else its position in the iterable.
    result : MatchResult or None
    error : Exception or None
        An :class:`~reglib_client.ApiError` from the service, or the error reading the pair's images.
    """

    key: Hashable
    result: T | None = None
    error: BaseException | None = None

    @property
    def ok(self) -> bool:
        """True when the pair gave a result."""
        return self.error is None
