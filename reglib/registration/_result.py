"""``Registration``: what :func:`reglib.register_points` found, and its one JSON form; ``WarpFit``:
what a method fitted in normalized coordinates returns before it is wrapped."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._json import as_array, as_bool, as_float, as_int, as_reason, as_seed, require_fields
from .._repr import short_repr
from .._transforms import KernelWarp
from .._verdict import Reason
from ..errors import InputError
from ..io import PointCloud
from ..robust import Model

__all__ = ["Registration", "WarpFit"]

_WHAT = "registration"
_KEYS = ("registered", "correspondence", "transform", "converged", "n_iter", "method", "seed")


@dataclass(frozen=True, eq=False)
class WarpFit:
    """The answer of a method that works in normalized coordinates ("l2e", the CPD family).

    :func:`reglib.register_points` maps it back to the caller's coordinates (its
    :class:`~reglib.robust.Normalization`), as :class:`~reglib.registration._rigid.RigidFit` is
    for the rigid methods, which work in the caller's units.

    Attributes
    ----------
    model : reglib.robust.Model
        The map from the normalized model to the normalized target.
    n_iter : int
        Rounds or iterations the method ran.
    converged : bool
        The method stopped by its own tolerance, not by its cap.
    reach : float
        Distance (normalized target units) within which a moved model point counts as
        corresponding to its nearest target point.
    """

    model: Model
    n_iter: int
    converged: bool
    reach: float
    reason: Reason | None = None  # why ``converged`` is False, when the method measured its own fit


@dataclass(frozen=True, eq=False)
class Registration:
    """What :func:`register_points` found.

    Attributes
    ----------
    transform : KernelWarp
        Maps model space into target space; callable on any (K, D) points. Rigid, similarity and
        affine methods give a warp with an affine linear part ``[A | t]`` in the caller's units (means
        zero, scales 1) and no centers (same JSON form).
    correspondence : (N,) int ndarray
        For each model point, the index of the nearest target point to its registered position,
        or -1 when none is within reach (three times the final residual scale). For an organized
        (H, W, 3) model, N = H * W in row-major order, -1 where the scan has no point.
    n_iter : int
        ``l2e``: describe-match-estimate rounds run; the other methods: their iterations.
    converged : bool
        ``l2e``: the last round moved no model point by more than 1e-3 (normalized units);
        the others: stopped by their tolerance before their iteration cap.
    registered : (N, D) float64 ndarray
        The model moved by ``transform`` (NaN rows where an organized model has no point).
    method : str
        The method that ran.
    seed : int or None
        The integer seed given as ``rng``, recorded for reproduction.
    reason : str or None
        Why ``converged`` is False although the method ran to its tolerance: the data support
        the answer too little (one of :data:`reglib.registration.REGISTRATION_REASONS`,
        e.g. ``small_overlap``); None otherwise.
    fitness : float or None
        Share of the model's points with a target point within 3 target spacings (its median
        nearest-neighbour distance) of their registered position, in [0, 1] (Open3D's ``fitness``, with a
        reach the target sets); None only for a form read back without it.
    inlier_rmse : float or None
        RMS distance of those points to their nearest target point, in the target's units (0 with none).
    matrix : (D + 1, D + 1) float64 ndarray or None
        For the rigid, similarity and affine methods, the map of ``transform`` as a homogeneous
        matrix ``[[A, t], [0, 1]]`` in the caller's units: ``registered = model @ A.T + t`` (a
        4 x 4 pose for 3-D sets, 3 x 3 for 2-D ones); None for the non-rigid methods.
    """

    transform: KernelWarp
    correspondence: np.ndarray
    n_iter: int
    converged: bool
    registered: np.ndarray
    method: str = "l2e"
    seed: int | None = None
    reason: Reason | None = None
    fitness: float | None = None
    inlier_rmse: float | None = None
    matrix: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """The registration JSON of CONTRACTS.md (NaN coordinates of an organized scan as null); ``matrix``
        is null for a non-rigid method."""
        reg = self.registered
        rows: list[Any] = reg.tolist()
        if not np.isfinite(reg).all():
            rows = [None if not np.isfinite(r).all() else row for r, row in zip(reg, rows, strict=True)]
        out = {"registered": rows, "correspondence": [int(v) for v in self.correspondence],
               "transform": self.transform.to_dict(), "converged": bool(self.converged), "n_iter": int(self.n_iter),
               "method": self.method, "seed": self.seed, "reason": self.reason,
               "matrix": None if self.matrix is None else np.asarray(self.matrix, dtype=np.float64).tolist()}
        if self.fitness is not None:  # (the contract's optional fit figures)
            out["fitness"] = float(self.fitness)
            out["inlier_rmse"] = float(self.inlier_rmse or 0.0)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> Registration:
        """Rebuild a registration from :meth:`to_dict`'s form (extra keys such as ``timings_ms`` are ignored;
        ``reason`` and ``matrix`` are optional, null when absent).

        Raises
        ------
        InputError
            A missing or malformed field, named.
        """
        d = require_fields(data, _KEYS, _WHAT)
        transform = KernelWarp.from_dict(d["transform"])
        rows = d["registered"]
        if not isinstance(rows, list):
            raise InputError(f"{_WHAT} `registered` must be a list of points")
        dim = transform.dim
        try:
            registered = np.array([[np.nan] * dim if r is None else r for r in rows], dtype=np.float64).reshape(-1, dim)
        except (TypeError, ValueError):
            raise InputError(f"{_WHAT} `registered` must be (N, {dim}) numbers or null rows") from None
        corr = d["correspondence"]
        if not isinstance(corr, list) or len(corr) != len(registered) or \
                any(isinstance(v, bool) or not isinstance(v, int) or v < -1 for v in corr):
            raise InputError(f"{_WHAT} `correspondence` must be {len(registered)} integers >= -1")
        if not isinstance(d["method"], str):
            raise InputError(f"{_WHAT} `method` must be a string, got {d['method']!r}")
        reason = as_reason(d.get("reason"), "reason", _WHAT)
        fitness = None if d.get("fitness") is None else as_float(d["fitness"], "fitness", _WHAT)
        if fitness is not None and not 0.0 <= fitness <= 1.0:
            raise InputError(f"{_WHAT} `fitness` must be in [0, 1], got {fitness!r}")
        rmse = None if d.get("inlier_rmse") is None else as_float(d["inlier_rmse"], "inlier_rmse", _WHAT)
        matrix = None if d.get("matrix") is None else _homogeneous_field(d["matrix"], dim)
        return cls(transform=transform, correspondence=np.asarray(corr, dtype=np.intp),
                   n_iter=as_int(d["n_iter"], "n_iter", _WHAT), converged=as_bool(d["converged"], "converged", _WHAT),
                   registered=registered, method=d["method"], seed=as_seed(d["seed"], "seed", _WHAT),
                   reason=reason, fitness=fitness, inlier_rmse=rmse, matrix=matrix)

    def registered_cloud(self, model: PointCloud) -> PointCloud:
        """The ``model`` cloud where this registration puts it, its colours and normals kept.

        The points are ``registered`` (an organized model's (H, W, 3) grid stays a grid, NaN where
        it has no point); the colours are the model's (a registration moves points, not their
        colour); the normals are turned by the map, as normals go: the inverse transpose of its
        Jacobian, made unit length again (for a rigid answer, its rotation).

        Parameters
        ----------
        model : PointCloud
            The model this registration was found for (what :func:`reglib.io.read_point_cloud` gave).

        Raises
        ------
        InputError
            ``model`` is not a PointCloud, has another number of points than ``registered``, or
            normals not shaped like its points.

        Examples
        --------
        >>> import numpy as np
        >>> from reglib import register_points
        >>> from reglib.io import PointCloud
        >>> rng = np.random.default_rng(0)
        >>> pts = rng.normal(size=(50, 3)) * [3.0, 2.0, 1.0]
        >>> cloud = PointCloud(points=pts, colors=np.full((50, 3), 0.5), normals=np.tile([0.0, 0.0, 1.0], (50, 1)))
        >>> res = register_points(cloud, pts[:, [1, 0, 2]] * [-1.0, 1.0, 1.0], method="cpd-rigid", rng=0)
        >>> moved = res.registered_cloud(cloud)
        >>> bool(np.allclose(moved.points, res.registered)), moved.colors[0].tolist()
        (True, [0.5, 0.5, 0.5])
        """
        if not isinstance(model, PointCloud):
            raise InputError(f"`model` must be a reglib.io.PointCloud, got {type(model).__name__}")
        shape = np.shape(model.points)
        dim = self.registered.shape[1]
        if int(np.prod(shape[:-1])) != len(self.registered) or shape[-1] != dim:
            raise InputError(f"`model` has points of shape {shape}; this registration moved {len(self.registered)} "
                             f"points of dimension {dim}")
        normals = None
        if model.normals is not None:
            if np.shape(model.normals) != shape:
                raise InputError(f"`model.normals` must have the shape of its points, {shape}, "
                                 f"got {np.shape(model.normals)}")
            normals = _turned_normals(self.transform, np.asarray(model.points, dtype=np.float64).reshape(-1, dim),
                                      np.asarray(model.normals, dtype=np.float64).reshape(-1, dim)).reshape(shape)
        return PointCloud(points=self.registered.reshape(shape), colors=model.colors, normals=normals)

    @property
    def n_matched(self) -> int:
        """Model points with a target point within reach (``correspondence >= 0``)."""
        return int(np.count_nonzero(self.correspondence >= 0))

    def __repr__(self) -> str:
        return short_repr(self, ("method", "registered", "n_matched", "converged", "reason", "n_iter", "fitness",
                                 "inlier_rmse", "matrix", "seed", "transform"))


def _homogeneous_field(value: Any, dim: int) -> np.ndarray:
    """The ``matrix`` field: finite (D + 1, D + 1) with last row (0, ..., 0, 1)."""
    m = as_array(value, "matrix", _WHAT, shape=(dim + 1, dim + 1))
    if not np.array_equal(m[dim], np.eye(dim + 1)[dim]):
        raise InputError(f"{_WHAT} `matrix` must be homogeneous, its last row (0, ..., 0, 1); got {m[dim].tolist()}")
    return m


def _turned_normals(transform: KernelWarp, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``normals`` at ``points`` after ``transform``: the inverse transpose of its Jacobian applied, unit length
    again (NaN rows, an organized scan's holes, stay NaN; a zero normal stays zero)."""
    out = np.full_like(normals, np.nan)
    seen = np.isfinite(points).all(axis=1)
    if seen.any():
        inverse = np.linalg.pinv(transform.jacobian(points[seen]))  # pinv: a folding map has singular Jacobians
        turned = np.einsum("kji,kj->ki", inverse, normals[seen])
        length = np.linalg.norm(turned, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[seen] = np.where(length > 0, turned / length, turned)
    return out
