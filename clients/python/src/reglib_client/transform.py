"""Evaluate the service's transform JSON locally, with numpy only.

The JSON form and the formula are those of the project's CONTRACTS.md::

    {"type": "kernel_warp", "version": 1, "dim": D,
     "src_mean": [..D], "src_scale": s_x, "dst_mean": [..D], "dst_scale": s_y,
     "linear": null | {"kind": "affine", "matrix": (D, D+1)} | {"kind": "homography", "matrix": (3, 3)},
     "beta": beta, "centers": (M, D), "weights": (M, D)}

    f(x) = dst_mean + dst_scale * g((x - src_mean) / src_scale)
    g(u) = L(u) + sum_m exp(-beta |u - c_m|^2) w_m

L is the identity (``linear`` null), ``u -> A u + t`` for an affine matrix [A | t], or, in 2-D,
the projective map of a homography. ``f`` maps points of image a (the model, ``src``) to image b
(the target, ``dst``); points are (x, y[, z]) with x the column.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

__all__ = ["Transform", "homogeneous_matrix"]

_CHUNK = 1 << 14  # points per block, so the (K, M) kernel block stays small


def homogeneous_matrix(value: Any, dim: int) -> np.ndarray:
    """A registration's ``matrix``: finite (D+1, D+1) ``[[A, t], [0, 1]]`` of a rigid, similarity or affine map."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"`matrix` must be numbers (nested lists), got {type(value).__name__}") from None
    last = np.eye(dim + 1)[dim]
    if arr.shape != (dim + 1, dim + 1) or not np.isfinite(arr).all() or not np.array_equal(arr[dim], last):
        raise ValueError(f"`matrix` must be a finite ({dim + 1}, {dim + 1}) homogeneous matrix, last row (0, ..., 1)")
    arr.setflags(write=False)
    return arr


def _array(value: Any, key: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"transform `{key}` must be numbers (nested lists), got {type(value).__name__}") from None
    if not np.isfinite(arr).all():
        raise ValueError(f"transform `{key}` must hold only finite numbers")
    arr.setflags(write=False)
    return arr


def _positive(data: dict[str, Any], key: str) -> float:
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"transform `{key}` must be a positive finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False, slots=True)
class Transform:
    """A transformation returned by the service, evaluable at any points without the server.

    Build one with :meth:`from_dict`; ``to_dict()`` gives the JSON back unchanged. Calling it maps
    (K, D) points of image a to image b.

    Examples
    --------
    >>> t = Transform.from_dict({"type": "kernel_warp", "version": 1, "dim": 2,
    ...     "src_mean": [0, 0], "src_scale": 1, "dst_mean": [5, 0], "dst_scale": 1,
    ...     "linear": None, "beta": 1, "centers": [], "weights": []})
    >>> t([[1.0, 2.0]])
    array([[6., 2.]])
    """

    dim: int
    src_mean: np.ndarray
    src_scale: float
    dst_mean: np.ndarray
    dst_scale: float
    linear_kind: Literal["affine", "homography"] | None
    linear_matrix: np.ndarray | None
    beta: float
    centers: np.ndarray
    weights: np.ndarray
    _json: dict[str, Any]

    @classmethod
    def from_dict(cls, data: Any) -> Transform:
        """Read the transform JSON (see the module docstring); a malformed field is a ``ValueError`` naming it."""
        if not isinstance(data, dict):
            raise ValueError(f"transform must be a JSON object, got {type(data).__name__}")
        required = ("type", "version", "dim", "src_mean", "src_scale", "dst_mean", "dst_scale", "linear", "beta",
                    "centers", "weights")
        missing = [key for key in required if key not in data]
        if missing:
            raise ValueError(f"transform is missing field(s) {missing}")
        if data["type"] != "kernel_warp":
            raise ValueError(f"transform `type` must be 'kernel_warp', got {data['type']!r}")
        if isinstance(data["version"], bool) or data["version"] != 1:
            raise ValueError(f"transform `version` must be 1, got {data['version']!r}")
        dim = data["dim"]
        if isinstance(dim, bool) or dim not in (2, 3):
            raise ValueError(f"transform `dim` must be 2 or 3, got {dim!r}")
        dim = int(dim)
        means = {}
        for key in ("src_mean", "dst_mean"):
            means[key] = _array(data[key], key)
            if means[key].shape != (dim,):
                raise ValueError(f"transform `{key}` must have {dim} numbers, got shape {means[key].shape}")
        centers = _array(data["centers"], "centers")
        weights = _array(data["weights"], "weights")
        if centers.size == 0:
            centers = np.zeros((0, dim))
        if weights.size == 0:
            weights = np.zeros((0, dim))
        if centers.ndim != 2 or centers.shape[1] != dim:
            raise ValueError(f"transform `centers` must have shape (M, {dim}), got {centers.shape}")
        if weights.shape != centers.shape:
            raise ValueError(f"transform `weights` must have the shape of `centers` {centers.shape}, "
                             f"got {weights.shape}")
        linear = data["linear"]
        kind = None
        matrix = None
        if linear is not None:
            if not isinstance(linear, dict) or linear.get("kind") not in ("affine", "homography"):
                raise ValueError("transform `linear` must be null or {'kind': 'affine' | 'homography', 'matrix': ...}")
            kind = linear["kind"]
            if kind == "homography" and dim != 2:
                raise ValueError("transform `linear.kind` 'homography' needs dim 2")
            matrix = _array(linear.get("matrix"), "linear.matrix")
            want = (dim, dim + 1) if kind == "affine" else (3, 3)
            if matrix.shape != want:
                raise ValueError(f"transform `linear.matrix` must have shape {want}, got {matrix.shape}")
        for arr in (centers, weights):
            arr.setflags(write=False)
        return cls(dim=dim, src_mean=means["src_mean"], src_scale=_positive(data, "src_scale"),
                   dst_mean=means["dst_mean"], dst_scale=_positive(data, "dst_scale"), linear_kind=kind,
                   linear_matrix=matrix, beta=_positive(data, "beta"), centers=centers, weights=weights,
                   _json=copy.deepcopy(data))

    def to_dict(self) -> dict[str, Any]:
        """The transform JSON as the service sent it (a fresh copy)."""
        return copy.deepcopy(self._json)

    @property
    def n_centers(self) -> int:
        """Number of kernel basis functions M."""
        return len(self.centers)

    def _linear(self, u: np.ndarray) -> np.ndarray:
        m = self.linear_matrix
        if m is None:
            return u.copy()
        if self.linear_kind == "affine":
            return u @ m[:, :-1].T + m[:, -1]
        q = u @ m[:, :2].T + m[:, 2]
        w = q[:, 2:3]
        # Points on the horizon line have no image; keep them finite and far away (as the library does).
        w = np.where(np.abs(w) < 1e-12, np.copysign(1e-12, w + 0.0), w)
        return q[:, :2] / w

    def __call__(self, points: Any) -> np.ndarray:
        """Map ``points`` (K, D) array_like of (x, y[, z]) to (K, D) float64 in image b's coordinates."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.size == 0 and pts.ndim <= 2:
            pts = pts.reshape(0, self.dim)
        if pts.ndim != 2 or pts.shape[1] != self.dim:
            raise ValueError(f"`points` must have shape (K, {self.dim}), got {pts.shape}")
        if not np.isfinite(pts).all():
            raise ValueError("`points` must hold only finite numbers")
        out = np.empty_like(pts)
        sq_centers = (self.centers * self.centers).sum(1)
        for start in range(0, len(pts), _CHUNK):
            u = (pts[start:start + _CHUNK] - self.src_mean) / self.src_scale
            g = self._linear(u)
            if self.n_centers:
                # |u - c|^2 = |u|^2 + |c|^2 - 2 u.c: no (K, M, D) temporary
                d2 = (u * u).sum(1)[:, None] + sq_centers[None, :] - 2.0 * (u @ self.centers.T)
                np.maximum(d2, 0.0, out=d2)
                g += np.exp(-self.beta * d2) @ self.weights
            out[start:start + _CHUNK] = self.dst_mean + self.dst_scale * g
        return out

    def __repr__(self) -> str:
        return (f"Transform(dim={self.dim}, linear={self.linear_kind or 'none'}, n_centers={self.n_centers}, "
                f"beta={self.beta:g})")
