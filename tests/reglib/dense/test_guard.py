"""Tests of reglib.dense._guarding: the dense stage's guard, which weighs the dense estimate against the first one
(re-fit, keep the first, or keep the dense one). Pairs are made from scikit-image sample images with known shifts
(tests/reglib/dense/conftest.py)."""
from __future__ import annotations

import cv2
import numpy as np
import skimage.data

from reglib import KernelWarp
from reglib._transforms import LinearPart
from reglib.dense import DenseOptions
from reglib.dense._guarding import guard, keep_first
from reglib.dense._refine import working_frames
from reglib.dense._result import DenseFit


def test_guard_keeps_the_first_estimate_where_the_dense_one_gets_worse(make_affine):
    a = skimage.data.camera().astype(np.float32)[::2, ::2].copy()
    size = a.shape[0]
    t = np.array([3.0, -2.0])
    b = cv2.warpAffine(a, np.float32([[1, 0, t[0]], [0, 1, t[1]]]), (size, size), flags=cv2.INTER_CUBIC)
    f0 = make_affine([[1, 0, t[0]], [0, 1, t[1]]])  # the first estimate is right everywhere
    # a "dense" estimate gone wrong in one quarter: a 6 px bump there; its matches follow it
    bump = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=float(size), dst_mean=np.zeros(2), dst_scale=float(size),
                      linear=LinearPart(kind="affine", matrix=np.c_[np.eye(2), t / size]), beta=30.0,
                      centers=np.array([[0.75, 0.75]]), weights=np.array([[6.0, 4.0]]) / size)
    grid = np.mgrid[8:size - 8:8, 8:size - 8:8].reshape(2, -1).T[:, ::-1].astype(float)
    corner = (grid[:, 0] > 0.6 * size) & (grid[:, 1] > 0.6 * size)
    assert np.linalg.norm(bump(grid[corner]) - grid[corner] - t, axis=1).mean() > 3.0
    opts = DenseOptions(max_side=size)
    res = guard(working_frames(a, b, opts), f0, DenseFit(transform=bump, converged=True, src=grid, dst=bump(grid)),
                opts, np.random.default_rng(0), rounds=1)
    err = np.linalg.norm(res.transform(grid[corner]) - grid[corner] - t, axis=1)
    assert err.mean() < 1.0  # the corner follows the first estimate again (re-fitted or kept)
    assert res.rounds == 1 and res.fitted
    # the confidence map shows the corner supported once repaired
    assert res.confidence.shape == (size, size) and res.confidence[int(0.8 * size), int(0.8 * size)] > 0.5


def test_guard_re_fits_a_dense_estimate_that_lost_a_corner(make_affine):
    # a narrower bump: the check matches that support f0 there join the dense matches, and the
    # re-fit (supported at least as often as the dense estimate) is kept, not f0
    a = skimage.data.camera().astype(np.float32)[::2, ::2].copy()
    size = a.shape[0]
    t = np.array([3.0, -2.0])
    b = cv2.warpAffine(a, np.float32([[1, 0, t[0]], [0, 1, t[1]]]), (size, size), flags=cv2.INTER_CUBIC)
    f0 = make_affine([[1, 0, t[0]], [0, 1, t[1]]])
    bump = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=float(size), dst_mean=np.zeros(2), dst_scale=float(size),
                      linear=LinearPart(kind="affine", matrix=np.c_[np.eye(2), t / size]), beta=120.0,
                      centers=np.array([[0.75, 0.75]]), weights=np.array([[6.0, 4.2]]) / size)
    grid = np.mgrid[8:size - 8:8, 8:size - 8:8].reshape(2, -1).T[:, ::-1].astype(float)
    opts = DenseOptions(max_side=size)
    res = guard(working_frames(a, b, opts), f0, DenseFit(transform=bump, converged=True, src=grid, dst=bump(grid)),
                opts, np.random.default_rng(0), rounds=1)
    assert not res.kept_first and res.n_dense > len(grid)  # the dense matches and f0's check matches
    centre = np.array([[0.75 * size, 0.75 * size]])
    assert np.linalg.norm(bump(centre) - centre - t) > 4.0
    assert np.linalg.norm(res.transform(centre) - centre - t) < 1.0


def test_guard_keeps_the_first_estimate_when_nothing_supports_the_dense_one(make_affine):
    # Images that show different scenes (as a cross-sensor pair can look to the intensity check):
    # neither estimate is supported; the dense one rests on its own matches alone, so f0 stays.
    a = skimage.data.camera().astype(np.float32)[::2, ::2].copy()
    b = cv2.resize(skimage.data.coins(), a.shape[::-1]).astype(np.float32)
    size = a.shape[0]
    f0 = make_affine([[1, 0, 0], [0, 1, 0]])
    shifted = make_affine([[1, 0, 4.0], [0, 1, -3.0]])
    grid = np.mgrid[8:size - 8:8, 8:size - 8:8].reshape(2, -1).T[:, ::-1].astype(float)
    opts = DenseOptions(max_side=size)
    res = guard(working_frames(a, b, opts), f0,
                DenseFit(transform=shifted, converged=True, src=grid, dst=shifted(grid)), opts,
                np.random.default_rng(0), rounds=1)
    assert res.kept_first and res.n_dense == 0 and res.transform is f0
    np.testing.assert_allclose(res.transform(grid), grid, atol=1e-9)
    # the confidence map shows the evidence f0 was judged by: hardly any support
    assert res.confidence.shape == (size, size) and res.confidence.dtype == np.float32
    assert 0.0 <= res.confidence.min() and res.confidence.max() < 0.5


def test_keep_first_rule():
    # clearly more cells supported by f0 alone (margin max(3, 3 % of its check grid)): keep f0
    assert keep_first(20, 5, 400, 300, 1200) and not keep_first(12, 5, 400, 300, 1200)
    # the final estimate supported at fewer than max(3, 3 % of its grid) points: keep f0 even when
    # f0 has no more support than it
    assert keep_first(0, 0, 35, 300, 1200) and not keep_first(0, 0, 36, 300, 1200)
    assert keep_first(0, 0, 2, 10, 40) and not keep_first(0, 0, 3, 10, 40)
