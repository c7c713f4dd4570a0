import numpy as np
import pytest


def make_matches(n=400, outlier_rate=0.5, dim=2, seed=0, noise=0.5, box=500.0):
    """Putative matches from a known smooth non-rigid map with uniform outliers.

    Returns src, dst, the truth mask (True = real match) and the map itself.
    """
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, box, (n, dim))
    angle = np.deg2rad(12.0)
    rot = np.eye(dim)
    rot[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    centre = np.full(dim, box / 2)

    def true_map(p):
        p = np.asarray(p, dtype=float)
        bend = 0.04 * box * np.sin(2 * np.pi * p[:, ::-1] / (0.8 * box))
        return (p - centre) @ rot.T * 1.1 + centre + [15.0] * dim + bend

    dst = true_map(src) + rng.normal(0, noise, src.shape)
    bad = rng.random(n) < outlier_rate
    dst[bad] = rng.uniform(0, box, (int(bad.sum()), dim))
    return src, dst, ~bad, true_map


@pytest.fixture
def matches():
    return make_matches
