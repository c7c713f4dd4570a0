"""Closed-form rigid steps: Umeyama's SVD and FA3R against known motions and each other."""
from __future__ import annotations

import numpy as np
import pytest

from reglib.errors import InputError
from reglib.registration._procrustes import fa3r, umeyama


def _rotation(rng: np.random.Generator, dim: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(dim, dim)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scale", [False, True])
def test_umeyama_recovers_known_motion(dim: int, scale: bool) -> None:
    rng = np.random.default_rng(dim + 10 * scale)
    src = rng.normal(size=(40, dim)) * 5.0
    rot = _rotation(rng, dim)
    s = 2.5 if scale else 1.0
    t = rng.normal(size=dim) * 10.0
    m = umeyama(src, s * src @ rot.T + t, scale=scale)
    assert m.shape == (dim, dim + 1)
    np.testing.assert_allclose(m, np.c_[s * rot, t], atol=1e-9)


@pytest.mark.parametrize("scale", [False, True])
def test_fa3r_recovers_known_motion(scale: bool) -> None:
    rng = np.random.default_rng(3)
    src = rng.normal(size=(30, 3)) * 3.0
    rot = _rotation(rng, 3)
    s = 0.4 if scale else 1.0
    t = np.array([1.0, -2.0, 30.0])
    m = fa3r(src, s * src @ rot.T + t, scale=scale)
    assert m.shape == (3, 4)
    np.testing.assert_allclose(m, np.c_[s * rot, t], atol=1e-9)


def test_fa3r_equals_umeyama_on_noisy_weighted_data() -> None:
    rng = np.random.default_rng(4)
    worst = 0.0
    for _ in range(200):
        n = int(rng.integers(3, 60))
        src = rng.normal(size=(n, 3)) * rng.uniform(0.01, 100.0)
        # heavy noise: the cross-covariance is often far from a rotation (or a reflection)
        dst = src @ _rotation(rng, 3).T + rng.normal(size=(n, 3)) * rng.uniform(0.0, 3.0) * src.std()
        w = rng.uniform(0.0, 1.0, n)
        for scale in (False, True):
            a, b = umeyama(src, dst, w, scale=scale), fa3r(src, dst, w, scale=scale)
            worst = max(worst, float(np.abs(a - b).max() / max(1.0, np.abs(a).max())))
    assert worst < 1e-9


def test_planar_points_and_reflection_free_answer() -> None:
    rng = np.random.default_rng(5)
    src = np.c_[rng.normal(size=(20, 2)), np.zeros(20)]          # coplanar: H has rank 2
    rot = _rotation(rng, 3)
    for solver in (umeyama, fa3r):
        m = solver(src, src @ rot.T)
        assert np.linalg.det(m[:, :3]) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(m[:, :3], rot, atol=1e-9)


def test_zero_weights_ignore_corrupted_pairs() -> None:
    rng = np.random.default_rng(6)
    src = rng.normal(size=(50, 3))
    rot = _rotation(rng, 3)
    dst = src @ rot.T + 1.0
    dst[:10] = rng.normal(size=(10, 3)) * 50.0
    w = np.ones(50)
    w[:10] = 0.0
    for solver in (umeyama, fa3r):
        np.testing.assert_allclose(solver(src, dst, w), np.c_[rot, np.ones(3)], atol=1e-9)
        assert not np.allclose(solver(src, dst), np.c_[rot, np.ones(3)], atol=1e-3)


def test_inputs_are_not_modified() -> None:
    rng = np.random.default_rng(7)
    src, dst, w = rng.normal(size=(10, 3)), rng.normal(size=(10, 3)), rng.uniform(size=10)
    copies = [a.copy() for a in (src, dst, w)]
    umeyama(src, dst, w, scale=True)
    fa3r(src, dst, w, scale=True)
    for a, b in zip((src, dst, w), copies, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(("call", "match"), [
    (lambda: umeyama(np.zeros((5, 4)), np.zeros((5, 4))), r"`src` must have shape"),
    (lambda: umeyama(np.zeros((5, 3)), np.zeros((4, 3))), r"`dst` must have the same shape"),
    (lambda: umeyama(np.zeros((0, 3)), np.zeros((0, 3))), r"at least one point"),
    (lambda: umeyama(np.ones((5, 3)), np.ones((5, 3)), -np.ones(5)), r"`weights` must be finite and non-negative"),
    (lambda: umeyama(np.ones((5, 3)), np.ones((5, 3)), np.zeros(5)), r"positive sum"),
    (lambda: umeyama(np.ones((5, 3)), np.ones((5, 3)), np.ones(4)), r"`weights` must have shape \(5,\)"),
    (lambda: fa3r(np.zeros((5, 2)), np.zeros((5, 2))), r"`src` must have shape \(N, 3\)"),
])
def test_errors(call, match: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(InputError, match=match):
        call()
