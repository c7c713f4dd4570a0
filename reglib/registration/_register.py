"""``register_points``: align a model point set to a target without known correspondences.

One public function in front of every method of the table :data:`~reglib.registration._methods.METHODS`
(one module per method):

- ``"l2e"``: shape context + L2E (:mod:`reglib.registration._sc_l2e`), non-rigid;
- ``"cpd"``, ``"cpd-rigid"``, ``"cpd-affine"``: Coherent Point Drift (:mod:`reglib.registration._cpd`);
- ``"icp"``: robust point-to-point / point-to-plane ICP (:mod:`reglib.registration._icp`);
- ``"icp-hmrf"``: ICP with a hidden Markov random field over an organized scan's pixel grid
  (:mod:`reglib.registration._hmrf`);
- ``"color-gmm"``: color-assisted probabilistic registration (:mod:`reglib.registration._color_gmm`);
- ``"density-adaptive"``: registration robust to sampling density (:mod:`reglib.registration._density_adaptive`);
- ``"bayes"``: variational Bayesian registration with Student-t mixtures (:mod:`reglib.registration._bayes`);
- ``"cpd-net"``: CPD-Net, a learned coherent displacement field in one forward pass, 2-D
  (:mod:`reglib.registration._cpd_net`).

Input checks happen here, once: finite coordinates (NaN only as the missing pixels of an organized
(H, W, 3) scan), matching dimensions, enough points that are not all on one line, colors and normals
of the right shape, each given to a method that uses it (a keyword it does not use is an error; what
a :class:`~reglib.io.PointCloud` set carries and it does not use is ignored). The non-rigid and CPD
methods work in normalized coordinates; the rigid ones in the caller's units, so that their rotation
stays a rotation.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from .._validation import MAX_COORDINATE, as_colors, as_options, as_points, as_rng, seed_of
from .._verdict import polish_reason, settled_reason
from ..errors import InputError
from ..io import PointCloud
from ..robust import Normalization, single_thread_blas
from ._methods import METHODS, RIGID_METHODS, Method, MethodName, method_spec, methods_taking, options_class
from ._polish import polish_shift
from ._result import Registration, WarpFit
from ._rigid import RigidFit, caller_matrix, homogeneous, rigid_warp
from ._support import fit_figures, fit_reach

__all__ = ["register_points", "METHODS", "RIGID_METHODS", "options_class"]


def register_points(model: ArrayLike | PointCloud, target: ArrayLike | PointCloud, *, method: MethodName = "l2e",
                    options: Any = None, rng: int | np.random.Generator | None = None, model_colors: Any = None,
                    target_colors: Any = None, model_normals: Any = None,
                    target_normals: Any = None) -> Registration:
    """Register ``model`` onto ``target``: find a map model space -> target space.

    Parameters
    ----------
    model : (N, D) array_like, (H, W, 3) for an organized scan, or PointCloud
        Points (x, y[, z]) to move, D in {2, 3}. An organized scan (a depth camera's grid) may
        hold NaN where nothing was seen; ``"icp-hmrf"`` needs one. A :class:`~reglib.io.PointCloud`
        gives its ``points`` (a grid stays a grid) and the colors and normals it carries where
        ``method`` uses them (Notes); the others are ignored.
    target : (M, D) array_like, (H, W, 3), or PointCloud
        Points to move onto; no correspondence with ``model`` is given, M may differ from N,
        the target may carry outliers or lack parts of the model.
    method : str
        "l2e" (default; non-rigid, shape context + L2E), "cpd" (non-rigid), "cpd-rigid"
        (rotation, scale, translation), "cpd-affine", "icp", "icp-hmrf", "color-gmm",
        "density-adaptive", "bayes" (rigid), "cpd-net" (non-rigid, learned, 2-D); see the module
        docstring.
    options : options dataclass or dict, optional
        Of ``method``: ``RegistrationOptions`` ("l2e"), ``CPDOptions`` ("cpd*"), ``ICPOptions``,
        ``HMRFOptions``, ``ColorGMMOptions``, ``DensityAdaptiveOptions``, ``BayesOptions``,
        ``CPDNetOptions`` (:func:`options_class` names it).
    rng : int or numpy.random.Generator, optional
        Seed for sampling; the same seed gives the same answer.
    model_colors, target_colors : array_like, optional
        RGB in [0, 1] (or uint8, 0-255), one row of 3 per point (shaped (H, W, 3) for an organized scan);
        ``"color-gmm"`` only, which needs them (:meth:`Method.use_of
        <reglib.registration._methods.Method.use_of>`).
    model_normals, target_normals : array_like, optional
        Unit normals shaped like their points: ``model_normals`` for ``"icp"``, ``target_normals``
        for ``"icp"`` and ``"icp-hmrf"`` (estimated when not given) where the options use them (Notes).

    Returns
    -------
    Registration
        ``registered`` and ``correspondence`` have one row per model point (H * W rows for an
        organized scan, in row-major order: NaN and -1 where it has no point).

    Raises
    ------
    InputError
        When a set is not (N, 2), (N, 3) or (H, W, 3) numbers, holds inf (or NaN outside an
        organized scan), the two D differ, a set has fewer points than the method needs (l2e: 5,
        cpd: 3, cpd-affine: D + 1, cpd-rigid: 2, the rigid methods: 3 not all on one line),
        ``"cpd-net"`` is given 3-D sets, a colors or normals keyword is given to a method, or
        with options, that does not use it, a keyword and a PointCloud both give the same
        set's colors (or normals), colors or normals that are used have the wrong shape, or
        ``method`` / ``options`` are not recognized.

    Notes
    -----
    What each method reads from a PointCloud (the colors and normals it uses; a keyword array
    is used the same way, and one it cannot use is an ``InputError``):

    ================  ==========================  ==========================
    method            from a ``model`` cloud      from a ``target`` cloud
    ================  ==========================  ==========================
    l2e               points                      points
    cpd               points                      points
    cpd-rigid         points                      points
    cpd-affine        points                      points
    cpd-net           points                      points
    icp               points, normals             points, normals (a)
    icp-hmrf          points (an (H, W, 3) grid)  points, normals (b)
    color-gmm         points, colors (needed)     points, colors (needed)
    density-adaptive  points                      points
    bayes             points                      points
    ================  ==========================  ==========================

    (a) with ``variant="point_to_plane"`` (the default), or with model normals (their angle
    check); (b) with ``variant="point_to_plane"`` or ``prealign=True`` (the defaults).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    >>> model = np.c_[np.cos(t) + 0.4 * np.cos(2 * t), np.sin(t) + 0.3 * np.sin(3 * t)]
    >>> target = model @ np.array([[0, -1.0], [1.0, 0]]).T * 1.5 + [3.0, 1.0]  # rotated by 90 degrees
    >>> res = register_points(model, target, rng=0)
    >>> bool(np.abs(res.registered - target).max() < 0.05)
    True
    """
    spec = method_spec(method)
    opts: Any = as_options(options, spec.options)
    m_set, t_set = _as_set(model, "model"), _as_set(target, "target")
    m_grid, m_valid, t_grid, t_valid = m_set.grid, m_set.valid, t_set.grid, t_set.valid
    m_pts, t_pts = m_set.points, t_set.points
    if t_pts.shape[1] != m_pts.shape[1]:
        raise InputError(f"`target` must have the dimension of `model` (D = {m_pts.shape[1]}), "
                         f"got shape {t_grid.shape}")
    d = m_pts.shape[1]
    need = spec.points_needed(d)
    for name, pts in (("model", m_pts), ("target", t_pts)):
        if len(pts) < need:
            raise InputError(f"`{name}` must have at least {need} points for method {spec.name!r}, got {len(pts)}")
        if spec.rigid:
            _check_not_collinear(pts, name)
    given = {"model_colors": model_colors, "target_colors": target_colors, "model_normals": model_normals,
             "target_normals": target_normals}
    extras = _extras(spec, opts, {"model": m_set, "target": t_set}, given)
    generator = as_rng(rng)
    with single_thread_blas():
        if not spec.rigid:
            norm = Normalization.of(m_pts, t_pts)
            u, y = norm.apply(m_pts, t_pts)
            warp_fit: WarpFit = spec.fit(u, y, opts, generator)
            transform = warp_fit.model.to_warp(norm)
            if spec.motion != "non-rigid":  # one affine map: in the caller's units, without the frames' means
                transform = rigid_warp(caller_matrix(transform))
            n_iter, converged, reach = warp_fit.n_iter, warp_fit.converged, warp_fit.reach * norm.dst_scale
            reason = warp_fit.reason
        else:
            if spec.organized_model == "required":
                if m_grid.ndim != 3:
                    raise InputError(f"method {spec.name!r} needs an organized model scan of shape (H, W, 3), "
                                     f"got {m_grid.shape}")
                fit: RigidFit = spec.fit(m_grid, t_pts, opts, generator, **extras)
            else:
                fit = spec.fit(m_pts, t_pts, opts, generator, **extras)
            transform = rigid_warp(fit.matrix)
            n_iter, converged, reach, reason = fit.n_iter, fit.converged, fit.reach, fit.reason
    moved = transform(m_pts)
    # bounded by the reach: a point farther away has no correspondence, and an unbounded query of
    # one far from the target (an outlier) visits many cells of the tree; one query serves the fit figures too
    tree = cKDTree(t_pts)
    if spec.motion == "similarity" and converged and reason is None:
        reason = polish_reason(polish_shift(moved, tree, scale=bool(getattr(opts, "scale", False))))
        converged = reason is None
    figures_reach = fit_reach(tree)
    dist, idx = tree.query(moved, distance_upper_bound=np.nextafter(max(reach, figures_reach), np.inf))
    registered = np.full((len(m_valid), d), np.nan)
    registered[m_valid] = moved
    correspondence = np.full(len(m_valid), -1, dtype=np.intp)
    # indices into the target as given: an organized target's rows in row-major order
    target_rows = np.flatnonzero(t_valid)
    correspondence[m_valid] = np.where(dist <= reach, target_rows[np.minimum(idx, len(target_rows) - 1)], -1)
    fitness, inlier_rmse = fit_figures(moved, tree, dist=np.asarray(dist), reach=figures_reach)
    return Registration(transform=transform, correspondence=correspondence, n_iter=int(n_iter),
                        converged=bool(converged), registered=registered, method=spec.name, seed=seed_of(rng),
                        reason=settled_reason(bool(converged), reason), fitness=fitness, inlier_rmse=inlier_rmse,
                        matrix=None if transform.linear is None or spec.motion == "non-rigid"
                        else homogeneous(transform.linear.matrix))


def _as_scan(value: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``value`` as (N, D) finite points, or an organized (H, W, 3) scan with NaN for missing pixels.

    Returns the array and the (N,) or (H * W,) mask of the rows that hold a point.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is not None and arr.ndim == 3:
        if arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
            raise InputError(f"`{name}` as an organized scan must have shape (H, W, 3), got {arr.shape}")
        flat = arr.reshape(-1, 3)
        if np.isinf(flat).any():
            raise InputError(f"`{name}` holds inf values (an organized scan marks missing pixels with NaN)")
        valid = np.asarray(~np.isnan(flat).any(axis=1))
        if not valid.any():
            raise InputError(f"`{name}` is an organized scan without a single valid (non-NaN) point")
        if np.abs(flat[valid]).max() > MAX_COORDINATE:
            raise InputError(f"`{name}` has coordinates beyond {MAX_COORDINATE:.0e} in magnitude")
        return np.array(arr), valid
    pts = as_points(value, name)
    return pts, np.ones(len(pts), dtype=bool)


def _check_not_collinear(pts: np.ndarray, name: str) -> None:
    centered = pts - pts.mean(0)
    s = np.linalg.svd(centered, compute_uv=False) if len(pts) else np.zeros(1)
    if len(s) < 2 or s[1] <= 1e-9 * max(float(s[0]), 1e-300):
        raise InputError(f"`{name}` has all its points on one line (or one point): a rigid motion is not "
                         "determined by it")


_EXPECTED = {"colors": "RGB in [0, 1] or uint8, one row per point", "normals": "unit normals, one row per point"}


@dataclass(frozen=True, eq=False)
class _Set:
    """One point set as given: its rows (or grid), which rows hold a point, and the PointCloud it came in."""

    name: str  # "model" or "target"
    grid: np.ndarray  # (N, D), or (H, W, 3) for an organized scan
    valid: np.ndarray  # (N,) or (H * W,) bool: the rows that hold a point
    cloud: PointCloud | None  # the PointCloud given, None for an array

    @property
    def points(self) -> np.ndarray:
        """(K, D) the valid rows."""
        return self.grid.reshape(-1, self.grid.shape[-1])[self.valid]


def _as_set(value: Any, name: str) -> _Set:
    """``value`` (array_like or :class:`~reglib.io.PointCloud`) checked by :func:`_as_scan`."""
    if isinstance(value, PointCloud):
        grid, valid = _as_scan(value.points, f"{name}.points")
        return _Set(name=name, grid=grid, valid=valid, cloud=value)
    grid, valid = _as_scan(value, name)
    return _Set(name=name, grid=grid, valid=valid, cloud=None)


def _extras(spec: Method, opts: Any, sets: Mapping[str, _Set], given: Mapping[str, Any]) -> dict[str, Any]:
    """The colors / normals ``spec`` uses, from the keywords ``given`` or the sets' PointClouds, checked.

    A keyword the method (or, through ``spec.unused``, its options) does not use is an
    ``InputError``; what a PointCloud carries is then ignored. A keyword and a PointCloud that
    give the same thing are an ``InputError`` (no precedence to remember).

    Parameters
    ----------
    spec : Method
        The method's record (:meth:`Method.use_of`, ``unused``).
    opts : options dataclass
        The method's options, for ``spec.unused``.
    sets : mapping
        ``{"model": _Set, "target": _Set}``.
    given : mapping
        The keyword arguments of :data:`~reglib.registration._methods.EXTRAS`, None when not given.

    Returns
    -------
    dict
        The arguments for ``spec.fit``: (K, C) rows of the valid points, or the (H, W, C) grid
        for the model of a method on the pixel grid.
    """
    chosen: dict[str, tuple[Any, str, bool]] = {}  # argument -> (value, its name in messages, from a cloud)
    for arg, value in given.items():
        side, kind = arg.split("_")
        cloud = sets[side].cloud
        carried = None if cloud is None else getattr(cloud, kind)
        if value is not None and carried is not None:
            raise InputError(f"`{arg}` and `{side}.{kind}` (the PointCloud's) are both given: pass one")
        use = spec.use_of(arg)
        if value is not None and use == "unused":
            raise InputError(f"`{arg}` is used by method(s) {list(methods_taking(arg))} only, not by {spec.name!r}")
        if value is None and carried is None and use == "required":
            raise InputError(f"method {spec.name!r} needs `{arg}` ({_EXPECTED[kind]}), or a PointCloud `{side}` "
                             f"with {kind}")
        if use != "unused" and (value is not None or carried is not None):
            chosen[arg] = (value, f"`{arg}`", False) if value is not None else (carried, f"`{side}.{kind}`", True)
    idle = spec.unused(opts, frozenset(chosen)) if spec.unused is not None else {}
    out: dict[str, Any] = {}
    for arg, (value, label, carried) in chosen.items():
        if arg in idle:
            if carried:
                continue
            raise InputError(f"{label} is not used by method {spec.name!r} {idle[arg]}")
        side, kind = arg.split("_")
        on_grid = spec.organized_model == "required" and side == "model"  # the grid method takes the grid
        out[arg] = _checked(value, label, kind, sets[side], on_grid)
    return out


def _checked(value: Any, label: str, kind: str, points: _Set, on_grid: bool) -> np.ndarray:
    """Colors (3 per point) or normals (D per point) ``value`` of ``points``, checked where the points are.

    Returns the rows of the valid points, or the whole grid when ``on_grid``.
    """
    grid = points.grid
    shape = (*grid.shape[:-1], 3 if kind == "colors" else grid.shape[-1])
    try:
        arr = np.asarray(value)
        if kind == "normals":
            arr = arr.astype(np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{label} must be numbers of shape {shape}") from None
    if arr.shape != shape:
        raise InputError(f"{label} must have the shape of its points, {shape} ({_EXPECTED[kind]}), got {arr.shape}")
    if kind == "colors":  # uint8 (0-255) or numbers in [0, 1], as float64 in [0, 1]
        arr = as_colors(arr, label.strip("`"), rows=points.valid)
    rows = arr.reshape(-1, shape[-1])[points.valid]
    if not np.isfinite(rows).all():
        raise InputError(f"{label} must be finite where the points are")
    return arr if on_grid else rows
