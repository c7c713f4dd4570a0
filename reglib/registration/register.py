"""``register_points``: align a model point set to a target without known correspondences.

One public function in front of every method of the table :data:`~reglib.registration.methods.METHODS`
(one module per method):

- ``"l2e"``: shape context + L2E (:mod:`reglib.registration.sc_l2e`), non-rigid;
- ``"cpd"``, ``"cpd-rigid"``, ``"cpd-affine"``: Coherent Point Drift (:mod:`reglib.registration.cpd`);
- ``"icp"``: robust point-to-point / point-to-plane ICP (:mod:`reglib.registration.icp`);
- ``"icp-hmrf"``: ICP with a hidden Markov random field over an organized scan's pixel grid
  (:mod:`reglib.registration.hmrf`);
- ``"color-gmm"``: color-assisted probabilistic registration (:mod:`reglib.registration.color_gmm`);
- ``"density-adaptive"``: registration robust to sampling density (:mod:`reglib.registration.density_adaptive`);
- ``"bayes"``: variational Bayesian registration with Student-t mixtures (:mod:`reglib.registration.bayes`);
- ``"cpd-net"``: CPD-Net, a learned coherent displacement field in one forward pass, 2-D
  (:mod:`reglib.registration.cpd_net`).

Input checks happen here, once: finite coordinates (NaN only as the missing pixels of an
organized (H, W, 3) scan), matching dimensions, enough points that are not all on one line,
colors and normals of the right shape. The non-rigid and CPD methods work in normalized
coordinates; the rigid ones in the caller's units, so that their rotation stays a rotation.
"""
from __future__ import annotations

from typing import Any, Literal

import numpy as np
from scipy.spatial import cKDTree

from .._validation import MAX_COORDINATE, as_options, as_points, as_rng, seed_of
from ..errors import InputError
from ..robust import Normalization, single_thread_blas
from .methods import METHODS, RIGID_METHODS, Method, MethodName, method_spec, methods_taking, options_class
from .result import Registration, WarpFit
from .rigid import RigidFit, rigid_warp

__all__ = ["register_points", "METHODS", "RIGID_METHODS", "options_class"]


def register_points(model: Any, target: Any, *, method: MethodName = "l2e", options: Any = None,
                    rng: int | np.random.Generator | None = None, model_colors: Any = None,
                    target_colors: Any = None, model_normals: Any = None,
                    target_normals: Any = None) -> Registration:
    """Register ``model`` onto ``target``: find a map model space -> target space.

    Parameters
    ----------
    model : (N, D) array_like, or (H, W, 3) for an organized scan
        Points (x, y[, z]) to move, D in {2, 3}. An organized scan (a depth camera's grid) may
        hold NaN where nothing was seen; ``"icp-hmrf"`` needs one.
    target : (M, D) array_like, or (H, W, 3)
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
        RGB in [0, 1], one row per point (shaped like an organized scan); ``"color-gmm"`` only,
        which needs them (:attr:`Method.colors <reglib.registration.methods.Method>`).
    model_normals, target_normals : array_like, optional
        Unit normals, one row per point; ``"icp"`` and ``"icp-hmrf"`` (estimated when not given).

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
        ``"cpd-net"`` is given 3-D sets,
        colors or normals are given to a method that does not use them or have the wrong shape,
        or ``method`` / ``options`` are not recognized.

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
    m_grid, m_valid = _as_scan(model, "model")
    t_grid, t_valid = _as_scan(target, "target")
    m_pts, t_pts = m_grid.reshape(-1, m_grid.shape[-1])[m_valid], t_grid.reshape(-1, t_grid.shape[-1])[t_valid]
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
    extras = _extras(spec, m_grid, m_valid, t_grid, t_valid, model_colors=model_colors,
                     target_colors=target_colors, model_normals=model_normals, target_normals=target_normals)
    generator = as_rng(rng)
    with single_thread_blas():
        if not spec.rigid:
            norm = Normalization.of(m_pts, t_pts)
            u, y = norm.apply(m_pts, t_pts)
            warp_fit: WarpFit = spec.fit(u, y, opts, generator)
            transform = warp_fit.model.to_warp(norm)
            n_iter, converged, reach = warp_fit.n_iter, warp_fit.converged, warp_fit.reach * norm.dst_scale
            reason = None
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
    # one far from the target (an outlier) visits many cells of the tree
    dist, idx = cKDTree(t_pts).query(moved, distance_upper_bound=np.nextafter(reach, np.inf))
    registered = np.full((len(m_valid), d), np.nan)
    registered[m_valid] = moved
    correspondence = np.full(len(m_valid), -1, dtype=np.intp)
    # indices into the target as given: an organized target's rows in row-major order
    target_rows = np.flatnonzero(t_valid)
    correspondence[m_valid] = np.where(dist <= reach, target_rows[np.minimum(idx, len(target_rows) - 1)], -1)
    return Registration(transform=transform, correspondence=correspondence, n_iter=int(n_iter),
                        converged=bool(converged), registered=registered, method=spec.name, seed=seed_of(rng),
                        reason=reason)


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


_EXPECTED = {"colors": "RGB in [0, 1], one row per point", "normals": "unit normals, one row per point"}


def _extras(spec: Method, m_grid: np.ndarray, m_valid: np.ndarray, t_grid: np.ndarray,
            t_valid: np.ndarray, **given: Any) -> dict[str, Any]:
    """Colors / normals for the methods that take them (``spec.colors``, ``spec.normals``), checked
    against the points' shapes."""
    out: dict[str, Any] = {}
    for key, value in given.items():
        kind: Literal["colors", "normals"] = "colors" if key.endswith("colors") else "normals"
        use = getattr(spec, kind)
        if value is None:
            if use == "required":
                raise InputError(f"method {spec.name!r} needs `{key}` ({_EXPECTED[kind]})")
            continue
        if use == "unused":
            raise InputError(f"`{key}` is used by method(s) {list(methods_taking(kind))} only, not by {spec.name!r}")
        grid, valid = (m_grid, m_valid) if key.startswith("model") else (t_grid, t_valid)
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"`{key}` must be numbers of shape {grid.shape}") from None
        if arr.shape != grid.shape or grid.shape[-1] != 3:
            raise InputError(f"`{key}` must have the shape of its points {grid.shape} (3 channels), got {arr.shape}")
        rows = arr.reshape(-1, 3)[valid]
        if not np.isfinite(rows).all():
            raise InputError(f"`{key}` must be finite where the points are")
        if kind == "colors" and (rows.min(initial=0.0) < 0.0 or rows.max(initial=0.0) > 1.0):
            raise InputError(f"`{key}` must be RGB values in [0, 1]")
        if spec.organized_model == "required" and key.startswith("model"):
            out[key] = arr  # the grid method takes the grid
        else:
            out[key] = rows
    return out
