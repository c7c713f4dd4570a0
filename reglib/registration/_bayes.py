"""Robust variational Bayesian rigid registration with a Student-t mixture (Zhou et al. [1]).

The target points x_n are explained by a mixture whose components sit on the moved model points
R y_m + t, each a Student-t (heavy tails: a point far from every component barely moves the fit),
plus a uniform class for outliers. Following [1], the mixing proportions, the precision of the
components, the outlier share and the translation are latent variables with priors; variational
inference alternates the updates of their posteriors:

- q(z_n, u_n): the component (or the outlier class) of every target point and, per component,
  the Gamma-distributed scale u of the Student-t written as a Gaussian scale mixture;
  E[u_nm] = (nu + D) / (nu + tau E|x_n - R y_m - t|^2);
- q(pi) = Dirichlet(alpha_0 + N_m): mixing proportions, so a model point with no partner
  (missing correspondence) loses weight instead of pulling;
- q(w) = Beta: the outlier share, learned (no fixed w as in CPD);
- q(tau) = Gamma: the components' common precision (the inverse variance);
- q(t) = Gaussian: the translation, whose covariance enters the expected residuals;
- the rotation R: the point estimate maximizing the variational bound, a weighted Procrustes step
  with weights E[z_nm] E[u_nm];
- the degrees of freedom nu: the value maximizing the bound (a scalar root), when
  ``update_dof``.

As in [1]'s cooling schedule, the Gamma prior on the precision anneals: its mean variance
starts at the data's spread and its weight at half the data's, both shrinking geometrically by
``anneal`` per iteration, which keeps early iterations coarse (wide components) and leaves later
ones to the data.

Subsampling: inference runs on at most ``max_points`` points of each set (deterministic for a
given ``rng``): the model's on a voxel grid (one point per occupied voxel, the edge found by
bisection), so the components cover its surface evenly; the target's drawn uniformly at random,
so the observations keep their share of outliers (a voxel grid favors scattered outliers over
a dense surface, raising their share). Memory O(max_points^2). The motion found applies to
every point.

References
----------
.. [1] J. Zhou, X. Ma, L. Liang, Y. Yang, S. Xu, Y. Liu, S.-H. Ong, "Robust Variational Bayesian
       Point Set Registration", ICCV 2019. :doi:`10.1109/ICCV.2019.00105`
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.spatial.distance import cdist
from scipy.special import digamma, gammaln

from ..options import declared, option
from ._em import EMOptions, with_default
from ._mixture import rotation_angle, sample_pair, start_pose
from ._procrustes import umeyama
from ._rigid import RigidFit

__all__ = ["BayesOptions", "bayes_register"]

_VAR_MIN = 1e-10


@declared
@dataclass(frozen=True, slots=True, kw_only=True)
class BayesOptions(EMOptions):
    """Options of ``register_points(method="bayes")``.

    The fields of :class:`~reglib.registration._em.EMOptions` (``max_iter``, default 150;
    ``tol``, default 1e-4; ``max_points``: beyond it a voxel-grid subsample of the model and a
    uniform random one of the target; ``init`` and its settings: the start, by default the
    centroids aligned), and the priors. Lengths are in normalized units (each set
    centered on its mean, both divided by the larger RMS radius).

    Parameters
    ----------
    dof : float
        Degrees of freedom nu of the Student-t components at the start (nu in [1]; small is
        heavy-tailed, large Gaussian); in (0, 1000].
    update_dof : bool
        Re-estimate nu every iteration (maximizing the variational bound).
    alpha0 : float
        Dirichlet prior count of every mixing proportion (alpha_0 in [1]); > 0.
    outlier_prior : float
        Prior mean of the outlier share, in (0, 1); its Beta prior is worth 1 + N anneal^it
        observations at iteration it (annealed like the precision's prior).
    anneal : float
        Factor in (0, 1) by which the precision prior's mean variance and weight shrink per
        iteration (small: little annealing).
    """

    max_iter: int = with_default("max_iter", 150)
    tol: float = with_default("tol", 1e-4)
    dof: float = option(3.0, kind="float", low=0, high=1000, low_open=True,
                        doc="degrees of freedom nu of the Student-t components at the start")
    update_dof: bool = option(True, kind="bool", doc="re-estimate nu every iteration")
    alpha0: float = option(1.0, kind="float", low=0, low_open=True,
                           doc="Dirichlet prior count of every mixing proportion")
    outlier_prior: float = option(0.1, kind="float", low=0, high=1, low_open=True, high_open=True,
                                  doc="prior mean of the outlier share, in (0, 1)")
    anneal: float = option(0.9, kind="float", low=0, high=1, low_open=True, high_open=True,
                           doc="per-iteration shrink factor of the precision prior, in (0, 1)")


def _dof_update(nu: float, d: int, r: np.ndarray, tau_d2: np.ndarray) -> float:
    """nu maximizing the bound: log(nu/2) - psi(nu/2) + 1 + <E log u - E u> = 0, clipped to [0.5, 1000]."""
    total = float(r.sum())
    if total <= 1e-12:
        return nu
    a = (nu + d) / 2.0
    b = (nu + tau_d2) / 2.0
    mean_term = float((r * (digamma(a) - np.log(b) - a / b)).sum()) / total

    def f(v: float) -> float:
        return float(np.log(v / 2.0) - digamma(v / 2.0) + 1.0 + mean_term)

    lo, hi = 0.5, 1000.0
    if f(lo) * f(hi) > 0:
        return lo if abs(f(lo)) < abs(f(hi)) else hi
    return float(brentq(f, lo, hi, xtol=1e-4))


def bayes_register(model: np.ndarray, target: np.ndarray, opts: BayesOptions,
                   rng: np.random.Generator) -> RigidFit:
    """Rigidly register ``model`` onto ``target`` by variational inference in a Student-t mixture.

    Parameters
    ----------
    model, target : (N, D), (M, D) ndarray
        Trusted finite float64 points (x, y[, z]), D in {2, 3}, in the caller's units.
    opts : BayesOptions
        The method's options.
    rng : numpy.random.Generator
        Source of the subsampling's random choices (the same seed gives the same answer).

    Returns
    -------
    RigidFit
        ``matrix`` = ``[R | t]`` (D, D + 1) with x -> R x + t taking the model onto the target;
        ``reach`` three times the posterior mean component width (at least 1 % of the scale).

    References
    ----------
    .. [1] J. Zhou et al., "Robust Variational Bayesian Point Set Registration", ICCV 2019.
           :doi:`10.1109/ICCV.2019.00105`

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    >>> model = np.c_[np.cos(t) + 0.4 * np.cos(2 * t), np.sin(t) + 0.3 * np.sin(3 * t)]
    >>> a = np.deg2rad(30.0)
    >>> rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    >>> target = np.r_[model @ rot.T + [1.0, 2.0], rng.uniform(-1, 3, (100, 2))]  # 1/3 outliers
    >>> fit = bayes_register(model, target, BayesOptions(), rng)
    >>> bool(np.allclose(fit.matrix, np.c_[rot, [1.0, 2.0]], atol=0.02))
    True
    """
    start = start_pose(model, target, opts, rng)
    norm = sample_pair(model, target, opts.max_points, rng, ("voxel", "random"))
    y, x = norm.u, norm.v  # components from the model, observations from the target
    m, d = y.shape
    n = len(x)
    volume = float(np.prod(np.maximum(x.max(0) - x.min(0), 1e-3)))
    pose = norm.from_caller(start)
    rot, t_mean, t_var = pose.rot, pose.trans, 0.0
    # Priors: an annealed Gamma on tau (below), its mean variance the data's spread about the start
    # (or the start's own variance when it knows it); Beta on the outlier share; Dirichlet(alpha0)
    # on the proportions; a vague Gaussian N(0, 1e6 I) on t.
    var0 = max(float(cdist(x, y @ rot.T + t_mean if start is not None else y, "sqeuclidean").mean()) / d,
               _VAR_MIN)
    if pose.var is not None:
        var0 = max(min(var0, pose.var), _VAR_MIN)
    w_a0, w_b0 = opts.outlier_prior, 1.0 - opts.outlier_prior
    t_prec0 = 1e-6
    a_tau, b_tau = 1.0, var0
    e_log_pi = np.full(m, -np.log(m))
    e_log_w, e_log_1w = np.log(opts.outlier_prior), np.log1p(-opts.outlier_prior)
    nu = float(opts.dof)
    still = 0
    converged = False
    it = 0
    for it in range(1, opts.max_iter + 1):
        tau = a_tau / b_tau
        e_log_tau = float(digamma(a_tau) - np.log(b_tau))
        ty = y @ rot.T + t_mean
        d2 = cdist(x, ty, "sqeuclidean")
        d2 += d * t_var
        tau_d2 = tau * d2
        # log q(z_n = m) up to a constant: E log pi_m + E log(1 - w) + E log St(x_n; R y_m + t, tau, nu)
        logr = np.log1p(tau_d2 / nu)
        logr *= -(nu + d) / 2.0
        logr += e_log_pi + e_log_1w + (gammaln((nu + d) / 2.0) - gammaln(nu / 2.0)
                                       - d / 2.0 * np.log(nu * np.pi) + d / 2.0 * e_log_tau)
        log_out = e_log_w - np.log(volume)
        top = np.maximum(logr.max(1, keepdims=True), log_out)
        r = np.exp(logr - top)
        den = r.sum(1, keepdims=True) + np.exp(log_out - top)
        r /= den
        r_in = r.sum(1)  # (N,) probability of being an inlier
        e_u = (nu + d) / (nu + tau_d2)
        if opts.update_dof:
            nu = _dof_update(nu, d, r, tau_d2)
        wts = r * e_u  # (N, M)
        total = float(wts.sum())
        if total <= 1e-12:
            break
        # Rotation (point estimate) and translation posterior from the weighted pairs: the pairs'
        # cross-covariance is that of each target point with its weighted mean partner.
        wx, wy = wts.sum(1), wts.sum(0)
        mx, my = wx @ x / total, wy @ y / total
        live = wx > 1e-12 * total
        partner = (wts[live] @ y) / wx[live, None]
        new_rot = umeyama(partner, x[live], wx[live])[:, :d]
        prec = tau * total + t_prec0
        new_t = tau * total * (mx - new_rot @ my) / prec
        t_var_new = 1.0 / prec
        change = rotation_angle(new_rot @ rot.T) + float(np.linalg.norm(new_t - t_mean))
        rot, t_mean, t_var = new_rot, new_t, t_var_new
        # Expected weighted squared residual under the new motion, from moments (no new N x M).
        xc, yc = x - mx, y - my
        cross = float(np.sum((xc[live] * wx[live, None]) * ((partner - my) @ new_rot.T)))
        resid = (float(wx @ (xc * xc).sum(1)) + float(wy @ (yc * yc).sum(1)) - 2.0 * cross
                 + total * float(np.sum((mx - new_rot @ my - t_mean) ** 2)) + total * d * t_var)
        resid = max(resid, total * d * _VAR_MIN)
        # Precision: Gamma prior with mean 1 / (var0 anneal^it) and weight (half the data's at
        # first) decaying by anneal^it: early iterations stay coarse, later ones follow the data.
        cool = opts.anneal**it
        a0 = 1e-3 + cool * d * n / 4.0
        b0 = a0 * var0 * cool
        a_tau = a0 + d / 2.0 * float(r_in.sum())
        b_tau = b0 + resid / 2.0
        # Proportions and outlier share.
        alpha = opts.alpha0 + r.sum(0)
        e_log_pi = digamma(alpha) - digamma(alpha.sum())
        # The Beta prior is annealed like the precision's: worth the data at first, so that while
        # the components are still wide the uniform class cannot claim every point.
        strength = 1.0 + cool * n
        w_a = w_a0 * strength + float(n - r_in.sum())
        w_b = w_b0 * strength + float(r_in.sum())
        e_log_w, e_log_1w = float(digamma(w_a) - digamma(w_a + w_b)), float(digamma(w_b) - digamma(w_a + w_b))
        still = still + 1 if change < opts.tol else 0
        if still >= 2:
            converged = True
            break
    return norm.rigid_fit(rot, t_mean, float(np.sqrt(b_tau / a_tau)), it, converged)
