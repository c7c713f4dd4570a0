"""The L2E residual scale (the extrapolated fixed-point iteration lands where the plain one does), and regrowing."""
import numpy as np
import pytest

from reglib.robust._l2e import l2e_scale, scale_from_sorted


def _residuals(seed: int, spreads: tuple[float, ...], shares: tuple[float, ...], n: int = 800) -> np.ndarray:
    """Squared 2-D residuals: Gaussian clusters of the given spreads and shares, the rest uniform in 200 x 200."""
    rng = np.random.default_rng(seed)
    parts = [rng.normal(0.0, s, (int(n * w), 2)) for s, w in zip(spreads, shares, strict=True)]
    rest = n - sum(len(p) for p in parts)
    parts.append(rng.uniform(-100.0, 100.0, (rest, 2)))
    return (np.concatenate(parts) ** 2).sum(1)


@pytest.mark.parametrize("seed,spreads,shares", [(0, (1.0,), (0.5,)), (1, (0.5,), (0.1,)),
                                                  (2, (1.0, 8.0), (0.3, 0.3)), (3, (2.0, 20.0), (0.05, 0.6))])
@pytest.mark.parametrize("start", [0.01, 4.0, 400.0, 1e4])
def test_scale_sorted_reaches_the_plain_iterations_fixed_point(seed, spreads, shares, start):
    e2 = _residuals(seed, spreads, shares)
    plain = l2e_scale(e2, start, 2, n_iter=100_000)  # no extrapolation, run to convergence
    fast = scale_from_sorted(np.sort(e2), start, 2)
    assert fast == pytest.approx(plain, rel=2e-5)


def _bump_rows(src: np.ndarray, truth: np.ndarray) -> np.ndarray:
    from .conftest import BUMP_CENTRE
    return truth & (((src - BUMP_CENTRE) ** 2).sum(1) < 35.0**2)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("amp", [60.0, 80.0])
def test_regrow_follows_a_steep_bump_the_finer_levels_miss(seed, amp):
    from reglib.robust import L2EOptions, fit_matches

    from .conftest import make_bump_matches
    src, dst, _, truth, true_map = make_bump_matches(seed, amp=amp)
    rows = _bump_rows(src, truth)
    without = fit_matches(src, dst, method="l2e", options=L2EOptions(regrow=0), rng=0)
    grown = fit_matches(src, dst, method="l2e", options=L2EOptions(regrow=1), rng=0)
    # the levels' candidates are the matches near the coarse field: the bump's stay out
    assert without.inliers[rows].mean() < 0.3
    assert np.median(np.linalg.norm(without.transform(src[rows]) - true_map(src[rows]), axis=1)) > 10.0
    # regrowing takes them in, and no false match with them
    assert grown.inliers[rows].mean() > 0.9
    assert np.median(np.linalg.norm(grown.transform(src[rows]) - true_map(src[rows]), axis=1)) < 2.0
    assert np.count_nonzero(grown.inliers & ~truth) <= np.count_nonzero(without.inliers & ~truth)
    assert grown.inliers[truth].mean() > 0.97


def test_regrow_leaves_a_fit_without_a_missed_deformation_as_it_was(matches):
    from reglib.robust import L2EOptions, fit_matches
    src, dst, truth, _ = matches(n=600, outlier_rate=0.6, seed=4)
    a = fit_matches(src, dst, method="l2e", options=L2EOptions(regrow=0), rng=0)
    b = fit_matches(src, dst, method="l2e", options=L2EOptions(regrow=1), rng=0)
    assert np.array_equal(a.inliers, b.inliers)
    assert np.array_equal(a.transform(src), b.transform(src))


@pytest.mark.parametrize("share", [2, 3])
def test_regrow_does_not_follow_a_look_alike_group(share):
    # a half / a third of the matches in a disc are a texture period (+40 px) off, amid true matches of a smooth
    # field (one layer: a second one would keep such a group as its own layer, by design)
    from reglib.robust import L2EOptions, fit_matches
    rng = np.random.default_rng(5)
    src = rng.uniform(0.0, 500.0, (1000, 2))
    dst = src * 0.95 + np.array([20.0, 5.0]) + rng.normal(0.0, 0.5, src.shape)
    disc = np.flatnonzero(((src - np.array([250.0, 250.0])) ** 2).sum(1) < 90.0**2)[::share]
    dst[disc] += np.array([40.0, 0.0])
    fit = fit_matches(src, dst, method="l2e", options=L2EOptions(regrow=1, max_layers=1), rng=0)
    assert len(disc) >= 30
    assert not fit.inliers[disc].any()
    assert fit.inliers.sum() >= 0.97 * (len(src) - len(disc))
