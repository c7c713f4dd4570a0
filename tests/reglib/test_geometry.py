"""Rotations and similarity maps of reglib._geometry against made ground truth."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reglib._geometry import fa3r_rotation, nearest_rotation, rotation_angle, signed_svd, umeyama_similarity


def _random_rotations(rng: np.random.Generator, dim: int, n: int) -> np.ndarray:
    """n random proper rotations (scipy's in 3-D, by angle in 2-D)."""
    if dim == 3:
        return Rotation.random(n, random_state=rng).as_matrix()
    a = rng.uniform(-np.pi, np.pi, n)
    return np.stack([np.stack([np.cos(a), -np.sin(a)], -1), np.stack([np.sin(a), np.cos(a)], -1)], -2)


@pytest.mark.parametrize("dim", [2, 3])
def test_nearest_rotation_recovers_random_rotations(dim: int) -> None:
    rng = np.random.default_rng(dim)
    rots = _random_rotations(rng, dim, 50)
    # a symmetric positive definite factor does not change the polar rotation: H = R P
    a = rng.normal(size=(50, dim, dim))
    spd = np.einsum("hij,hkj->hik", a, a) + dim * np.eye(dim)
    np.testing.assert_allclose(nearest_rotation(rots @ spd), rots, atol=1e-10)
    np.testing.assert_allclose(nearest_rotation(rots[0] @ spd[0]), rots[0], atol=1e-10)   # one matrix


@pytest.mark.parametrize("dim", [2, 3])
def test_reflections_are_fixed_to_det_plus_one(dim: int) -> None:
    rng = np.random.default_rng(10 + dim)
    flip = np.diag([1.0] * (dim - 1) + [-1.0])
    h = _random_rotations(rng, dim, 30) @ flip @ np.diag(np.arange(dim, 0, -1.0))   # det < 0
    r = nearest_rotation(h)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("hji,hjk->hik", r, r), np.broadcast_to(np.eye(dim), r.shape), atol=1e-12)
    u, s, vt = signed_svd(h)
    assert (s[:, -1] < 0).all() and (s[:, :-1] > 0).all()           # the smallest one signed
    np.testing.assert_allclose(u @ vt, r, atol=0)
    # the answer is the closest proper rotation: no random one is closer in the Frobenius norm
    others = _random_rotations(rng, dim, 2000)
    best = np.linalg.norm(h[0] - r[0])
    assert (np.linalg.norm(h[0] - others, axis=(1, 2)) >= best - 1e-12).all()


def test_rotation_angle_of_known_rotations() -> None:
    rotvec = np.array([0.2, -0.4, 0.3])
    angle = float(np.linalg.norm(rotvec))
    assert float(rotation_angle(Rotation.from_rotvec(rotvec).as_matrix())) == pytest.approx(angle, abs=1e-12)
    c, s = np.cos(2.0), np.sin(2.0)
    assert float(rotation_angle(np.array([[c, -s], [s, c]]))) == pytest.approx(2.0, abs=1e-12)
    assert float(rotation_angle(np.array([[c, s], [-s, c]]))) == pytest.approx(2.0, abs=1e-12)   # sign-free
    stack = Rotation.from_rotvec(np.outer([0.0, 0.5, 1.0, np.pi], [0.0, 0.0, 1.0])).as_matrix()
    np.testing.assert_allclose(rotation_angle(stack), [0.0, 0.5, 1.0, np.pi], atol=1e-7)
    assert rotation_angle(stack).shape == (4,)


@pytest.mark.parametrize("dim", [2, 3])
def test_umeyama_recovers_a_known_similarity(dim: int) -> None:
    rng = np.random.default_rng(20 + dim)
    src = rng.normal(size=(60, dim)) * 4.0
    rot = _random_rotations(rng, dim, 1)[0]
    s, t = 1.7, rng.normal(size=dim) * 5.0
    dst = s * src @ rot.T + t
    np.testing.assert_allclose(umeyama_similarity(src, dst, scale=True), np.c_[s * rot, t], atol=1e-9)
    rigid = umeyama_similarity(src, dst)                                # scale=False: s = 1
    np.testing.assert_allclose(rigid[:, :dim], rot, atol=1e-9)
    # weights: corrupted pairs with weight zero do not count
    bad = dst.copy()
    bad[:15] += rng.normal(size=(15, dim)) * 30.0
    w = np.r_[np.zeros(15), rng.uniform(0.5, 2.0, 45)]
    np.testing.assert_allclose(umeyama_similarity(src, bad, w, scale=True), np.c_[s * rot, t], atol=1e-9)
    if dim == 3:
        np.testing.assert_allclose(umeyama_similarity(src, bad, w, scale=True, solver="fa3r"),
                                   np.c_[s * rot, t], atol=1e-9)


def test_fa3r_equals_svd_on_a_well_conditioned_case() -> None:
    rng = np.random.default_rng(30)
    for rot in Rotation.random(20, random_state=rng).as_matrix():
        h = rot @ np.diag(rng.uniform(1.0, 3.0, 3)) + 0.01 * rng.normal(size=(3, 3))
        np.testing.assert_allclose(fa3r_rotation(h), nearest_rotation(h), atol=1e-12)
    np.testing.assert_array_equal(fa3r_rotation(np.zeros((3, 3))), np.eye(3))
