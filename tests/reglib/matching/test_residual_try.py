"""The residual try of ``match_images`` (issue 50): an unsupported SIFT answer, the dense stage again from the sparse
fit composed with the motion it left. The pair is made here with a known map (a shift and one strong bump); the
sparse fit handed to the try is replaced by one that missed the bump."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

import reglib.matching._pipeline as pipeline
from reglib import KernelWarp
from reglib._verdict import UNSUPPORTED
from reglib.matching._dense import residual_retry
from reglib.robust import filter_matches

from .conftest import replaced_first_answer

SIZE = 320
CENTRE = np.array([170.0, 150.0])
SHIFT = np.array([7.0, -5.0])


def _backward(q: np.ndarray) -> np.ndarray:
    """b's pixel -> a's position: a shift and a bump of 16 px (sigma 36 px)."""
    g = np.exp(-np.sum((q - CENTRE) ** 2, axis=1) / (2 * 36.0**2))
    return q - SHIFT + 16.0 * g[:, None] * np.array([0.8, -0.6])


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    a = np.zeros((SIZE, SIZE), np.float32)
    for sigma, weight in ((1.5, 0.5), (4.0, 1.0), (10.0, 1.5)):
        a += weight * sigma * cv2.GaussianBlur(rng.standard_normal((SIZE, SIZE)).astype(np.float32), (0, 0), sigma)
    a = (a - a.min()) / (a.max() - a.min())
    ys, xs = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    m = _backward(np.c_[xs.ravel(), ys.ravel()]).reshape(SIZE, SIZE, 2).astype(np.float32)
    b = cv2.remap(a, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    b = 0.9 * b ** 0.85 + 0.04  # gain and gamma
    return (a * 255).astype(np.uint8), np.clip(b * 255, 0, 255).astype(np.uint8)


def _shift_only() -> KernelWarp:
    ys, xs = np.mgrid[8:SIZE:32, 8:SIZE:32]
    src = np.c_[xs.ravel(), ys.ravel()].astype(float)
    return filter_matches(src, src + SHIFT, options={"max_centers": 0}, rng=0).transform


def _bump_error(f: KernelWarp) -> float:
    """Mean error within 30 px of the bump's centre (points of b mapped back to a)."""
    ys, xs = np.mgrid[CENTRE[1] - 30:CENTRE[1] + 30:4, CENTRE[0] - 30:CENTRE[0] + 30:4]
    q = np.c_[xs.ravel(), ys.ravel()]
    return float(np.linalg.norm(f(_backward(q)) - q, axis=1).mean())


def _missed_bump(a: np.ndarray, b: np.ndarray, features: str = "sift"):
    """The stages on the pair, the sparse fit and the answer replaced by the shift alone: an answer that missed the
    bump, as the residual try receives it."""
    return replaced_first_answer(a, b, features, _shift_only(), sparse_too=True)


def test_residual_try_finds_the_missed_bump(pair) -> None:
    a, b = pair
    images, run, sparse, dense, rating = _missed_bump(a, b)
    assert _bump_error(dense.transform) > 10.0
    got, converged, reason = pipeline._residual_try(images, run, sparse, dense, rating)
    assert (converged, reason) == (True, None) and got is not dense
    assert _bump_error(got.transform) < 2.0  # from over 10 px
    assert "residual_try" in run.timings and "residual_start" in run.timings


def test_residual_try_keeps_the_first_answer_when_not_rated_better(pair) -> None:
    a, b = pair
    images, run, sparse, dense, rating = _missed_bump(a, b)
    unbeatable = dataclasses.replace(rating, z=1e9)
    got, converged, reason = pipeline._residual_try(images, run, sparse, dense, unbeatable)
    assert (converged, reason) == (False, UNSUPPORTED) and got is dense
    assert "residual_try" in run.timings and "residual_start" not in run.timings


def test_residual_try_keeps_the_first_answer_when_its_places_are_found_away(pair, monkeypatch) -> None:
    a, b = pair
    images, run, sparse, dense, rating = _missed_bump(a, b)
    seen = []
    monkeypatch.setattr(pipeline, "found_away", lambda *args: seen.append(_bump_error(args[2])) or 1.0)
    got, converged, reason = pipeline._residual_try(images, run, sparse, dense, rating)
    assert (converged, reason) == (False, UNSUPPORTED) and got is dense
    assert len(seen) == 1 and seen[0] < 2.0  # the retry found the bump, and is refused by this test alone


def test_no_residual_start_for_the_multimodal_path(pair) -> None:
    a, b = pair
    images, run, sparse, dense, _ = _missed_bump(a, b, features="multimodal")
    assert sparse.features == "multimodal"
    assert residual_retry(sparse, dense, images, run) is None
