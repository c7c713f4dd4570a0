"""Tests of the variational Bayesian Student-t rigid registration (``bayes``).

Ground truth is made: surfaces and contours moved by known rigid motions, with noise, uniform
outliers and missing parts.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reglib.errors import InputError
from reglib.registration._bayes import BayesOptions, bayes_register

from .conftest import bumpy, far_partial_pair


def _rotation(axis, degrees):
    """Rotation by ``degrees`` about ``axis`` (scipy's, independent of the library)."""
    return Rotation.from_rotvec(np.deg2rad(degrees) * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix()


def _angle(rot):
    return float(np.degrees(Rotation.from_matrix(rot).magnitude()))


def _surface(n, rng):
    xy = rng.uniform(-1, 1, (n, 2))
    return np.c_[xy, 0.3 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1]) + 0.2 * xy[:, 0] ** 2]


def _with_outliers(points, share, rng):
    n_out = round(share / (1 - share) * len(points))
    lo, hi = points.min(0), points.max(0)
    pad = 0.1 * (hi - lo)
    return np.r_[points, rng.uniform(lo - pad, hi + pad, (n_out, points.shape[1]))]


@pytest.mark.parametrize("field, value", [("dof", 0.0), ("dof", 1001.0), ("update_dof", 1), ("alpha0", 0.0),
                                          ("outlier_prior", 0.0), ("outlier_prior", 1.0), ("anneal", 1.0),
                                          ("anneal", 0.0), ("max_iter", 0), ("max_iter", 1001), ("tol", -1.0),
                                          ("max_points", 9), ("max_points", 3001), ("init", "identity"),
                                          ("feature_voxel", 0.0)])
def test_options_reject_bad_values(field, value):
    with pytest.raises(InputError, match=field):
        BayesOptions(**{field: value})


@pytest.mark.slow
@pytest.mark.parametrize("share", [0.0, 0.5])
def test_recovers_a_known_motion_with_up_to_half_outliers(share):
    rng = np.random.default_rng(1)
    pts = _surface(600, rng)
    rot, trans = _rotation([1, 2, 3], 30), np.array([0.5, -0.2, 1.0])
    target = _with_outliers(pts @ rot.T + trans + rng.normal(scale=0.005, size=pts.shape), share, rng)
    fit = bayes_register(pts, target, BayesOptions(), rng)
    assert _angle(fit.matrix[:, :3] @ rot.T) < 0.5
    np.testing.assert_allclose(fit.matrix[:, 3], trans, atol=0.01)
    assert fit.converged


@pytest.mark.slow
def test_outlier_class_matters_at_half_outliers():
    # With the Student-t tails made Gaussian and the outlier share pinned near zero, the same
    # problem is no longer solved: the test above measures the robust model.
    rng = np.random.default_rng(1)
    pts = _surface(600, rng)
    rot, trans = _rotation([1, 2, 3], 30), np.array([0.5, -0.2, 1.0])
    target = _with_outliers(pts @ rot.T + trans + rng.normal(scale=0.005, size=pts.shape), 0.5, rng)
    fit = bayes_register(pts, target, BayesOptions(dof=1000.0, update_dof=False, outlier_prior=1e-9), rng)
    err = _angle(fit.matrix[:, :3] @ rot.T) + np.linalg.norm(fit.matrix[:, 3] - trans) * 100
    assert err > 1.0


def test_missing_part_of_the_model_in_the_target():
    rng = np.random.default_rng(2)
    pts = _surface(800, rng)
    rot, trans = _rotation([0, 1, 0], 20), np.array([0.0, 0.3, 0.0])
    keep = pts[:, 0] < 0.5  # the target saw 3/4 of the surface
    target = pts[keep] @ rot.T + trans
    fit = bayes_register(pts, target, BayesOptions(), rng)
    assert _angle(fit.matrix[:, :3] @ rot.T) < 1.0
    np.testing.assert_allclose(fit.matrix[:, 3], trans, atol=0.02)


def test_two_dimensional_contour_and_fixed_dof():
    t = np.linspace(0, 2 * np.pi, 150, endpoint=False)
    model = np.c_[np.cos(t) + 0.4 * np.cos(2 * t), np.sin(t) + 0.3 * np.sin(3 * t)]
    a = np.deg2rad(-25)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    fit = bayes_register(model, model @ rot.T + [3.0, -1.0], BayesOptions(update_dof=False),
                         np.random.default_rng(0))
    assert fit.matrix.shape == (2, 3)
    np.testing.assert_allclose(fit.matrix, np.c_[rot, [3.0, -1.0]], atol=1e-3)


def test_large_input_is_subsampled_and_deterministic():
    rng = np.random.default_rng(3)
    pts = _surface(50000, rng)
    rot, trans = _rotation([1, 0, 1], 15), np.array([0.1, 0.1, 0.1])
    target = pts @ rot.T + trans
    before = pts.copy()
    opts = BayesOptions(max_points=300)
    a = bayes_register(pts, target, opts, np.random.default_rng(5))
    b = bayes_register(pts, target, opts, np.random.default_rng(5))
    np.testing.assert_array_equal(a.matrix, b.matrix)
    assert _angle(a.matrix[:, :3] @ rot.T) < 1.0
    np.testing.assert_array_equal(pts, before)


def test_default_start_is_the_centroids_aligned():
    assert BayesOptions().init == "centroid"


def test_feature_start_registers_a_partial_scan_rotated_by_130_degrees():
    model, _, target, rot, trans = far_partial_pair()
    fit = bayes_register(model, target, BayesOptions(init="features", max_points=600), np.random.default_rng(1))
    assert _angle(fit.matrix[:, :3] @ rot.T) < 2.0
    np.testing.assert_allclose(fit.matrix[:, 3], trans, atol=0.05)   # 2 % of the extent


def test_given_starts_from_the_callers_pose():
    # Moving the model so that its centroid lies on the target's makes the caller's pose the
    # centroid start: init="given" then gives the default's answer, composed with that move.
    rng = np.random.default_rng(3)
    model = bumpy(rng.uniform(-1, 1, (400, 2)))
    target = bumpy(rng.uniform(-1, 1, (400, 2)))
    target = target[target[:, 0] > -0.3] @ _rotation([1, 0, 2], 10).T + [0.2, 0.0, 0.1]
    shift = target.mean(0) - model.mean(0)
    opts = BayesOptions(max_iter=30, init="centroid")
    centroid = bayes_register(model, target, opts, np.random.default_rng(0))
    given = bayes_register(model + shift, target, BayesOptions(max_iter=30, init="given"), np.random.default_rng(0))
    np.testing.assert_allclose(given.matrix[:, :3], centroid.matrix[:, :3], atol=1e-8)
    np.testing.assert_allclose(given.matrix[:, :3] @ shift + given.matrix[:, 3], centroid.matrix[:, 3], atol=1e-8)
    unmoved = bayes_register(model, target, BayesOptions(max_iter=30, init="given"), np.random.default_rng(0))
    assert np.abs(unmoved.matrix - centroid.matrix).max() > 1e-3
