"""The transformation as a value: a Gaussian-kernel warp with an optional global linear part.

A :class:`KernelWarp` maps points of image a (the model, ``src``) into image b (the target,
``dst``). It is evaluable on any points, not only those it was estimated from, and has an exact
JSON round trip (``to_dict`` / ``from_dict``) in the form fixed by CONTRACTS.md::

    f(x) = dst_mean + dst_scale * g((x - src_mean) / src_scale)
    g(u) = L(u) + sum_m exp(-beta |u - c_m|^2) w_m

where L is the identity, an affine map ``u -> A u + t`` (matrix (D, D+1) = [A | t]) or, in 2-D,
a homography (3, 3) acting on homogeneous coordinates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ._validation import as_points
from .errors import InputError

__all__ = ["KernelWarp", "LinearPart", "kernel_matrix", "kernel_apply"]

_CHUNK = 1 << 13  # rows per block of the Jacobian (keeps its K x M x D temporaries small)
# Elements of the (rows, M) kernel block that kernel_apply reuses: 512 KiB stays in cache and
# under the allocator's mmap threshold (a fresh multi-MiB block per chunk costs more in page
# faults than its exp).
_BLOCK_ELEMENTS = 1 << 16


# exp of arguments below about -708 underflows, and numpy's exp takes a slow path there:
# clip first. exp(-700) ~ 1e-304 stands for 0.
_EXP_FLOOR = -700.0
# float32's exp gives denormals below about -87 (a slow path too): exp(-87) ~ 2e-38 stands for 0.
_EXP_FLOOR32 = -87.0


def _augmented(points: np.ndarray, centers: np.ndarray, beta: float) -> tuple[np.ndarray, np.ndarray]:
    """(K, D+2) and (D+2, M) factors whose product is ``-beta |p - c|^2``.

    ``-beta |p - c|^2 = 2 beta p.c - beta |c|^2 - beta |p|^2``: one matrix product gives all of
    it, instead of a product and two broadcast passes over the (K, M) result.
    """
    k, d = points.shape
    left = np.empty((k, d + 2))
    left[:, :d] = points
    left[:, d] = 1.0
    left[:, d + 1] = (points * points).sum(1) * -beta
    right = np.empty((d + 2, len(centers)))
    right[:d] = centers.T * (2.0 * beta)
    right[d] = (centers * centers).sum(1) * -beta
    right[d + 1] = 1.0
    return left, right


def _exp_kernel(left: np.ndarray, right: np.ndarray, out: np.ndarray, single: np.ndarray | None = None) -> np.ndarray:
    """exp(left @ right) into ``out``; the exp in float32 through ``single`` (same shape) when given."""
    np.matmul(left, right, out=out)
    # Rounding can leave +1e-16 where p == c; far pairs are clipped above the underflow.
    if single is None:
        np.clip(out, _EXP_FLOOR, 0.0, out=out)
        return np.exp(out, out=out)
    np.clip(out, _EXP_FLOOR32, 0.0, out=single)
    np.exp(single, out=single)
    out[...] = single
    return out


def kernel_matrix(points: np.ndarray, centers: np.ndarray, beta: float, out: np.ndarray | None = None, *,
                  single_exp: bool = False) -> np.ndarray:
    """Gaussian kernel ``exp(-beta |p - c|^2)`` between rows of ``points`` (K, D) and ``centers`` (M, D).

    Uses ``|p|^2 + |c|^2 - 2 p.c`` (one matrix product) so no (K, M, D) temporary is made;
    written into ``out`` (K, M) when given. With ``single_exp`` the exp is taken in float32 (the
    exponent is formed, and the result returned, in float64): each value in [0, 1] within 2e-7 of
    the exact one, and faster, since numpy's float64 exp has no SIMD path below AVX-512.
    The estimators' inner loops use it; a transform's evaluation does not.
    """
    left, right = _augmented(points, centers, beta)
    out = np.empty((len(points), len(centers))) if out is None else out
    return _exp_kernel(left, right, out, np.empty(out.shape, np.float32) if single_exp else None)


def kernel_apply(points: np.ndarray, centers: np.ndarray, beta: float, weights: np.ndarray,
                 out: np.ndarray, *, single_exp: bool = False) -> np.ndarray:
    """Add the kernel field ``kernel_matrix(points, centers, beta) @ weights`` to ``out`` (K, D).

    Evaluated in blocks of rows in one reused buffer, so memory is O(M) whatever K, and each
    entry is computed as in :func:`kernel_matrix` (``single_exp`` as there).
    """
    k, m = len(points), len(centers)
    if not k or not m:
        return out
    rows = min(k, max(16, _BLOCK_ELEMENTS // m))
    buf = np.empty((rows, m))
    single = np.empty((rows, m), np.float32) if single_exp else None
    left, right = _augmented(points, centers, beta)
    for start in range(0, k, rows):
        block = left[start:start + rows]
        b = _exp_kernel(block, right, buf[:len(block)], None if single is None else single[:len(block)])
        out[start:start + rows] += b @ weights
    return out


@dataclass(frozen=True, eq=False)
class LinearPart:
    """Global linear part of a warp, in normalized coordinates.

    ``kind="affine"``: ``matrix`` is (D, D+1) = [A | t], u -> A u + t.
    ``kind="homography"``: ``matrix`` is (3, 3), 2-D only, u -> dehomogenize(H [u, 1]).
    """

    kind: Literal["affine", "homography"]
    matrix: np.ndarray

    def apply(self, u: np.ndarray) -> np.ndarray:
        m = self.matrix
        if self.kind == "affine":
            return u @ m[:, :-1].T + m[:, -1]
        q = u @ m[:, :2].T + m[:, 2]
        w = q[:, 2:3]
        # Points on or behind the horizon line have no image; keep them finite and far away.
        w = np.where(np.abs(w) < 1e-12, np.copysign(1e-12, w + 0.0), w)
        return q[:, :2] / w

    def jacobian(self, u: np.ndarray) -> np.ndarray:
        """(K, D, D) derivative of the linear part at ``u``."""
        m = self.matrix
        if self.kind == "affine":
            return np.broadcast_to(m[:, :-1], (len(u),) + m[:, :-1].shape).copy()
        q = u @ m[:, :2].T + m[:, 2]
        w = q[:, 2]
        w = np.where(np.abs(w) < 1e-12, 1e-12, w)
        # d(q_i / w)/du_j = (H_ij w - q_i H_2j) / w^2
        jac = (m[None, :2, :2] * w[:, None, None] - q[:, :2, None] * m[None, 2:3, :2]) / (w * w)[:, None, None]
        return jac


@dataclass(frozen=True, eq=False)
class KernelWarp:
    """A smooth non-rigid transformation ``f: src space -> dst space`` (see module docstring).

    Attributes mirror the JSON form of CONTRACTS.md. Build one with an estimator
    (:func:`reglib.filter_matches`, :func:`reglib.register_points`, :func:`reglib.match_images`),
    with :meth:`identity`, or from JSON with :meth:`from_dict`.

    Examples
    --------
    >>> import numpy as np
    >>> t = KernelWarp.identity(2)
    >>> t(np.array([[1.0, 2.0]]))
    array([[1., 2.]])
    >>> KernelWarp.from_dict(t.to_dict())(np.array([[3.0, 4.0]]))
    array([[3., 4.]])
    """

    dim: int
    src_mean: np.ndarray
    src_scale: float
    dst_mean: np.ndarray
    dst_scale: float
    linear: LinearPart | None
    beta: float
    centers: np.ndarray
    weights: np.ndarray

    def __post_init__(self) -> None:
        for name in ("src_mean", "dst_mean", "centers", "weights"):
            arr = np.array(getattr(self, name), dtype=np.float64)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if self.linear is not None:
            self.linear.matrix.setflags(write=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def identity(cls, dim: int = 2) -> KernelWarp:
        """The identity map in ``dim`` dimensions (no centres, no linear part)."""
        if dim not in (2, 3):
            raise InputError(f"`dim` must be 2 or 3, got {dim!r}")
        return cls(dim=dim, src_mean=np.zeros(dim), src_scale=1.0, dst_mean=np.zeros(dim), dst_scale=1.0,
                   linear=None, beta=1.0, centers=np.zeros((0, dim)), weights=np.zeros((0, dim)))

    def source_shifted(self, offset: Any) -> KernelWarp:
        """The map ``p -> f(p - offset)``: the same transform on a source frame whose origin moved by ``offset``.

        Exact, for every kind of linear part: the map works on normalized source coordinates
        ``(p - src_mean) / src_scale``, so only ``src_mean`` moves.

        Examples
        --------
        >>> import numpy as np
        >>> f = KernelWarp.identity(2)
        >>> f.source_shifted([3.0, 3.0])(np.array([[10.0, 20.0]]))
        array([[ 7., 17.]])
        """
        shift = np.broadcast_to(np.asarray(offset, dtype=np.float64), (self.dim,))
        return KernelWarp(dim=self.dim, src_mean=self.src_mean + shift, src_scale=self.src_scale,
                          dst_mean=self.dst_mean, dst_scale=self.dst_scale, linear=self.linear, beta=self.beta,
                          centers=self.centers, weights=self.weights)

    def rescaled(self, src_factor: float, dst_factor: float) -> KernelWarp:
        """The same map between copies of src and dst space resized by ``src_factor`` and ``dst_factor``.

        Pixel coordinates follow the centre convention of CONTRACTS.md: a resized copy's pixel x'
        is ``s (x + 0.5) - 0.5`` (OpenCV's ``resize``), so the result g satisfies
        ``g(s_a (x + 0.5) - 0.5) = s_b (f(x) + 0.5) - 0.5`` exactly. 2-D only; factors > 0.

        Examples
        --------
        >>> import numpy as np
        >>> f = KernelWarp.identity(2)
        >>> f.rescaled(0.5, 0.5)(np.array([[0.5, 1.5]]))
        array([[0.5, 1.5]])
        """
        if self.dim != 2:
            raise InputError("`rescaled` applies to 2-D (image) transforms")
        for name, value in (("src_factor", src_factor), ("dst_factor", dst_factor)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise InputError(f"`{name}` must be a positive finite number, got {value!r}")
        if src_factor == 1.0 and dst_factor == 1.0:
            return self
        lin = None if self.linear is None else LinearPart(kind=self.linear.kind, matrix=self.linear.matrix.copy())
        return KernelWarp(dim=2,
                          src_mean=src_factor * (self.src_mean + 0.5) - 0.5, src_scale=src_factor * self.src_scale,
                          dst_mean=dst_factor * (self.dst_mean + 0.5) - 0.5, dst_scale=dst_factor * self.dst_scale,
                          linear=lin, beta=self.beta, centers=self.centers, weights=self.weights)

    # ------------------------------------------------------------------ evaluation
    @property
    def n_centers(self) -> int:
        """Number of kernel basis functions M."""
        return len(self.centers)

    def _g(self, u: np.ndarray) -> np.ndarray:
        out = u.copy() if self.linear is None else self.linear.apply(u)
        if self.n_centers:
            kernel_apply(u, self.centers, self.beta, self.weights, out)
        return out

    def __call__(self, points: Any) -> np.ndarray:
        """Map ``points`` (K, D) array_like of (x, y[, z]) to (K, D) float64 in dst space."""
        pts = as_points(points, "points", dims=(self.dim,))
        # kernel_apply works in blocks of rows itself: no (K, M) array is made whatever K.
        return self.dst_mean + self.dst_scale * self._g((pts - self.src_mean) / self.src_scale)

    def jacobian(self, points: Any) -> np.ndarray:
        """(K, D, D) derivative df/dx at ``points``; entry [k, i, j] = d f_i / d x_j."""
        pts = as_points(points, "points", dims=(self.dim,))
        jac = np.empty((len(pts), self.dim, self.dim))
        ratio = self.dst_scale / self.src_scale
        for start in range(0, len(pts), _CHUNK):
            u = (pts[start:start + _CHUNK] - self.src_mean) / self.src_scale
            if self.linear is None:
                j = np.broadcast_to(np.eye(self.dim), (len(u), self.dim, self.dim)).copy()
            else:
                j = self.linear.jacobian(u)
            if self.n_centers:
                k = kernel_matrix(u, self.centers, self.beta)  # (K, M)
                # d/du_j of sum_m k_m w_mi = sum_m k_m w_mi (-2 beta) (u_j - c_mj)
                kw = k[:, :, None] * self.weights[None, :, :]  # (K, M, D) is K*M*D; chunked, so bounded
                j += -2.0 * self.beta * (np.einsum("kmi,kj->kij", kw, u) - np.einsum("kmi,mj->kij", kw, self.centers))
            jac[start:start + _CHUNK] = j * ratio
        return jac

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict in the form of CONTRACTS.md (plain floats, nested lists)."""
        return {
            "type": "kernel_warp",
            "version": 1,
            "dim": int(self.dim),
            "src_mean": [float(v) for v in self.src_mean],
            "src_scale": float(self.src_scale),
            "dst_mean": [float(v) for v in self.dst_mean],
            "dst_scale": float(self.dst_scale),
            "linear": None if self.linear is None else {"kind": self.linear.kind,
                                                        "matrix": self.linear.matrix.tolist()},
            "beta": float(self.beta),
            "centers": self.centers.tolist(),
            "weights": self.weights.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Any) -> KernelWarp:
        """Rebuild a warp from :meth:`to_dict`'s form; malformed fields raise ``InputError`` naming them."""
        dim = _checked_dim(data)
        centers, weights = _kernel_fields(data, dim)
        linear = _linear_field(data["linear"], dim)
        return cls(dim=dim, src_mean=_vector_field(data, "src_mean", dim), src_scale=_positive_field(data, "src_scale"),
                   dst_mean=_vector_field(data, "dst_mean", dim), dst_scale=_positive_field(data, "dst_scale"),
                   linear=linear, beta=_positive_field(data, "beta"), centers=centers, weights=weights)

    def __repr__(self) -> str:
        lin = "none" if self.linear is None else self.linear.kind
        return f"KernelWarp(dim={self.dim}, linear={lin}, n_centers={self.n_centers}, beta={self.beta:g})"


_JSON_FIELDS = ("type", "version", "dim", "src_mean", "src_scale", "dst_mean", "dst_scale", "linear", "beta",
                "centers", "weights")


def _checked_dim(data: Any) -> int:
    """The ``dim`` of a transform's JSON form, once it is an object with every field, of type kernel_warp, version 1."""
    if not isinstance(data, dict):
        raise InputError(f"transform must be a JSON object, got {type(data).__name__}")
    missing = [k for k in _JSON_FIELDS if k not in data]
    if missing:
        raise InputError(f"transform is missing field(s) {missing}")
    if data["type"] != "kernel_warp":
        raise InputError(f"transform `type` must be 'kernel_warp', got {data['type']!r}")
    if data["version"] != 1 or isinstance(data["version"], bool):
        raise InputError(f"transform `version` must be 1, got {data['version']!r}")
    dim = data["dim"]
    if isinstance(dim, bool) or dim not in (2, 3):
        raise InputError(f"transform `dim` must be 2 or 3, got {dim!r}")
    return dim


def _kernel_fields(data: dict[str, Any], dim: int) -> tuple[np.ndarray, np.ndarray]:
    """``centers`` and ``weights``, (M, dim) each; empty lists are M = 0."""
    centers = _finite_array(data["centers"], "centers")
    weights = _finite_array(data["weights"], "weights")
    if centers.size == 0:
        centers = centers.reshape(0, dim)
    if weights.size == 0:
        weights = weights.reshape(0, dim)
    if centers.ndim != 2 or centers.shape[1] != dim:
        raise InputError(f"transform `centers` must have shape (M, {dim}), got {centers.shape}")
    if weights.shape != centers.shape:
        raise InputError(f"transform `weights` must have the shape of `centers` {centers.shape}, got {weights.shape}")
    return centers, weights


def _linear_field(linear: Any, dim: int) -> LinearPart | None:
    """The ``linear`` field: null, or an affine (dim, dim + 1) or, in 2-D, a homography (3, 3) matrix."""
    if linear is None:
        return None
    if not isinstance(linear, dict) or linear.get("kind") not in ("affine", "homography"):
        raise InputError("transform `linear` must be null or {'kind': 'affine'|'homography', 'matrix': ...}")
    mat = _finite_array(linear.get("matrix"), "linear.matrix")
    want = (dim, dim + 1) if linear["kind"] == "affine" else (3, 3)
    if linear["kind"] == "homography" and dim != 2:
        raise InputError("transform `linear.kind` 'homography' needs dim 2")
    if mat.shape != want:
        raise InputError(f"transform `linear.matrix` must have shape {want}, got {mat.shape}")
    return LinearPart(kind=linear["kind"], matrix=mat)


def _vector_field(data: dict[str, Any], key: str, dim: int) -> np.ndarray:
    """The field ``key``: ``dim`` finite numbers."""
    arr = _finite_array(data[key], key)
    if arr.shape != (dim,):
        raise InputError(f"transform `{key}` must have {dim} numbers, got shape {arr.shape}")
    return arr


def _positive_field(data: dict[str, Any], key: str) -> float:
    """The field ``key``: a positive finite number (not a bool)."""
    val = data[key]
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val) or val <= 0:
        raise InputError(f"transform `{key}` must be a positive finite number, got {val!r}")
    return float(val)


def _finite_array(value: Any, key: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"transform `{key}` must be numbers (nested lists), got {type(value).__name__}") from None
    if not np.isfinite(arr).all():
        raise InputError(f"transform `{key}` must hold only finite numbers")
    return arr
