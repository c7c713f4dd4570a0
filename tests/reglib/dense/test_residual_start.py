"""Tests of reglib.dense._residual_start: the sparse fit composed with the motion it left. The pair is made here with
a known map: b is a seen through a shift and one strong bump, with a gain and a gamma, and the start it is given
knows the shift only (a sparse fit that missed the bump)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from reglib import KernelWarp
from reglib.dense import DenseOptions
from reglib.dense._residual_start import _histogram_matched, residual_start
from reglib.robust import filter_matches

SIZE = 256
CENTRE = np.array([140.0, 120.0])
SHIFT = np.array([6.0, -4.0])


def _texture(seed: int = 3) -> np.ndarray:
    """Grey texture with detail at several scales (what a photograph offers the flow)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((SIZE, SIZE), np.float32)
    for sigma, weight in ((1.5, 0.5), (4.0, 1.0), (10.0, 1.5)):
        img += weight * cv2.GaussianBlur(rng.standard_normal((SIZE, SIZE)).astype(np.float32), (0, 0), sigma) * sigma
    img -= img.min()
    return (img / img.max()).astype(np.float32)


def _backward(q: np.ndarray) -> np.ndarray:
    """M: b's pixel -> a's position (a shift and a bump of 14 px, sigma 32 px)."""
    g = np.exp(-np.sum((q - CENTRE) ** 2, axis=1) / (2 * 32.0**2))
    return q - SHIFT + 14.0 * g[:, None] * np.array([0.8, -0.6])


def _pair() -> tuple[np.ndarray, np.ndarray]:
    a = _texture()
    ys, xs = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    m = _backward(np.c_[xs.ravel(), ys.ravel()]).reshape(SIZE, SIZE, 2).astype(np.float32)
    b = cv2.remap(a, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    b = 0.85 * b ** 0.8 + 0.05  # gain and gamma between the images
    return (a * 255).astype(np.uint8), np.clip(b * 255, 0, 255).astype(np.uint8)


def _shift_only() -> KernelWarp:
    """The start that missed the bump: the shift, fitted with no kernel part."""
    ys, xs = np.mgrid[8:SIZE:32, 8:SIZE:32]
    src = np.c_[xs.ravel(), ys.ravel()].astype(float)
    return filter_matches(src, src + SHIFT, options={"max_centers": 0}, rng=0).transform


def _errors(f: KernelWarp) -> tuple[float, float]:
    """Mean error near the bump (within 30 px of its centre, in b) and away from it, at points of b mapped back."""
    ys, xs = np.mgrid[24:SIZE - 24:4, 24:SIZE - 24:4]
    q = np.c_[xs.ravel(), ys.ravel()].astype(float)
    err = np.linalg.norm(f(_backward(q)) - q, axis=1)
    near = np.linalg.norm(q - CENTRE, axis=1) < 30
    return float(err[near].mean()), float(err[~near].mean())


@pytest.mark.parametrize(("max_side", "gain"), [(DenseOptions().max_side, 0.3), (200, 0.5)])
def test_residual_start_finds_the_bump_the_start_missed(max_side: int, gain: float):
    """The start over the bump comes within ``gain`` of the shift-only start's error, also on a working copy smaller
    than the images (``max_side`` 200: the same map, in the original pixels)."""
    a, b = _pair()
    f0 = _shift_only()
    near0, _ = _errors(f0)
    assert near0 > 8.0  # the start is far off over the bump
    start = residual_start(a, b, f0, DenseOptions(max_side=max_side), np.random.default_rng(0))
    assert start is not None
    near1, far1 = _errors(start)
    assert near1 < gain * near0
    assert far1 < 0.5


def test_residual_start_gives_none_without_samples():
    a, b = _pair()
    mask = np.zeros(a.shape, bool)
    assert residual_start(a, b, _shift_only(), DenseOptions(), np.random.default_rng(0), mask_a=mask) is None


def test_histogram_matching_undoes_a_monotone_change_of_grey_levels():
    a, _ = _pair()
    changed = np.clip(255 * (0.9 * (a / 255.0) ** 1.4 + 0.05), 0, 255).astype(np.uint8)
    back = _histogram_matched(changed, a)
    assert np.abs(back.astype(int) - a.astype(int)).mean() < 1.0
    assert np.abs(changed.astype(int) - a.astype(int)).mean() > 10.0
