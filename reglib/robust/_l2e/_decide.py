"""The last stage of the L2E fit: which matches are inliers, under the final field.

A heavy-tailed inlier model (two concentric Gaussians) against uniform false matches is fitted to the
final residuals by EM; the false matches' density is the one measured near the field when they crowd
a ring around it (look-alikes on a repeated texture, :func:`near_volume`), else uniform over the
image. The posterior of every match, the core widened by ``score_scale``, is its score.
"""
from __future__ import annotations

import numpy as np

from .._options import L2EOptions
from ._scale import SIGMA2_MIN, live
from ._state import Fit, State, subset

_TAIL_ITER = 10  # EM iterations of the inlier model at most (its tail's weight creeps on, deciding nothing)
_TAIL_TOL = 1e-4  # relative change of the variances at which its EM stops
# leverage at most (a share of the hat matrix's trace): a left-out residual is at most 20 times its fitted one
_MAX_LEVERAGE = 0.95

# The false matches' density near the field (:func:`near_volume`): residual rings sqrt(2) apart, in
# units of the sharpest residual scale. A ring population is a dip no nearer than ring _NEAR_FIRST
# (2.8 scales) followed by two rings holding at least _NEAR_RISE times the dip's count, _NEAR_MANY
# matches and _NEAR_SHARE of the residuals (a second, wider mode of true matches, as when a third of
# them are far less precise than the rest, holds fewer).
_NEAR_FIRST, _NEAR_RISE, _NEAR_MANY, _NEAR_SHARE = 3, 2.5, 25, 0.05
# A smaller ring, of _NEAR_FEW or more (few putatives: a T-shirt's 200), counts only with more
# evidence: more than uniform false matches would put there by chance (_NEAR_SIGNIFICANCE Poisson
# deviations), fewer than the core inside the dip (a ring that outnumbers the core may as well be the
# true matches) and at most as many as lie beyond it (look-alikes crowd near the field on top of false
# matches spread further; a ring with little beyond it is the end of the true matches' tail).
_NEAR_FEW, _NEAR_SIGNIFICANCE = 10, 3.0


def decide(state: State, opts: L2EOptions) -> Fit:
    """The :class:`Fit` of ``state``'s field: every match's score, the inliers and the inlier scale."""
    work = state.work
    n, d = work.u.shape
    e2 = ((work.y - state.model.predict(work.u)) ** 2).sum(1) if len(work.rows) < n else state.e2.copy()
    # The matches a finer level was fitted on pulled the field toward themselves: their residuals
    # are judged as if each had been left out (e / (1 - h), h its leverage), as the others are.
    # With about one centre per four matches the field otherwise shrinks the true matches'
    # residuals below their real spread and rejects the ones that are merely less precise. (The
    # coarse level is left as it is: stiff on many matches, and on a dozen the shared-out
    # leverage of its centres says little about any one of them.)
    if state.level is not None:
        solver, rows = state.level
        if (leverage := solver.leverage()) is not None:  # None: unknown (the solve fell back to least squares)
            e2[work.rows[rows]] /= (1.0 - np.minimum(leverage, _MAX_LEVERAGE)) ** 2
    sample = subset(np.arange(n), opts.max_fit_points, work.fixed)  # four scalars: a sample suffices
    local = near_volume(e2[sample], state.sharp2, d, work.volume)
    g1, s1, g2, s2 = _fit_tails(e2[sample], state.spread2, d, local)
    sigma2 = (g1 * s1 + g2 * s2) / (g1 + g2)  # the variance of the inlier mixture
    scores = _tail_posterior(e2, (g1, s1 * opts.score_scale**2, g2, s2), d, local)
    return Fit(state.model, scores, scores > opts.inlier_threshold, float(np.sqrt(sigma2)), state.n_iter,
               bool(state.converged), work.volume)


def near_volume(e2: np.ndarray, sharp2: float, d: int, volume: float) -> float:
    """Volume of the false matches' uniform density as it is near the field (at most ``volume``).

    False matches are not always uniform over the image: on a repeated texture (a printed or
    woven cloth, a facade) many pair a feature with a look-alike a few texture periods away, so
    their residuals crowd a ring around the field, far denser than 1 / ``volume``. A heavy
    inlier tail (:func:`_fit_tails`) would take that ring in. Counted in rings sqrt(2) apart (in
    units of the sharpest residual scale ``sharp2``), true residuals fall off from the core; a
    ring population shows as a dip followed by a steep rise (at least _NEAR_RISE times the dip's
    count in the next two rings, which uniform false matches alone give only when they are
    dense already). The density of those two rings is then taken as the false matches' density:
    the first ring of _NEAR_MANY matches or more denser than uniform, else the first smaller one that
    stands out from chance, holds fewer than the core and no more than lie beyond it.
    """
    r = np.sqrt(e2 / sharp2)
    edges = 2.0 ** (np.arange(16) / 2.0)
    counts = np.histogram(r, bins=edges)[0]
    rings = [(j, int(counts[j + 1] + counts[j + 2])) for j in range(_NEAR_FIRST, len(counts) - 2)
             if counts[j] <= counts[j - 1] and counts[j + 1] > counts[j]]
    rings = [(j, ring) for j, ring in rings
             if ring >= max(_NEAR_FEW, _NEAR_SHARE * len(e2)) and ring >= _NEAR_RISE * counts[j]]
    ball = np.pi if d == 2 else 4.0 / 3.0 * np.pi

    def density(j: int, ring: int) -> tuple[float, int]:
        """(the volume the ring's density stands for, the residuals from the ring outward)."""
        area = ball * (edges[j + 3] ** d - edges[j + 1] ** d) * sharp2 ** (d / 2.0)
        beyond = int(np.count_nonzero(r >= edges[j + 1]))
        return beyond * area / ring, beyond

    for j, ring in rings:
        if ring >= _NEAR_MANY and (near := density(j, ring)[0]) < volume:
            return near
    for j, ring in rings:
        near, beyond = density(j, ring)
        chance = ring * near / volume  # what uniform false matches put in the ring
        if ring >= chance + _NEAR_SIGNIFICANCE * np.sqrt(chance) + 1.0 and ring < len(r) - beyond \
                and ring <= beyond - ring:
            return min(volume, near)
    return volume


def _tail_posterior(e2: np.ndarray, params: tuple[float, float, float, float], d: int, volume: float) -> np.ndarray:
    """Posterior of the two inlier components (core + tail) against the uniform outliers."""
    g1, s1, g2, s2 = params
    core = g1 * np.exp(-e2 / (2.0 * s1)) / (2.0 * np.pi * s1) ** (d / 2.0)
    tail = g2 * np.exp(-e2 / (2.0 * s2)) / (2.0 * np.pi * s2) ** (d / 2.0)
    inlier = core + tail
    return inlier / (inlier + (1.0 - g1 - g2) / volume)


def _fit_tails(e2: np.ndarray, sigma2: float, d: int, volume: float,
               n_iter: int = _TAIL_ITER) -> tuple[float, float, float, float]:
    """Weights and variances of a heavy-tailed inlier model, fitted by EM with the transformation fixed.

    True feature-match residuals are not Gaussian: most are within a pixel or two, a minority
    (localization error at coarse scales, where the field is not quite followed) several times
    further. Two concentric Gaussians, a core and a tail three times wider at the start, against
    the uniform density of false matches, model that; the tail only takes weight where there are
    more residuals near zero than the uniform term explains.
    """
    g1, s1, g2, s2 = 0.4, sigma2, 0.1, 9.0 * sigma2
    e2_sorted = np.sort(np.asarray(e2, dtype=float))  # (the sums run over the live prefix)
    m = len(e2_sorted)
    core_buf, tail_buf, total_buf = np.empty(m), np.empty(m), np.empty(m)
    for _ in range(n_iter):
        c1 = g1 / (2.0 * np.pi * s1) ** (d / 2.0)
        c2 = g2 / (2.0 * np.pi * s2) ** (d / 2.0)
        j = live(e2_sorted, max(s1, s2))  # (the uniform term is positive: g1 + g2 < 1)
        e2, core, tail, total = e2_sorted[:j], core_buf[:j], tail_buf[:j], total_buf[:j]
        np.multiply(e2, -0.5 / s1, out=core)
        np.exp(core, out=core)
        core *= c1
        np.multiply(e2, -0.5 / s2, out=tail)
        np.exp(tail, out=tail)
        tail *= c2
        np.add(core, tail, out=total)
        total += (1.0 - g1 - g2) / volume
        core /= total
        tail /= total
        n1, n2 = float(core.sum()), float(tail.sum())
        if n1 <= 1e-12:
            break
        new_s1 = max(float(core @ e2) / (d * n1), SIGMA2_MIN)
        # The tail is two to five times as wide as the core: it must neither duplicate the core
        # nor spread into a second, uniform-like component that would take in false matches.
        new_s2 = min(max(float(tail @ e2) / (d * max(n2, 1e-12)), 4.0 * new_s1), 25.0 * new_s1)
        g1 = min(max(n1 / m, 1e-3), 1.0 - 2e-3)
        g2 = min(max(n2 / m, 1e-6), 1.0 - g1 - 1e-3)
        done = abs(new_s1 - s1) <= _TAIL_TOL * s1 and abs(new_s2 - s2) <= _TAIL_TOL * s2
        s1, s2 = new_s1, new_s2
        if done:
            break
    return g1, s1, g2, s2
