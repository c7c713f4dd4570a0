"""L2E and VFC with a rigid or similarity linear part (``linear="rigid" | "similarity"``), 2-D and 3-D."""
from __future__ import annotations

import numpy as np
import pytest

from reglib.errors import InputError
from reglib.robust import L2EOptions, filter_matches


def _rotation(dim: int, rng: np.random.Generator) -> np.ndarray:
    if dim == 2:
        a = rng.uniform(-np.pi, np.pi)
        return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _matches(dim: int, scale: float, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    src = rng.uniform(-50, 50, size=(400, dim))
    rot = _rotation(dim, rng)
    t = rng.uniform(-20, 20, size=dim)
    dst = scale * src @ rot.T + t + rng.normal(scale=0.05, size=src.shape)
    wrong = rng.random(len(src)) < 0.5
    dst[wrong] = rng.uniform(-100, 100, size=(int(wrong.sum()), dim))
    return src, dst, rot, t, wrong


def _linear(res, dim: int) -> np.ndarray:
    basis = res.transform(np.vstack([np.zeros(dim), np.eye(dim)]))
    return np.c_[(basis[1:] - basis[0]).T, basis[0]]


@pytest.mark.parametrize("dim", [2, 3])
def test_rigid_part_recovers_the_motion_in_the_callers_units(dim: int) -> None:
    rng = np.random.default_rng(dim)
    src, dst, rot, t, wrong = _matches(dim, 1.0, rng)
    opts = {"linear": "rigid", "n_centers": 0, "max_centers": 0}
    res = filter_matches(src, dst, options=opts, rng=0)
    m = _linear(res, dim)
    assert np.abs(m[:, :dim] - rot).max() < 1e-3
    assert np.linalg.det(m[:, :dim]) == pytest.approx(1.0, abs=1e-6)     # a rotation, no scale
    assert np.abs(m[:, dim] - t).max() < 0.05
    assert res.inliers[~wrong].mean() > 0.98 and res.inliers[wrong].mean() < 0.02
    assert res.converged and res.reason is None


@pytest.mark.parametrize("dim", [2, 3])
def test_similarity_part_finds_the_scale(dim: int) -> None:
    rng = np.random.default_rng(10 + dim)
    src, dst, rot, t, wrong = _matches(dim, 2.5, rng)
    res = filter_matches(src, dst, options=L2EOptions(linear="similarity", n_centers=0, max_centers=0), rng=0)
    m = _linear(res, dim)
    assert np.abs(m[:, :dim] - 2.5 * rot).max() < 5e-3
    assert res.inliers[~wrong].mean() > 0.98
    # "rigid" cannot take the scale: its map stays a rotation in the caller's units
    rigid = filter_matches(src, dst, options={"linear": "rigid", "n_centers": 0, "max_centers": 0}, rng=0)
    assert np.allclose(np.linalg.svd(_linear(rigid, dim)[:, :dim], compute_uv=False), 1.0)


def test_rigid_with_a_kernel_and_vfc_run() -> None:
    rng = np.random.default_rng(5)
    src, dst, rot, t, wrong = _matches(3, 1.0, rng)
    res = filter_matches(src, dst, options={"linear": "rigid"}, rng=0)
    assert res.inliers[~wrong].mean() > 0.95 and res.inliers[wrong].mean() < 0.05
    vfc = filter_matches(src, dst, method="vfc", options={"linear": "similarity"}, rng=0)
    assert vfc.inliers[~wrong].mean() > 0.9


def test_unknown_linear_named() -> None:
    with pytest.raises(InputError, match="linear"):
        L2EOptions(linear="euclid")  # type: ignore[arg-type]
