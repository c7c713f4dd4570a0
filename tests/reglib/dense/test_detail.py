"""Tests of reglib.dense._detail: the narrow-kernel lattice fit over a smooth fit. Fields are made here with known
values: a narrow bump that a wide kernel cannot follow."""
from __future__ import annotations

import numpy as np

from reglib import KernelWarp
from reglib.dense._detail import detailed
from reglib.robust import filter_matches

SHAPE = (240, 320)
CENTRE = np.array([160.0, 120.0])


def _bump(p: np.ndarray) -> np.ndarray:
    """A shift plus one narrow bump (sigma 18 px, 12 px high): the true map a -> b."""
    g = np.exp(-np.sum((p - CENTRE) ** 2, axis=1) / (2 * 18.0**2))
    return p + np.array([5.0, -3.0]) + 12.0 * g[:, None] * np.array([1.0, 0.5])


def _grid(step: float = 8.0) -> np.ndarray:
    ys, xs = np.mgrid[4:SHAPE[0]:step, 4:SHAPE[1]:step]
    return np.c_[xs.ravel(), ys.ravel()].astype(float)


def _smooth(src: np.ndarray, dst: np.ndarray) -> KernelWarp:
    """A wide-kernel fit: the dense stage's kind of smooth estimate (a coarse basis only)."""
    return filter_matches(src, dst, options={"max_centers": 0, "beta": 0.3}, rng=0).transform


def test_detailed_follows_a_narrow_bump_the_smooth_fit_misses():
    src = _grid()
    dst = _bump(src)
    smooth = _smooth(src, dst)
    near = np.linalg.norm(src - CENTRE, axis=1) < 30
    before = np.linalg.norm(smooth(src[near]) - dst[near], axis=1).mean()
    assert before > 1.5  # the wide kernel does not follow the bump
    fine = detailed(smooth, src, dst, SHAPE, 8.0)
    probe = _grid(5.0) + 1.3  # off the matches
    err = np.linalg.norm(fine(probe) - _bump(probe), axis=1)
    assert err[np.linalg.norm(probe - CENTRE, axis=1) < 30].mean() < 0.3 * before
    assert err.mean() < 0.25


def test_detailed_keeps_the_smooth_fit_where_there_are_no_matches():
    src = _grid()
    dst = _bump(src)
    smooth = _smooth(src, dst)
    hole = np.linalg.norm(src - [60.0, 60.0], axis=1) < 40  # an untextured area: no matches there
    fine = detailed(smooth, src[~hole], dst[~hole], SHAPE, 8.0)
    inside = _grid(4.0)
    inside = inside[np.linalg.norm(inside - [60.0, 60.0], axis=1) < 20]
    assert np.abs(fine(inside) - smooth(inside)).max() < 0.5


def test_detailed_is_not_pulled_by_a_stray_match():
    src = _grid()
    dst = _bump(src)
    k = int(np.argmin(np.linalg.norm(src - [250.0, 60.0], axis=1)))
    bad = dst.copy()
    bad[k] += [15.0, -10.0]
    smooth = _smooth(src, dst)
    fine = detailed(smooth, src, bad, SHAPE, 8.0)
    assert np.linalg.norm(fine(src[k:k + 1]) - dst[k]) < 1.5
    # a score of zero removes a match's pull altogether
    scores = np.ones(len(src))
    scores[k] = 0.0
    held = detailed(smooth, src, bad, SHAPE, 8.0, scores=scores)
    assert np.linalg.norm(held(src[k:k + 1]) - dst[k]) < 0.3


def test_detailed_is_an_ordinary_kernel_warp():
    src = _grid()
    dst = _bump(src)
    fine = detailed(_smooth(src, dst), src, dst, SHAPE, 8.0)
    again = KernelWarp.from_dict(fine.to_dict())
    probe = _grid(7.0)
    np.testing.assert_allclose(again(probe), fine(probe), atol=1e-9)
    assert fine.n_centers > 600 and fine.linear is not None  # a 12 px lattice over 320 x 240 with a margin: 690
