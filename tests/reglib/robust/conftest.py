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


BUMP_CENTRE = np.array([150.0, 200.0])


def bump(points, amp=60.0, width=40.0):
    """A steep Gaussian bump of displacement (amp, amp / 2) px around BUMP_CENTRE (a local stretch up to ~0.9)."""
    g = np.exp(-((points - BUMP_CENTRE) ** 2).sum(1) / (2.0 * width**2))
    return g[:, None] * np.array([amp, amp / 2.0])


def make_bump_matches(seed=0, n_true=600, n_false=600, amp=60.0, width=40.0):
    """True matches of a similarity plus :func:`bump` (0.5 px noise) and uniform false ones in a 500 px box.

    Returns src, dst, the similarity's predictions at src (a field that misses the bump), the truth mask and the
    true map.
    """
    rng = np.random.default_rng(seed)
    src = rng.uniform(0.0, 500.0, (n_true + n_false, 2))

    def true_map(p):
        return p * 1.05 + np.array([10.0, -5.0]) + bump(p, amp, width)

    smooth = src * 1.05 + np.array([10.0, -5.0])
    dst = true_map(src) + rng.normal(0.0, 0.5, src.shape)
    dst[n_true:] = rng.uniform(0.0, 520.0, (n_false, 2))
    return src, dst, smooth, np.arange(len(src)) < n_true, true_map


@pytest.fixture
def matches():
    return make_matches
