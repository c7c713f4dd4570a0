import json

import numpy as np
import pytest

import reglib
from reglib import InputError, KernelWarp, filter_matches


def precision_recall(found, truth):
    tp = np.count_nonzero(found & truth)
    return tp / max(np.count_nonzero(found), 1), tp / max(np.count_nonzero(truth), 1)


@pytest.mark.parametrize("method", ["l2e", "vfc"])
@pytest.mark.parametrize("dim", [2, 3])
def test_known_field_recovered_at_half_outliers(matches, method, dim):
    src, dst, truth, true_map = matches(n=400, outlier_rate=0.5, dim=dim, seed=1)
    res = filter_matches(src, dst, method=method, rng=0)
    precision, recall = precision_recall(res.inliers, truth)
    assert precision >= 0.95 and recall >= 0.95, (precision, recall)
    # The transform is right away from the inputs too (the map is a value, not a lookup).
    probe = np.random.default_rng(5).uniform(50, 450, (200, dim))
    err = np.linalg.norm(res.transform(probe) - true_map(probe), axis=1)
    # 200 true matches sample a volume far more thinly than an area; VFC's published kernel
    # (beta 0.1, 16 centres, no linear part) is smoother than this field.
    tolerance = {("l2e", 2): 3.0, ("l2e", 3): 5.0, ("vfc", 2): 10.0, ("vfc", 3): 15.0}[method, dim]
    assert np.median(err) < tolerance, np.median(err)


@pytest.mark.parametrize("linear", ["affine", "none", "homography"])
def test_every_linear_part_recovers_the_field(matches, linear):
    src, dst, truth, _ = matches(n=300, outlier_rate=0.4, seed=2)
    res = filter_matches(src, dst, options={"linear": linear}, rng=0)
    precision, recall = precision_recall(res.inliers, truth)
    assert precision >= 0.95 and recall >= 0.9, (precision, recall)
    assert (res.transform.to_dict()["linear"] is None) == (linear == "none")


def test_high_outlier_rate(matches):
    src, dst, truth, _ = matches(n=2000, outlier_rate=0.8, seed=3)
    res = filter_matches(src, dst, rng=0)
    precision, recall = precision_recall(res.inliers, truth)
    assert precision >= 0.95 and recall >= 0.95, (precision, recall)


def test_scores_and_sigma(matches):
    src, dst, truth, _ = matches(n=300, outlier_rate=0.3, seed=4, noise=1.0)
    res = filter_matches(src, dst, rng=0)
    assert res.scores.shape == (300,) and res.scores.dtype == np.float64
    assert np.all((res.scores >= 0) & (res.scores <= 1))
    assert res.scores[truth].mean() > 0.8 > res.scores[~truth].mean()
    # Residual scale of the true matches, in the caller's units: noise 1 px per axis.
    assert 0.5 < res.sigma < 4.0
    assert res.converged and res.n_iter > 0 and res.reason is None


@pytest.mark.parametrize("scale, shift", [(1e-3, (0.0, 0.0)), (37.0, (1e5, -2e5)), (1.0, (1e6, 1e6))])
def test_invariant_to_joint_scaling_and_shift(matches, scale, shift):
    src, dst, _, _ = matches(n=300, outlier_rate=0.4, seed=6)
    base = filter_matches(src, dst, rng=0)
    moved = filter_matches(src * scale + shift, dst * scale + shift, rng=0)
    np.testing.assert_array_equal(base.inliers, moved.inliers)
    np.testing.assert_allclose(moved.scores, base.scores, atol=1e-6)
    probe = src[:20]
    np.testing.assert_allclose(moved.transform(probe * scale + shift), base.transform(probe) * scale + shift,
                               rtol=1e-6, atol=1e-6 * max(scale, 1.0) * 1e3)
    assert moved.sigma == pytest.approx(base.sigma * scale, rel=1e-5)


@pytest.mark.parametrize("method", ["l2e", "vfc"])
def test_same_seed_same_answer(matches, method):
    src, dst, _, _ = matches(n=5000, outlier_rate=0.6, seed=7)
    a = filter_matches(src, dst, method=method, rng=11)
    b = filter_matches(src, dst, method=method, rng=np.random.default_rng(11))
    np.testing.assert_array_equal(a.inliers, b.inliers)
    np.testing.assert_array_equal(a.scores, b.scores)
    assert a.transform.to_dict() == b.transform.to_dict()


def test_large_input_scored_everywhere(matches):
    src, dst, truth, _ = matches(n=30000, outlier_rate=0.7, seed=8)
    res = filter_matches(src, dst, rng=0)
    precision, recall = precision_recall(res.inliers, truth)
    assert precision >= 0.98 and recall >= 0.98, (precision, recall)


def test_transform_json_round_trip_is_exact(matches):
    src, dst, _, _ = matches(n=300, outlier_rate=0.3, seed=9)
    t = filter_matches(src, dst, rng=0).transform
    text = json.dumps(t.to_dict())
    back = KernelWarp.from_dict(json.loads(text))
    probe = np.random.default_rng(0).uniform(-100, 600, (100, 2))
    np.testing.assert_array_equal(back(probe), t(probe))
    assert back.to_dict() == t.to_dict()


@pytest.mark.parametrize("n", [0, 1, 5])
@pytest.mark.parametrize("dim", [2, 3])
def test_too_few_matches_is_an_answer(n, dim):
    src = np.arange(n * dim, dtype=float).reshape(n, dim)
    res = filter_matches(src, src + 1.0)
    assert res.inliers.shape == (n,) and res.inliers.dtype == bool and not res.inliers.any()
    assert res.scores.shape == (n,) and not res.scores.any()
    assert res.converged is False and res.reason == "too_few_matches"
    probe = np.ones((3, dim))
    np.testing.assert_array_equal(res.transform(probe), probe)


def test_empty_lists_accepted():
    res = filter_matches([], [])
    assert res.inliers.shape == (0,)


@pytest.mark.parametrize(
    "src, dst, pattern",
    [
        (np.zeros((5, 4)), np.zeros((5, 4)), r"`src` must have shape \(N, 2\) or \(N, 3\), got \(5, 4\)"),
        (np.zeros(10), np.zeros(10), r"`src` must have shape"),
        (np.zeros((5, 2)), np.zeros((6, 2)), r"`dst` must have the same shape as `src`"),
        (np.zeros((5, 2)), np.zeros((5, 3)), r"`dst` must have the same shape"),
        (np.full((5, 2), np.nan), np.zeros((5, 2)), r"`src` must be finite"),
        (np.zeros((5, 2)), np.full((5, 2), np.inf), r"`dst` must be finite"),
        ([["a", "b"]] * 6, np.zeros((6, 2)), r"`src` must be a numeric array"),
        (None, np.zeros((6, 2)), r"`src`"),
    ],
)
def test_bad_input_is_named(src, dst, pattern):
    with pytest.raises(InputError, match=pattern):
        filter_matches(src, dst)


def test_bad_method_and_options_are_named(matches):
    src, dst, _, _ = matches(n=50)
    with pytest.raises(InputError, match=r"`method` must be one of \['l2e', 'vfc'\]"):
        filter_matches(src, dst, method="ransac")
    with pytest.raises(InputError, match=r"unknown field\(s\) \['betta'\]"):
        filter_matches(src, dst, options={"betta": 1.0})
    with pytest.raises(InputError, match=r"`beta` must be > 0"):
        filter_matches(src, dst, options={"beta": -1.0})
    with pytest.raises(InputError, match=r"`linear` must be one of"):
        filter_matches(src, dst, options={"linear": "spline"})
    with pytest.raises(InputError, match=r"needs 2-D points"):
        filter_matches(np.zeros((10, 3)), np.zeros((10, 3)), options={"linear": "homography"})
    with pytest.raises(InputError, match=r"`options` must be None"):
        filter_matches(src, dst, options=3)
    with pytest.raises(InputError, match=r"`rng`"):
        filter_matches(src, dst, rng="seed")
    assert isinstance(filter_matches(src, dst, options=reglib.L2EOptions(beta=0.5)), reglib.FilterResult)


def test_caller_arrays_not_mutated(matches):
    src, dst, _, _ = matches(n=100)
    s0, d0 = src.copy(), dst.copy()
    filter_matches(src, dst, rng=0)
    np.testing.assert_array_equal(src, s0)
    np.testing.assert_array_equal(dst, d0)


@pytest.mark.parametrize("method", ["l2e", "vfc"])
def test_degenerate_inputs_do_not_crash(method):
    rng = np.random.default_rng(0)
    same = np.ones((40, 2))
    res = filter_matches(same, same + 3.0, method=method, rng=0)  # all identical: a pure shift
    np.testing.assert_allclose(res.transform(same), same + 3.0, atol=1e-6)
    assert res.inliers.all()
    dup = np.repeat(rng.uniform(0, 100, (8, 2)), 12, axis=0)  # every match duplicated 12 times
    res = filter_matches(dup, dup * 1.1 + 5, method=method, rng=0)
    assert res.inliers.all()
    line = np.c_[np.linspace(0, 100, 60), np.zeros(60)]  # collinear
    res = filter_matches(line, line + [2.0, 1.0], method=method, rng=0)
    np.testing.assert_allclose(res.transform(line), line + [2.0, 1.0], atol=1e-6)
    noise = rng.uniform(0, 100, (400, 2))  # 100 % outliers: an answer, most matches rejected
    res = filter_matches(noise, rng.uniform(0, 100, (400, 2)), method=method, rng=0)
    assert res.inliers.mean() < 0.1
    tiny = rng.uniform(0, 10, (6, 2))
    res = filter_matches(tiny, rng.uniform(0, 10, (6, 2)), method=method, rng=0)
    assert res.inliers.shape == (6,) and np.isfinite(res.transform(tiny)).all()


@pytest.mark.parametrize("linear", ["affine", "homography"])
def test_no_kernel_fits_the_linear_part_alone(linear):
    """n_centers=0: the global part alone, no kernel and no finer levels."""
    rng = np.random.default_rng(1)
    src = rng.uniform(0, 400, (300, 2))
    if linear == "affine":
        true = np.array([[1.1, 0.2, 30.0], [-0.15, 0.95, -12.0]])
        clean = src @ true[:, :2].T + true[:, 2]
    elif linear == "homography":
        h = np.array([[1.05, 0.1, 20.0], [-0.05, 0.98, 5.0], [2e-4, -1e-4, 1.0]])
        q = np.c_[src, np.ones(len(src))] @ h.T
        clean = q[:, :2] / q[:, 2:]
    dst = clean + rng.normal(0, 0.5, src.shape)
    bad = rng.random(len(src)) < 0.4
    dst[bad] = rng.uniform(0, 400, (int(bad.sum()), 2))
    res = filter_matches(src, dst, options={"linear": linear, "n_centers": 0}, rng=0)
    assert res.transform.n_centers == 0
    p, r = precision_recall(res.inliers, ~bad)
    assert p >= 0.95 and r >= 0.95
    assert np.abs(res.transform(src[~bad]) - clean[~bad]).max() < 2.0


def test_no_kernel_and_no_linear_part_is_named():
    with pytest.raises(InputError, match="n_centers"):
        filter_matches(np.zeros((10, 2)), np.zeros((10, 2)), options={"linear": "none", "n_centers": 0})


@pytest.mark.parametrize("method, field, value", [("l2e", "max_iter", 1001), ("l2e", "fine_iter", 101),
                                                  ("l2e", "n_anneal", 61), ("l2e", "max_levels", 21),
                                                  ("vfc", "max_iter", 10001)])
def test_iteration_counts_are_bounded(matches, method, field, value):
    src, dst, _, _ = matches(n=50)
    with pytest.raises(InputError, match=field):
        filter_matches(src, dst, method=method, options={field: value})


def test_long_annealing_stays_finite(matches):
    """sigma^2 annealed 60 times would underflow; it is held at a floor instead. Annealed far
    below the noise, L2E follows only the matches closest to its fit: fewer, but right ones."""
    src, dst, truth, _ = matches(n=300)
    res = filter_matches(src, dst, options={"n_anneal": 60}, rng=0)
    assert np.isfinite(res.scores).all() and np.isfinite(res.transform(src)).all()
    p, _ = precision_recall(res.inliers, truth)
    assert p >= 0.95 and res.n_inliers >= 10


def test_coordinates_whose_squares_overflow_are_named():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 1, (40, 2)) * 1e99
    res = filter_matches(src, src + 1e97, rng=0)  # 1e99 still works
    assert res.inliers.all()
    with pytest.raises(InputError, match="`dst` has coordinates up to"):
        filter_matches(src, src * 1e3, rng=0)


@pytest.mark.parametrize("method", ["l2e", "vfc"])
def test_an_iteration_cap_is_recorded_not_a_failure(matches, method):
    """``converged`` is the verdict (False exactly when there is a reason); a cap is ``stopped``."""
    src, dst, truth, _ = matches(n=300, outlier_rate=0.4, seed=3)
    capped = filter_matches(src, dst, method=method, options={"max_iter": 1}, rng=0)
    settled = filter_matches(src, dst, method=method, rng=0)
    assert capped.stopped == "iteration_cap" and settled.stopped == "tolerance"
    for res in (capped, settled):
        assert res.converged == (res.reason is None)
        assert reglib.FilterResult.from_dict(res.to_dict()).stopped == res.stopped
    # L2E's annealing has found the answer by its last step; one re-weighting there does not change that
    # (VFC's EM from its start is another matter: one step of it is no estimate, nor is it the default's)
    if method == "l2e":
        precision, recall = precision_recall(capped.inliers, truth)
        assert precision >= 0.95 and recall >= 0.95 and capped.converged, (precision, recall)
    assert capped.to_dict()["stopped"] == "iteration_cap"


def test_random_putatives_say_why_they_are_no_answer():
    rng = np.random.default_rng(0)
    res = filter_matches(rng.uniform(0, 1000, (500, 2)), rng.uniform(0, 1000, (500, 2)), rng=0)
    assert not res.converged and res.reason is not None


def test_nothing_estimated_has_no_stopped_key():
    res = filter_matches(np.zeros((3, 2)), np.zeros((3, 2)), rng=0)
    assert res.stopped is None and "stopped" not in res.to_dict() and res.reason == "too_few_matches"
    bad = {**filter_matches(*np.random.default_rng(1).uniform(0, 100, (2, 40, 2)), rng=0).to_dict(), "stopped": "x"}
    with pytest.raises(InputError, match="`stopped` must be null or one of"):
        reglib.FilterResult.from_dict(bad)
