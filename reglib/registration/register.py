"""``register_points``: align a model point set to a target without known correspondences.

One public function in front of every method; each method lives in its own module:

- ``"l2e"``: shape context + L2E (:mod:`reglib.registration.sc_l2e`), non-rigid;
- ``"cpd"``, ``"cpd-rigid"``, ``"cpd-affine"``: Coherent Point Drift (:mod:`reglib.registration.cpd`);
- ``"icp"``: robust point-to-point / point-to-plane ICP (:mod:`reglib.registration.icp`);
- ``"icp-hmrf"``: ICP with a hidden Markov random field over an organized scan's pixel grid
  (:mod:`reglib.registration.hmrf`);
- ``"color-gmm"``: colour-assisted probabilistic registration (:mod:`reglib.registration.color_gmm`);
- ``"density-adaptive"``: registration robust to sampling density (:mod:`reglib.registration.density_adaptive`);
- ``"bayes"``: variational Bayesian registration with Student-t mixtures (:mod:`reglib.registration.bayes`).

Input checks happen here, once: finite coordinates (NaN only as the missing pixels of an
organized (H, W, 3) scan), matching dimensions, enough points that are not all on one line,
colours and normals of the right shape. The non-rigid and CPD methods work in normalized
coordinates; the rigid ones in the caller's units, so that their rotation stays a rotation.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy.spatial import cKDTree

from .._validation import MAX_COORDINATE, as_choice, as_options, as_points, as_rng, seed_of
from ..errors import InputError
from ..robust import Normalization, single_thread_blas
from .cpd import CPDOptions, cpd_register
from .result import Registration
from .rigid import RigidFit, rigid_warp
from .sc_l2e import RegistrationOptions, register_sc_l2e

__all__ = ["register_points", "METHODS", "RIGID_METHODS", "options_class"]

Method = Literal["l2e", "cpd", "cpd-rigid", "cpd-affine", "icp", "icp-hmrf", "color-gmm", "density-adaptive", "bayes"]
METHODS: tuple[Method, ...] = ("l2e", "cpd", "cpd-rigid", "cpd-affine", "icp", "icp-hmrf", "color-gmm",
                               "density-adaptive", "bayes")


@dataclass(frozen=True)
class _Rigid:
    """A rigid method: its module, options class and function, and the extra inputs it takes."""

    module: str
    options: str
    function: str
    colors: bool = False
    normals: bool = False
    organized_model: bool = False


_RIGID: dict[str, _Rigid] = {
    "icp": _Rigid("icp", "ICPOptions", "icp_register", normals=True),
    "icp-hmrf": _Rigid("hmrf", "HMRFOptions", "icp_hmrf_register", normals=True, organized_model=True),
    "color-gmm": _Rigid("color_gmm", "ColorGMMOptions", "color_gmm_register", colors=True),
    "density-adaptive": _Rigid("density_adaptive", "DensityAdaptiveOptions", "density_adaptive_register"),
    "bayes": _Rigid("bayes", "BayesOptions", "bayes_register"),
}
RIGID_METHODS: tuple[str, ...] = tuple(_RIGID)


def _member(spec: _Rigid, name: str) -> Any:
    return getattr(importlib.import_module(f"{__package__}.{spec.module}"), name)


def options_class(method: str) -> type:
    """The options dataclass of a registration ``method`` (e.g. ``RegistrationOptions`` for "l2e")."""
    method = as_choice(method, "method", METHODS)
    if method == "l2e":
        return RegistrationOptions
    if method.startswith("cpd"):
        return CPDOptions
    return _member(_RIGID[method], _RIGID[method].options)  # type: ignore[no-any-return]


def register_points(model: Any, target: Any, *, method: Method = "l2e", options: Any = None,
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
        "density-adaptive", "bayes" (rigid); see the module docstring.
    options : options dataclass or dict, optional
        Of ``method``: ``RegistrationOptions`` ("l2e"), ``CPDOptions`` ("cpd*"), ``ICPOptions``,
        ``HMRFOptions``, ``ColorGMMOptions``, ``DensityAdaptiveOptions``, ``BayesOptions``
        (:func:`options_class` names it).
    rng : int or numpy.random.Generator, optional
        Seed for sampling; the same seed gives the same answer.
    model_colors, target_colors : array_like, optional
        RGB in [0, 1], one row per point (shaped like an organized scan); ``"color-gmm"`` only,
        which needs them.
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
        colours or normals are given to a method that does not use them or have the wrong shape,
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
    method = as_choice(method, "method", METHODS)
    opts: Any = as_options(options, options_class(method))
    rigid = _RIGID.get(method)
    m_grid, m_valid = _as_scan(model, "model")
    t_grid, t_valid = _as_scan(target, "target")
    m_pts, t_pts = m_grid.reshape(-1, m_grid.shape[-1])[m_valid], t_grid.reshape(-1, t_grid.shape[-1])[t_valid]
    if t_pts.shape[1] != m_pts.shape[1]:
        raise InputError(f"`target` must have the dimension of `model` (D = {m_pts.shape[1]}), "
                         f"got shape {t_grid.shape}")
    d = m_pts.shape[1]
    need = {"l2e": 5, "cpd": 3, "cpd-affine": d + 1, "cpd-rigid": 2}.get(method, 3)
    for name, pts in (("model", m_pts), ("target", t_pts)):
        if len(pts) < need:
            raise InputError(f"`{name}` must have at least {need} points for method {method!r}, got {len(pts)}")
        if rigid is not None:
            _check_not_collinear(pts, name)
    extras = _extras(method, rigid, m_grid, m_valid, t_grid, t_valid, model_colors=model_colors,
                     target_colors=target_colors, model_normals=model_normals, target_normals=target_normals)
    generator = as_rng(rng)
    with single_thread_blas():
        if rigid is None:
            norm = Normalization.of(m_pts, t_pts)
            u, y = norm.apply(m_pts, t_pts)
            if method == "l2e":
                g, n_iter, converged, reach = register_sc_l2e(u, y, opts, generator)
            else:
                g, n_iter, converged, reach = cpd_register(u, y, method, opts, generator)
            transform = g.to_warp(norm)
            reach *= norm.dst_scale
        else:
            run = _member(rigid, rigid.function)
            if rigid.organized_model:
                if m_grid.ndim != 3:
                    raise InputError(f"method {method!r} needs an organized model scan of shape (H, W, 3), "
                                     f"got {m_grid.shape}")
                fit: RigidFit = run(m_grid, t_pts, opts, generator, **extras)
            else:
                fit = run(m_pts, t_pts, opts, generator, **extras)
            transform = rigid_warp(fit.matrix)
            n_iter, converged, reach = fit.n_iter, fit.converged, fit.reach
    moved = transform(m_pts)
    dist, idx = cKDTree(t_pts).query(moved)
    registered = np.full((len(m_valid), d), np.nan)
    registered[m_valid] = moved
    correspondence = np.full(len(m_valid), -1, dtype=np.intp)
    # indices into the target as given: an organized target's rows in row-major order
    target_rows = np.flatnonzero(t_valid)
    correspondence[m_valid] = np.where(dist <= reach, target_rows[idx], -1)
    return Registration(transform=transform, correspondence=correspondence, n_iter=int(n_iter),
                        converged=bool(converged), registered=registered, method=method, seed=seed_of(rng))


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
    centred = pts - pts.mean(0)
    s = np.linalg.svd(centred, compute_uv=False) if len(pts) else np.zeros(1)
    if len(s) < 2 or s[1] <= 1e-9 * max(float(s[0]), 1e-300):
        raise InputError(f"`{name}` has all its points on one line (or one point): a rigid motion is not "
                         "determined by it")


def _extras(method: str, rigid: _Rigid | None, m_grid: np.ndarray, m_valid: np.ndarray, t_grid: np.ndarray,
            t_valid: np.ndarray, **given: Any) -> dict[str, Any]:
    """Colours / normals for the methods that take them, checked against the points' shapes."""
    out: dict[str, Any] = {}
    for key, value in given.items():
        kind = "colors" if key.endswith("colors") else "normals"
        takes = rigid is not None and getattr(rigid, kind)
        if value is None:
            if kind == "colors" and takes:
                raise InputError(f"method {method!r} needs `{key}` (RGB in [0, 1], one row per point)")
            continue
        if not takes:
            users = [m for m, r in _RIGID.items() if getattr(r, kind)]
            raise InputError(f"`{key}` is used by method(s) {users} only, not by {method!r}")
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
        if rigid is not None and rigid.organized_model and key.startswith("model"):
            out[key] = arr  # the grid method takes the grid
        else:
            out[key] = rows
    return out
