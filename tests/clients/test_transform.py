"""The client's numpy evaluator of the transform JSON agrees with reglib.KernelWarp (the library)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from reglib import KernelWarp
from reglib._transforms import LinearPart
from reglib_client import Transform


def _warp(dim: int, kind: str | None, seed: int) -> KernelWarp:
    rng = np.random.default_rng(seed)
    linear = None
    if kind == "affine":
        linear = LinearPart(kind="affine", matrix=np.hstack([np.eye(dim) + 0.1 * rng.normal(size=(dim, dim)),
                                                             rng.normal(size=(dim, 1))]))
    elif kind == "homography":
        h = np.eye(3) + 0.05 * rng.normal(size=(3, 3))
        linear = LinearPart(kind="homography", matrix=h)
    return KernelWarp(dim=dim, src_mean=rng.normal(size=dim) * 50, src_scale=37.5, dst_mean=rng.normal(size=dim) * 50,
                      dst_scale=41.0, linear=linear, beta=0.8, centers=rng.normal(size=(12, dim)),
                      weights=0.3 * rng.normal(size=(12, dim)))


@pytest.mark.parametrize(("dim", "kind"), [(2, None), (2, "affine"), (2, "homography"), (3, None), (3, "affine")])
def test_evaluator_matches_the_library(dim: int, kind: str | None) -> None:
    warp = _warp(dim, kind, seed=dim * 10 + len(kind or ""))
    data = json.loads(json.dumps(warp.to_dict()))  # exactly what travels over the wire
    transform = Transform.from_dict(data)
    points = np.random.default_rng(5).normal(size=(500, dim)) * 60
    np.testing.assert_allclose(transform(points), warp(points), rtol=1e-12, atol=1e-9)
    assert transform.dim == dim and transform.n_centers == 12
    assert transform.to_dict() == data


def test_identity_and_empty_points() -> None:
    transform = Transform.from_dict(KernelWarp.identity(2).to_dict())
    points = np.array([[1.5, -2.0], [0.0, 7.0]])
    np.testing.assert_array_equal(transform(points), points)
    assert transform(np.zeros((0, 2))).shape == (0, 2)
    assert transform([]).shape == (0, 2)


def test_many_points_are_evaluated_in_blocks() -> None:
    warp = _warp(2, "affine", seed=3)
    points = np.random.default_rng(6).uniform(-100, 100, size=(40_000, 2))
    np.testing.assert_allclose(Transform.from_dict(warp.to_dict())(points), warp(points), rtol=1e-12, atol=1e-9)


def test_to_dict_is_a_copy() -> None:
    data = KernelWarp.identity(3).to_dict()
    transform = Transform.from_dict(data)
    data["dim"] = 99
    out = transform.to_dict()
    out["beta"] = -1
    assert transform.to_dict()["dim"] == 3 and transform.to_dict()["beta"] == 1.0


@pytest.mark.parametrize(("change", "message"), [
    ({"type": "tps"}, "`type`"),
    ({"version": 2}, "`version`"),
    ({"dim": 4}, "`dim`"),
    ({"src_mean": [0.0]}, "`src_mean`"),
    ({"dst_scale": 0.0}, "`dst_scale`"),
    ({"beta": float("nan")}, "`beta`"),
    ({"centers": [[0.0, float("inf")]], "weights": [[0.0, 0.0]]}, "`centers`"),
    ({"centers": [[0.0, 1.0]], "weights": [[0.0, 0.0], [1.0, 1.0]]}, "`weights`"),
    ({"linear": {"kind": "affine", "matrix": [[1.0, 0.0], [0.0, 1.0]]}}, "`linear.matrix`"),
    ({"linear": {"kind": "similarity"}}, "`linear`"),
])
def test_malformed_json_names_the_field(change: dict, message: str) -> None:
    data = {**KernelWarp.identity(2).to_dict(), **change}
    with pytest.raises(ValueError, match=message):
        Transform.from_dict(data)
    with pytest.raises(ValueError, match="missing"):
        Transform.from_dict({"type": "kernel_warp"})


def test_points_of_the_wrong_dimension_are_rejected() -> None:
    transform = Transform.from_dict(KernelWarp.identity(2).to_dict())
    with pytest.raises(ValueError, match=r"shape \(K, 2\)"):
        transform(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        transform([[0.0, np.nan]])
