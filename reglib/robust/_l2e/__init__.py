"""The L2E estimator of a non-rigid transformation in an RKHS (Ma et al., CVPR 2013; IEEE TSP 2015).

Residuals of true matches are modelled as N(0, sigma^2 I); the estimate minimizes the L2 distance
between that density and the residuals' empirical density, which for a fixed sigma amounts to
maximizing sum_i phi_i, phi_i = exp(-|e_i|^2 / 2 sigma^2), minus an RKHS smoothness penalty. An
outlier's influence is bounded (phi_i -> 0), so it is ignored rather than followed.

Solver (ours; the papers use quasi-Newton): iteratively re-weighted least squares, where each step
is the stationarity condition of the criterion with phi held at the current estimate ([1]), with
deterministic annealing of sigma^2 as in the published code. A global linear part (affine, or a
homography for images) is estimated jointly with the kernel residual under the same criterion.
:func:`l2e_fit` reads as its stages, one private module each:

1. ``_start``: the work subset, the coarse basis and the best of a few deterministic first estimates;
2. ``_anneal``: the coarse level, annealed from that start; then the residual scales: the sharp one
   by the partial L2E criterion of Scott [2] (``_scale``: minimizing over the inlier weight gives the
   fixed point sigma^2 = 2 sum phi|e|^2 / (D sum phi)), and the true matches' spread by a mixture;
3. ``_levels``: finer levels (more centres, a narrower kernel) on the candidates the field selects,
   then the regrown level over a steep deformation the candidates left out;
4. ``_decide``: a heavy-tailed inlier model against uniform false matches, fitted by EM to the final
   residuals, gives every match's score.

``_state`` holds what they hand each other; ``_reweight`` the fit at a fixed scale that every stage
(and the shape-context registration) uses. Normalized coordinates, trusted arrays.

References
----------
.. [1] J. Ma, W. Qiu, J. Zhao, Y. Ma, A. L. Yuille, Z. Tu, "Robust L2E Estimation of Transformation
       for Non-Rigid Registration", IEEE Trans. Signal Processing 63(5), 2015.
       :doi:`10.1109/TSP.2014.2388434`
.. [2] D. W. Scott, "Parametric Statistical Modeling by Minimum Integrated Square Error",
       Technometrics 43(3), 2001. :doi:`10.1198/004017001316975899`
"""
from ._decide import near_volume
from ._fit import l2e_fit
from ._layer import with_layer
from ._reweight import reweighted_fit
from ._scale import l2e_scale, scale_from_sorted
from ._state import Fit

# reweighted_fit and l2e_scale are also the building blocks of reglib.registration's rounds.
__all__ = ["Fit", "l2e_fit", "l2e_scale", "near_volume", "reweighted_fit", "scale_from_sorted", "with_layer"]
