"""The L2E residual scale: the extrapolated fixed-point iteration lands where the plain one does."""
import numpy as np
import pytest

from reglib.robust.l2e import l2e_scale, scale_from_sorted


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
