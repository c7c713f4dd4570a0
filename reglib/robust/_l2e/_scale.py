"""Residual scales with the transformation held fixed: L2E's (the sharpest cluster) and a mixture's (its spread).

Every function works on squared residual norms ``e2`` in normalized units (trusted arrays).
"""
from __future__ import annotations

import numpy as np

SIGMA2_MIN = 1e-10  # floor of every variance estimate, normalized units (about 0.004 px for a 1000 px image)

# A residual with e2 > _DEAD * s has exp(-e2 / 2 s) == 0.0 exactly (below exp(-745)): it adds
# nothing to any sum of the EM fits, which therefore work on the sorted residuals' live prefix only
# (with many false matches, most of them are dead at the final widths).
_DEAD = 1500.0


def live(e2_sorted: np.ndarray, s: float) -> int:
    """Residuals of ``e2_sorted`` (ascending) that a Gaussian of variance ``s`` does not underflow on."""
    return int(np.searchsorted(e2_sorted, _DEAD * s, side="right"))


def l2e_scale(e2: np.ndarray, sigma2: float, d: int, n_iter: int = 100) -> float:
    """Residual scale by the partial-L2E criterion with the transformation held fixed.

    Minimizing Scott's partial L2E over the inlier weight and sigma gives the fixed point
    sigma^2 = 2 sum phi |e|^2 / (D sum phi), phi = exp(-|e|^2 / 2 sigma^2): the scale of the
    dominant cluster of residuals, unaffected by far-away ones. The model is not re-fitted
    while sigma moves, so it cannot chase a few points it interpolates.
    """
    phi, weighted = np.empty_like(e2, dtype=float), np.empty_like(e2, dtype=float)
    for _ in range(n_iter):
        np.divide(e2, -2.0 * sigma2, out=phi)  # -e2 / (2 sigma2), in one pass
        np.exp(phi, out=phi)
        sp = float(phi.sum())
        if sp <= 1e-300:
            return sigma2
        np.multiply(phi, e2, out=weighted)
        new = max(2.0 * float(weighted.sum()) / (d * sp), SIGMA2_MIN)
        if abs(new - sigma2) <= 1e-6 * sigma2:
            return new
        sigma2 = new
    return sigma2


def scale_from_sorted(e2_sorted: np.ndarray, sigma2: float, d: int, n_iter: int = 100) -> float:
    """:func:`l2e_scale` of residuals sorted ascending (its fixed point, summed over the live ones).

    The map sigma^2 -> 2 sum phi e^2 / (D sum phi) is increasing (its derivative is a variance over
    the weights phi), so the iterates move monotonically to the nearest fixed point, at a linear
    rate that is often slow (20-100 iterations). After every two steps the sequence is
    extrapolated (Aitken's delta-squared, assuming the second step's ratio to the first persists)
    when both go the same way and the second is shorter (ratio below 0.95); the stopping test is
    the plain iteration's, at an extrapolated point as at any other."""
    phi, weighted = np.empty_like(e2_sorted), np.empty_like(e2_sorted)
    before: float | None = None  # the iterate one step back, on every other step
    for _ in range(n_iter):
        j = live(e2_sorted, sigma2)
        e2, ph, wt = e2_sorted[:j], phi[:j], weighted[:j]
        np.divide(e2, -2.0 * sigma2, out=ph)  # -e2 / (2 sigma2), in one pass
        np.exp(ph, out=ph)
        sp = float(ph.sum())
        if sp <= 1e-300:
            return sigma2
        np.multiply(ph, e2, out=wt)
        new = max(2.0 * float(wt.sum()) / (d * sp), SIGMA2_MIN)
        if abs(new - sigma2) <= 1e-6 * sigma2:
            return new
        if before is None:
            before, sigma2 = sigma2, new
            continue
        d1, d2 = sigma2 - before, new - sigma2
        before, sigma2 = None, new
        if d1 * d2 > 0.0 and abs(d2) < 0.95 * abs(d1):
            rate = d2 / d1
            jump = new + d2 * rate / (1.0 - rate)
            if jump > SIGMA2_MIN:
                sigma2 = jump
    return sigma2


def mixture_scale(e2_sorted: np.ndarray, sigma2: float, d: int, volume: float, n_iter: int = 100) -> float:
    """sigma^2 of the inlier component of a Gaussian-inlier / uniform-outlier mixture fitted to
    residuals sorted ascending, with the transformation held fixed.

    Residuals of true matches ~ N(0, sigma^2 I), of false ones uniform over ``volume`` (the extent
    of the dst points); sigma and the inlier share gamma are fitted by EM starting from the L2E
    scale. L2E's own scale is the width of the sharpest cluster of residuals, which for real
    feature matches (heavy-tailed localization error, some model misfit) is far narrower than the
    spread of true matches; the mixture's maximum-likelihood sigma covers that spread while the
    uniform term keeps far-away residuals out. (The E-step is
    :func:`reglib.robust._core.mixture_posterior`'s arithmetic; a dead residual's posterior is 0.)
    """
    gamma = 0.5
    m = len(e2_sorted)
    inlier, weighted = np.empty_like(e2_sorted), np.empty_like(e2_sorted)
    for _ in range(n_iter):
        outlier = (1.0 - gamma) * (2.0 * np.pi * sigma2) ** (d / 2.0) / volume
        j = live(e2_sorted, sigma2) if outlier > 0.0 else m
        e2, inl, wt = e2_sorted[:j], inlier[:j], weighted[:j]
        np.divide(e2, -2.0 * sigma2, out=inl)
        np.exp(inl, out=inl)
        inl *= gamma
        np.add(inl, outlier, out=wt)
        np.divide(inl, wt, out=inl)  # the posterior
        sp = float(inl.sum())
        if sp <= 1e-12:
            break
        np.multiply(inl, e2, out=wt)
        new = max(float(wt.sum()) / (d * sp), SIGMA2_MIN)
        gamma = min(max(sp / m, 1e-3), 1.0 - 1e-3)
        done = abs(new - sigma2) <= 1e-6 * sigma2
        sigma2 = new
        if done:
            break
    return sigma2


def scales(e2: np.ndarray, start: float, d: int, volume: float) -> tuple[float, float]:
    """The sharp scale (:func:`scale_from_sorted`, from ``start``) and the spread (:func:`mixture_scale`)
    of the squared residuals ``e2``, as variances."""
    e2_sorted = np.sort(e2)
    sharp2 = scale_from_sorted(e2_sorted, start, d)
    return sharp2, mixture_scale(e2_sorted, sharp2, d, volume)
