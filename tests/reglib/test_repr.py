"""The result types print as one short line: counts, shapes and the verdict, never their arrays."""
from __future__ import annotations

import numpy as np

import reglib
from reglib._repr import short_repr
from reglib.dense import DenseResult
from reglib.features import Features
from reglib.io import PointCloud


def _big_filter() -> reglib.FilterResult:
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 800, (3000, 2))
    dst = src + 4 * np.sin(src[:, ::-1] / 90)
    dst[:900] = rng.uniform(0, 800, (900, 2))
    return reglib.filter_matches(src, dst, rng=0)


def test_filter_result_repr_is_short_and_names_the_verdict() -> None:
    res = _big_filter()
    text = repr(res)
    assert len(text) <= 400 and "[" not in text
    assert f"n_matches={res.n_matches}" in text and f"n_inliers={res.n_inliers}" in text
    assert f"converged={res.converged}" in text and "KernelWarp(" in text


def test_image_match_repr_shows_shapes_not_arrays() -> None:
    res = _big_filter()
    n = res.n_matches
    rng = np.random.default_rng(1)
    match = reglib.ImageMatch(keypoints_a=rng.uniform(0, 800, (5000, 2)), keypoints_b=rng.uniform(0, 800, (5000, 2)),
                              src=rng.uniform(0, 800, (n, 2)), dst=rng.uniform(0, 800, (n, 2)), inliers=res.inliers,
                              scores=res.scores, transform=res.transform, converged=False, reason="unsupported",
                              seed=3, shape_a=(800, 900), shape_b=(700, 850), n_dense=1234,
                              confidence=np.zeros((800, 900), np.float32), dense="sparse_better",
                              timings_ms={"features": 1.0, "total": 2.0})
    text = repr(match)
    assert len(text) <= 400
    assert "confidence=<array 800x900 float32>" in text and "shape_a=(800, 900)" in text
    assert "reason='unsupported'" in text and "dense='sparse_better'" in text and "n_dense=1234" in text


def test_registration_repr_is_short() -> None:
    rng = np.random.default_rng(2)
    model = rng.uniform(-1, 1, (4000, 3))
    reg = reglib.register_points(model, model + [0.1, 0.0, -0.2], method="cpd-rigid", rng=0)
    text = repr(reg)
    assert len(text) <= 400
    assert "registered=<array 4000x3 float64>" in text and "matrix=<array 4x4 float64>" in text
    assert f"n_matched={reg.n_matched}" in text and reg.n_matched == int((reg.correspondence >= 0).sum())


def test_other_results_print_their_sizes() -> None:
    pts = np.zeros((10000, 3))
    assert repr(PointCloud(points=pts, colors=np.zeros((10000, 3)))) == (
        "PointCloud(points=<array 10000x3 float64>, colors=<array 10000x3 float64>)")
    feats = Features(np.zeros((600, 2)), np.zeros(600), np.zeros(600), np.zeros((600, 128), np.float32))
    assert repr(feats) == "Features(points=<array 600x2 float64>, descriptors=<array 600x128 float32>)"
    ev = reglib.evaluate(_big_filter().transform, np.zeros((500, 2)), np.ones((500, 2)), shape_b=(100, 100))
    assert len(repr(ev)) <= 400 and "n_landmarks=500" in repr(ev)
    dense = DenseResult(transform=_big_filter().transform, converged=True, n_dense=7,
                        confidence=np.ones((300, 200), np.float32), rounds=3, kept_first=False)
    assert "confidence=<array 300x200 float32>" in repr(dense) and len(repr(dense)) <= 400


def test_short_repr_leaves_out_none_and_rounds_floats() -> None:
    class Thing:
        a = 1.23456789
        b = None
        c = (2, 3)

    assert short_repr(Thing(), ("a", "b", "c")) == "Thing(a=1.235, c=(2, 3))"
