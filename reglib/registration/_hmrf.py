"""ICP with low-overlap outlier rejection by a hidden Markov random field (Stechschulte et al. [1]).

For organized scans (depth cameras, flash lidar, stereo): the model is an (H, W, 3) grid with
NaN where nothing was seen. Model points without a partner in the target (outside the overlap,
occluded) come in connected regions of the pixel grid, so each pixel i gets a hidden label
z_i in {+1 inlier, -1 outlier} with an Ising / two-label Potts prior on the 4-neighbor grid,
P(z) ~ exp(beta sum_{i~j} z_i z_j), and its observation y_i, the distance of the moved model
point to its nearest target point, is drawn from the inlier or the outlier component.

Every ICP iteration runs one EM step of this hidden field (the mean-field EM of Celeux, Forbes
and Peyrard [2], the inference [1] uses):

- E-step: ``mf_sweeps`` mean-field sweeps over the grid, m_i = tanh(beta sum_{j~i} m_j +
  (log p_in(y_i) - log p_out(y_i)) / 2), m_i = E[z_i], in two checkerboard half-sweeps (all pixels
  of one color at once, vectorized; no per-pixel loop). Pixels with no data have m_i = 0 (no
  evidence either way) and pass nothing on. gamma_i = (1 + m_i) / 2 is the inlier posterior.
- M-step: the components' parameters by weighted maximum likelihood. Inliers: a half-normal
  law of the distance, densest at 0, sigma_in^2 = sum gamma y^2 / sum gamma. Outliers: a Gaussian
  (mu_out, sigma_out^2) of the distance ([1] models both components as distributions of y;
  these two are our choice of forms, each with closed-form updates), with sigma_out >= sigma_in
  and mu_out >= sigma_in.
- ICP step: the weighted point-to-plane (or point-to-point) step of :mod:`reglib.registration._steps`
  with weights gamma_i (``hard=True``: gamma_i > 1/2).

Nearest-target queries are bounded (a k-d tree query far from the target is slow): by the
global search's reach in the first iteration, then by max(20 sigma_in, 4 target spacings), a
bound that only shrinks; a pixel beyond it is an outlier for sure (its evidence is -50).

The field's parameters start from the first distances: sigma_in from their 25th percentile, the
outlier component from their upper half. The initial pose is the one of ``icp_register``'s
``init`` (the same global search by default; ``init="features"``: the feature start of
:mod:`reglib.registration._feature_start`), refined by a VarTrimmed robust ICP
(``prealign=True``): the field's distances are only informative near the right pose, and the
mean field started far from it labels the wrong regions. Large grids: with more than ``max_points`` pixels
the grid is thinned by a stride s (every s-th row and column), which keeps it a grid.

References
----------
.. [1] J. Stechschulte, N. Ahmed, C. Heckman, "Robust low-overlap 3-D point cloud registration for
       outlier rejection", ICRA 2019. :doi:`10.1109/ICRA.2019.8793857` (arXiv:1711.05864)
.. [2] G. Celeux, F. Forbes, N. Peyrard, "EM procedures using mean field-like approximations for
       Markov model-based image segmentation", Pattern Recognition 36(1), 2003.
       :doi:`10.1016/S0031-3203(02)00027-4`
"""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..options import declared, option
from ._feature_start import choose_start
from ._icp import refine_icp
from ._icp_options import ICPLoopOptions, ICPOptions
from ._normals import LazyNormals
from ._rigid import RigidFit
from ._start import Start
from ._steps import plane_step, point_spacing, point_step

__all__ = ["HMRFOptions", "icp_hmrf_register", "mean_field"]

_LOG_2_OVER_PI_HALF = 0.5 * np.log(2.0 / np.pi)
_BOUND_SIGMAS = 20.0  # nearest-target queries reach 20 sigma_in (at least 4 target spacings)


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class HMRFOptions(ICPLoopOptions):
    """Options of ``register_points(method="icp-hmrf")``; lengths are in the caller's units.

    Parameters
    ----------
    beta : float
        Coupling of the 4-neighbor Ising prior (beta in [1]); 0 makes the labels independent
        (a plain two-component mixture on the distances).
    mf_sweeps : int
        Mean-field sweeps per ICP iteration (each a pair of checkerboard half-sweeps).
    hard : bool
        Weight pairs by the hard label (gamma > 1/2) instead of the inlier posterior gamma.
    prealign : bool
        Start the field from the pose of a robust ICP (:func:`~reglib.registration._icp.
        icp_register` with the VarTrimmed loss, which keeps its minimum at the true pose at low
        overlap better than the M-estimators with a MAD scale) run from the initial alignment,
        rather than from the initial alignment itself.
    max_points : int
        Pixels of the model grid used at most (thinned by a stride beyond it).
    variant, max_iter, tol, k_normals, solver, init, n_rotations, init_max_angle, init_points, \
init_iter, init_keep, init_margin
        The ICP residual, its iteration and the initial alignment, as for ``"icp"``
        (:class:`~reglib.registration._icp_options.ICPLoopOptions`).
    """

    beta: float = option(1.0, kind="float", low=0, high=10, doc="coupling of the 4-neighbor Ising prior")
    mf_sweeps: int = option(3, kind="int", low=1, high=100, doc="mean-field sweeps per ICP iteration")
    hard: bool = option(False, kind="bool", doc="weight pairs by the hard label instead of the inlier posterior")
    prealign: bool = option(True, kind="bool", doc="start the field from the pose of a VarTrimmed robust ICP")
    max_points: int = option(60000, kind="int", low=100, high=1_000_000,
                             doc="pixels of the model grid used at most (thinned by a stride beyond it)")

    def icp_options(self) -> ICPOptions:
        """The ICP options that share these settings (used for the initial alignment)."""
        return ICPOptions(**self.loop_fields())

    def unused_extras(self, given: Collection[str]) -> dict[str, str]:
        """The extras among the ``given`` argument names that these options leave unused.

        Target normals serve the point-to-plane residual and the point-to-plane ``prealign``;
        point-to-point without it reads none (the method record's ``unused``).

        Parameters
        ----------
        given : collection of str
            Argument names of :data:`~reglib.registration._methods.EXTRAS` that are given.

        Returns
        -------
        dict
            {argument: the condition under which it is unused, in words}; empty when all are used.
        """
        if self.variant == "point_to_point" and not self.prealign and "target_normals" in given:
            return {"target_normals": "with variant='point_to_point' and prealign=False"}
        return {}


def _neighbor_sum(m: np.ndarray) -> np.ndarray:
    """Sum of the 4-neighbors of every pixel of ``m`` (H, W); zero beyond the border."""
    s = np.zeros_like(m)
    s[1:, :] += m[:-1, :]
    s[:-1, :] += m[1:, :]
    s[:, 1:] += m[:, :-1]
    s[:, :-1] += m[:, 1:]
    return s


def mean_field(evidence: np.ndarray, seen: np.ndarray, beta: float, sweeps: int,
               start: np.ndarray | None = None) -> np.ndarray:
    """Mean spins m = E[z] (H, W) of the Ising field with external field ``evidence`` / 2.

    Parameters
    ----------
    evidence : (H, W) ndarray
        log p_in(y_i) - log p_out(y_i) per pixel (ignored where not ``seen``).
    seen : (H, W) bool ndarray
        Pixels with data; the others keep m = 0.
    beta : float
        Coupling of the 4-neighbor prior.
    sweeps : int
        Checkerboard sweeps.
    start : (H, W) ndarray, optional
        Mean spins to start from (zeros when omitted).

    Returns
    -------
    (H, W) ndarray
        m in [-1, 1]; the inlier posterior is (1 + m) / 2.

    Examples
    --------
    >>> import numpy as np
    >>> ev = np.full((4, 4), 2.0); ev[:, :2] = -2.0
    >>> m = mean_field(ev, np.ones((4, 4), bool), beta=0.5, sweeps=5)
    >>> bool((m[:, 2:] > 0.9).all() and (m[:, :2] < -0.9).all())
    True
    """
    h, w = evidence.shape
    m = np.zeros((h, w)) if start is None else np.where(seen, start, 0.0)
    ext = np.where(seen, 0.5 * evidence, 0.0)
    parity = (np.add.outer(np.arange(h), np.arange(w)) % 2).astype(bool)
    colors = (seen & ~parity, seen & parity)
    for _ in range(sweeps):
        for mask in colors:
            field = beta * _neighbor_sum(m) + ext
            m[mask] = np.tanh(field[mask])
    return m


def _log_half_normal(y: np.ndarray, sigma: float) -> np.ndarray:
    return _LOG_2_OVER_PI_HALF - np.log(sigma) - y * y / (2.0 * sigma * sigma)


def _log_gauss(y: np.ndarray, mu: float, sigma: float) -> np.ndarray:
    return -0.5 * np.log(2.0 * np.pi) - np.log(sigma) - (y - mu) ** 2 / (2.0 * sigma * sigma)


def icp_hmrf_register(model: np.ndarray, target: np.ndarray, opts: HMRFOptions, rng: np.random.Generator, *,
                      target_normals: np.ndarray | None = None) -> RigidFit:
    """Register an organized model scan onto a target by HMRF-weighted ICP (module docstring).

    Parameters
    ----------
    model : (H, W, 3) float64 ndarray
        Organized scan, (x, y, z) per pixel ``[row, col]``, NaN rows where nothing was seen.
    target : (M, 3) or (H', W', 3) float64 ndarray
        Target points; NaN rows (organized target) are dropped.
    opts : HMRFOptions
        Field and ICP settings.
    rng : numpy.random.Generator
        Draws the samples of the initial alignment; the same seed gives the same answer.
    target_normals : (M, 3) or (H', W', 3) ndarray, optional
        Target normals for point-to-plane and the prealignment (PCA of ``opts.k_normals``
        neighbors when omitted). The model takes none: the field weighs its pixels by their
        distances alone.

    Returns
    -------
    RigidFit
        ``[R | t]`` (3, 4) taking model points onto the target, iterations, convergence, and the
        reach 3 sigma_in (at least the target's spacing).

    Raises
    ------
    InputError
        ``model`` not (H, W, 3), fewer than 3 seen pixels, or normals of the wrong shape.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> u, v = np.meshgrid(np.linspace(-1, 1, 40), np.linspace(-1, 1, 30))
    >>> grid = np.dstack([u, v, 0.3 * np.sin(2 * u) * np.cos(3 * v)])
    >>> target = grid.reshape(-1, 3)[:900] + [0.05, -0.02, 0.01]      # the upper 3/4, shifted
    >>> fit = icp_hmrf_register(grid, target, HMRFOptions(init="given"), rng)
    >>> bool(np.allclose(fit.matrix, np.c_[np.eye(3), [0.05, -0.02, 0.01]], atol=1e-3))
    True
    """
    scan = _scan(model, target, opts, target_normals)
    start = _start(scan, opts, rng)
    return _iterate(scan, start, opts, rng)


@dataclass(frozen=True, eq=False)
class _Scan:
    """What the field ICP runs on: the thinned model grid's seen pixels and the target's seen points."""

    seen: np.ndarray  # (h, w) bool: pixels of the thinned model grid with data
    pts: np.ndarray  # (K, 3) their points, in row-major order of the seen pixels
    tgt: np.ndarray  # (M, 3) the target's finite points
    tn: np.ndarray | None  # (M, 3) their normals, when given
    tree: cKDTree  # built on tgt


def _scan(model: np.ndarray, target: np.ndarray, opts: HMRFOptions, target_normals: np.ndarray | None) -> _Scan:
    """The checked inputs of :func:`icp_hmrf_register`, the model grid thinned by a stride to ``opts.max_points``.

    Parameters
    ----------
    model, target, opts, target_normals
        As for :func:`icp_hmrf_register`.

    Returns
    -------
    _Scan
        The seen pixels of the thinned grid and the target's finite points, with a tree on them.

    Raises
    ------
    InputError
        As :func:`icp_hmrf_register`.
    """
    if model.ndim != 3 or model.shape[2] != 3:
        raise InputError(f"`model` must be an organized scan of shape (H, W, 3), got {model.shape}")
    tflat = target.reshape(-1, 3)
    tok = np.isfinite(tflat).all(1)
    tgt = np.ascontiguousarray(tflat[tok])
    tn = None
    if target_normals is not None:
        if np.shape(target_normals) != target.shape:
            raise InputError(f"`target_normals` must have shape {target.shape}, got {np.shape(target_normals)}")
        tn = np.asarray(target_normals, dtype=np.float64).reshape(-1, 3)[tok]
    hh, ww = model.shape[:2]
    stride = 1
    while (hh // stride) * (ww // stride) > opts.max_points:
        stride += 1
    grid = model[::stride, ::stride]
    seen = np.isfinite(grid).all(2)
    if seen.sum() < 3 or len(tgt) < 3:
        raise InputError("`model` and `target` need at least 3 seen points each")
    return _Scan(seen=seen, pts=grid[seen], tgt=tgt, tn=tn, tree=cKDTree(tgt))


def _start(scan: _Scan, opts: HMRFOptions, rng: np.random.Generator) -> Start:
    """The initial alignment of ``opts.init``, refined by a VarTrimmed robust ICP with ``opts.prealign``.

    Parameters
    ----------
    scan : _Scan
        The model's seen points and the target.
    opts : HMRFOptions
        The start's fields and ``prealign``.
    rng : numpy.random.Generator
        Draws the samples of the search and of the robust ICP.

    Returns
    -------
    Start
        The pose the field starts from, with the search's query bound.
    """
    icp_opts = opts.icp_options()
    start, _ = choose_start(scan.pts, scan.tgt, scan.tree, icp_opts, rng)
    if opts.prealign:
        # (init only steers which of the start's runners-up the coarse stage may pick)
        pre_opts = replace(icp_opts, init="features" if icp_opts.init == "features" else "given",
                           variant="point_to_plane", loss="trimmed", trim_ratio=None)
        pre = refine_icp(scan.pts, scan.tgt, scan.tree, start, pre_opts, rng, target_normals=scan.tn)
        start = Start(pre.matrix, start.bound)
    return start


def _first_params(d: np.ndarray, far: np.ndarray, floor: float) -> tuple[float, float, float]:
    """(sigma_in, mu_out, sigma_out) of the two components from the first iteration's distances ``d``.

    The inlier scale from the lower quartile of the distances within the query bound (``far``
    marks the others), the outlier component from their upper half; none below ``floor``.
    """
    near = d[~far] if (~far).sum() >= 3 else d
    lo = max(float(np.quantile(near, 0.25)) / 0.3186, floor)  # the half-normal's 25th percentile
    upper = near[near >= np.median(near)]
    return (lo, max(float(upper.mean()), lo), max(float(upper.std()), lo))


def _evidence(d: np.ndarray, far: np.ndarray, seen: np.ndarray, params: tuple[float, float, float]) -> np.ndarray:
    """log p_in(d_i) - log p_out(d_i) per seen pixel (H, W) under ``params``, clipped to [-50, 50].

    A pixel whose pair lies beyond the query bound (``far``) is an outlier for sure: -50.
    """
    sigma_in, mu_out, sigma_out = params
    evidence = np.zeros(seen.shape)
    ev = _log_half_normal(d, sigma_in) - _log_gauss(d, mu_out, sigma_out)
    evidence[seen] = np.where(far, -50.0, ev)
    return np.clip(evidence, -50.0, 50.0)


def _components(gamma: np.ndarray, d: np.ndarray, params: tuple[float, float, float],
                floor: float) -> tuple[float, float, float]:
    """M-step of the two components: (sigma_in, mu_out, sigma_out) weighted by the posteriors ``gamma``.

    A component without weight keeps its ``params``; no scale falls below ``floor``, and the
    outlier component's mean and width not below the inlier scale.
    """
    sigma_in, mu_out, sigma_out = params
    g_in, g_out = float(gamma.sum()), float((1.0 - gamma).sum())
    s_in = np.sqrt(float(gamma @ (d * d)) / max(g_in, 1e-12)) if g_in > 1e-9 else sigma_in
    s_in = max(s_in, floor)
    if g_out > 1e-9:
        mu = float((1.0 - gamma) @ d) / g_out
        var = float((1.0 - gamma) @ (d - mu) ** 2) / g_out
        mu_out, sigma_out = max(mu, s_in), max(np.sqrt(var), s_in)
    return (s_in, mu_out, sigma_out)


def _iterate(scan: _Scan, start: Start, opts: HMRFOptions, rng: np.random.Generator) -> RigidFit:
    """The HMRF-weighted ICP from ``start`` (module docstring): E-step by mean field, M-step, pose step.

    Parameters
    ----------
    scan : _Scan
        The model's seen points and the target.
    start : Start
        The initial pose and query bound.
    opts : HMRFOptions
        Field and ICP settings.
    rng : numpy.random.Generator
        Draws the sample of the target's spacing.

    Returns
    -------
    RigidFit
        As :func:`icp_hmrf_register`'s.
    """
    pts, tgt, tree, seen = scan.pts, scan.tgt, scan.tree, scan.seen
    radius = float(np.sqrt(np.mean(np.sum((pts - pts.mean(0)) ** 2, 1)))) or 1.0
    rot, t = start.matrix[:, :3].copy(), start.matrix[:, 3].copy()
    plane = opts.variant == "point_to_plane"
    normals = LazyNormals(tgt, tree, opts.k_normals, scan.tn) if plane else None
    floor = 1e-9 * radius
    spacing = point_spacing(tree, tgt, rng)
    bound = start.bound
    m_grid: np.ndarray | None = None
    params: tuple[float, float, float] | None = None
    prev: np.ndarray | None = None
    converged = False
    it = 0
    sigma_in = floor
    for it in range(1, opts.max_iter + 1):
        x = pts @ rot.T + t
        if prev is not None and np.sqrt(np.mean(np.sum((x - prev) ** 2, 1))) < opts.tol * radius:
            converged = True
            it -= 1
            break
        prev = x
        d, j = tree.query(x, distance_upper_bound=bound)
        d = np.asarray(d)
        far = ~np.isfinite(d)                        # beyond the query bound: an outlier for sure
        j = np.minimum(j, len(tgt) - 1)
        d = np.where(far, bound, d)
        if params is None:
            params = _first_params(d, far, floor)
        sigma_in = params[0]
        m_grid = mean_field(_evidence(d, far, seen, params), seen, opts.beta, opts.mf_sweeps, m_grid)
        gamma = 0.5 * (1.0 + m_grid[seen])
        params = _components(gamma, d, params, floor)
        s_in = params[0]
        bound = min(bound, max(_BOUND_SIGMAS * s_in, 4.0 * spacing))
        w = (gamma > 0.5).astype(np.float64) if opts.hard else gamma
        if (w > 1e-6).sum() < 6 or float(w.sum()) <= 0.0:
            break
        y = tgt[j]
        if plane and normals is not None:
            step, c, shift = plane_step(x, y, normals[j], w)
            t = step @ (t - c) + c + shift
            rot = step @ rot
        else:
            mm = point_step(pts, y, w, opts.solver)
            rot, t = mm[:, :3], mm[:, 3]
        sigma_in = s_in
    return RigidFit(matrix=np.c_[rot, t], n_iter=it, converged=converged, reach=max(3.0 * sigma_in, spacing))
