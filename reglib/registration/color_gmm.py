"""Colour-assisted probabilistic rigid registration (Danelljan, Meneghetti, Khan, Felsberg [1]).

Both point sets are observations of one latent scene, a mixture of K spatial Gaussians in which
every component also carries its own colour distribution: a point x with colour c is drawn from

    p(x, c) = (1 - gamma) sum_k pi_k N(x; mu_k, sigma_k^2 I) p(c | k) + gamma U(x) U(c),
    p(c | k) = sum_l rho_kl B_l(c),

the colour of a point being independent of its position given its component [1, Sec. 3]. The
B_l are fixed colour basis densities (here soft bins on a regular grid over the RGB cube, see
:func:`reglib.registration._mixture.colour_basis`), the rho_kl the colour weights learned per
component. EM estimates the scene (mu, sigma, pi, rho) and the model's rigid motion jointly
[1, Sec. 4]: the E-step's posteriors use colour and geometry together, so a point is pulled
towards components of its own colour; the motion's M-step is the weighted Procrustes step of the
joint registration of Evangelidis et al. [2]; the target's motion stays the identity.

Where geometry alone is ambiguous (a planar floor or wall slides in its plane), the colour
distributions of the components pin the motion down.

Subsampling: EM runs on at most ``max_points`` points of each set, picked on a voxel grid
(one point per occupied voxel, the edge found by bisection, carrying the mean colour of its
voxel; deterministic for a given ``rng``),
so its posteriors are (max_points, n_components) matrices: memory O(max_points * n_components),
independent of the input size. The motion found applies to every point.

References
----------
.. [1] M. Danelljan, G. Meneghetti, F. S. Khan, M. Felsberg, "A Probabilistic Framework for
       Color-Based Point Set Registration", CVPR 2016. :doi:`10.1109/CVPR.2016.201`
.. [2] G. D. Evangelidis, R. Horaud, "Joint Alignment of Multiple Point Sets with Batch and
       Incremental Expectation-Maximization", IEEE TPAMI 40(6), 2018.
       :doi:`10.1109/TPAMI.2017.2717829`
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import check_int, check_range
from ..errors import InputError
from ._mixture import (
    colour_basis,
    equalize_colours,
    normalize_pair,
    scene_em,
    subsample_with_means,
)
from .rigid import RigidFit

__all__ = ["ColorGMMOptions", "color_gmm_register"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ColorGMMOptions:
    """Options of ``register_points(method="color-gmm")``.

    Lengths are in normalized units (each set centred on its mean, both divided by the larger RMS
    radius).

    Parameters
    ----------
    n_components : int
        Components K of the scene mixture, placed initially on a voxel-grid sample of the target
        (K in [1]; 2 to 3000). 150 with 1000 points: on the benchmark's planar Kinect patches
        300 components with 1500 points were no more accurate and three times slower.
    luminance_bins, chroma_bins : int
        Colour basis functions along the luminance axis and along each of the two chroma axes
        (red-green, yellow-blue); the basis has ``luminance_bins * chroma_bins**2`` soft bins
        (the B_l of [1]; 1 to 16 each). Luminance carries most of the texture of indoor scans,
        hence the finer grid (8 levels: on a synthetic painted plane shifted by a tenth of its
        width, 4 levels left 3 % of the shift, 8 recovered it exactly).
    outlier : float
        Weight of the uniform outlier class (gamma above), in [0, 1).
    max_iter : int
        EM iterations at most (1 to 1000).
    tol : float
        EM stops when the motion changes by less than ``tol`` (radians plus normalized units)
        in two successive iterations.
    max_points : int
        Points of each set EM uses at most (voxel-grid subsample beyond it, each kept point
        carrying the mean colour of its voxel; 10 to 3000).
    equalize : bool
        Map the colours to opponent channels (luminance, red-green, yellow-blue), the luminance
        equalized by its empirical CDF over both sets together, before the colour basis;
        otherwise the basis sees raw RGB.
    """

    n_components: int = 150
    luminance_bins: int = 8
    chroma_bins: int = 3
    outlier: float = 0.05
    max_iter: int = 100
    tol: float = 1e-5
    max_points: int = 1000
    equalize: bool = True

    def __post_init__(self) -> None:
        check_int("n_components", self.n_components, 2, 3000)
        check_int("luminance_bins", self.luminance_bins, 1, 16)
        check_int("chroma_bins", self.chroma_bins, 1, 16)
        check_range("outlier", self.outlier, 0, 1, high_open=True)
        check_int("max_iter", self.max_iter, 1, 1000)
        check_range("tol", self.tol, 0, low_open=True)
        check_int("max_points", self.max_points, 10, 3000)
        if not isinstance(self.equalize, (bool, np.bool_)):
            raise InputError(f"`equalize` must be a bool, got {self.equalize!r}")


def color_gmm_register(model: np.ndarray, target: np.ndarray, opts: ColorGMMOptions,
                       rng: np.random.Generator, *, model_colors: np.ndarray,
                       target_colors: np.ndarray) -> RigidFit:
    """Rigidly register coloured ``model`` points onto coloured ``target`` points.

    Parameters
    ----------
    model, target : (N, D), (M, D) ndarray
        Trusted finite float64 points (x, y[, z]), D in {2, 3}, in the caller's units.
    opts : ColorGMMOptions
        The method's options.
    rng : numpy.random.Generator
        Source of the subsampling's random choices (the same seed gives the same answer).
    model_colors, target_colors : (N, 3), (M, 3) ndarray
        RGB colours in [0, 1] of the model and target points, row for row.

    Returns
    -------
    RigidFit
        ``matrix`` = ``[R | t]`` (D, D + 1) with x -> R x + t taking the model onto the target;
        ``reach`` three times the final RMS component width (at least 1 % of the scale).

    References
    ----------
    .. [1] M. Danelljan et al., "A Probabilistic Framework for Color-Based Point Set
           Registration", CVPR 2016. :doi:`10.1109/CVPR.2016.201`

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(-1, 1, (400, 2))
    >>> pts = np.c_[xy, np.zeros(400)]                  # a flat, featureless plane ...
    >>> col = np.c_[(xy[:, 0] > 0) * 0.9, (xy[:, 1] > 0) * 0.9, np.full(400, 0.5)]  # ... painted
    >>> moved = pts + [0.15, -0.1, 0.0]                 # slid within its own plane
    >>> fit = color_gmm_register(pts, moved, ColorGMMOptions(), rng, model_colors=col,
    ...                          target_colors=col)
    >>> bool(np.allclose(fit.matrix[:, 3], [0.15, -0.1, 0.0], atol=0.02))
    True
    """
    iu, col_u = subsample_with_means(model, np.clip(model_colors, 0.0, 1.0), opts.max_points, rng)
    iv, col_v = subsample_with_means(target, np.clip(target_colors, 0.0, 1.0), opts.max_points, rng)
    norm = normalize_pair(model[iu], target[iv])
    if opts.equalize:
        col_u, col_v = equalize_colours([col_u, col_v])
    bins = (opts.luminance_bins, opts.chroma_bins, opts.chroma_bins)
    cu = colour_basis(col_u, bins)
    cv = colour_basis(col_v, bins)
    fit = scene_em(norm.u, norm.v, n_components=opts.n_components, max_iter=opts.max_iter,
                   tol=opts.tol, outlier=opts.outlier, rng=rng, colour_u=cu, colour_v=cv)
    return norm.rigid_fit(fit.rot, fit.trans, float(np.sqrt(fit.sigma2)), fit.n_iter, fit.converged)
